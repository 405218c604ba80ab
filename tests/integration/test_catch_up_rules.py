"""What a diagnoser does with throws a publisher's cache replays after an outage (docs/contracts.md section 3,
Catching up): a real diagnoser and its switch states on disk, records of the shipped nominal recording, no bus."""
from __future__ import annotations

import logging

import pytest

from railswitch.schemas import MotorSample, ThrowEvent, ThrowRecord, encode, key_expr
from railswitch.services.adapters.baseline_store import BaselineStore
from railswitch.services.adapters.zenoh_bus import Received
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.live_diagnoser import LiveDiagnoser
from railswitch.services.core.recent_throws import RecentThrows
from tests.live import RecordSource


class Published:
    """The diagnoses a LiveDiagnoser puts on the bus, by (switch, throw index)."""

    def __init__(self):
        self.diagnosed: list[tuple[str, int]] = []
        self.diagnoses = []
        self.published = 0

    def put(self, key: str, message) -> None:
        if key.endswith("/diagnosis"):
            self.diagnosed.append((message.switch_id, message.throw_index))
            self.diagnoses.append(message)


@pytest.fixture()
def records():
    source = RecordSource()
    return [source.next("sw1") for _ in range(8)]


def live_diagnoser(tmp_path, recover=None) -> tuple[LiveDiagnoser, Published]:
    store = BaselineStore("poly", tmp_path)
    published = Published()
    return LiveDiagnoser(Diagnoser("poly", on_state=store.save, stored_state=store.load), published,
                         known=store.known, recover=recover), published


def send(live: LiveDiagnoser, *records) -> None:
    for record in records:
        live.handle(Received(key_expr(record.switch_id, "record"), encode(record), 0.0))


def test_a_restarted_diagnoser_skips_the_replayed_throws_its_state_has_seen(tmp_path, records):
    first, published = live_diagnoser(tmp_path)
    send(first, *records[:4])
    assert published.diagnosed == [("sw1", i) for i in range(4)]
    again, published = live_diagnoser(tmp_path)  # a new process, the same state folder
    send(again, *records[2:6])  # the cache kept throws 2 and 3, diagnosed before the outage
    assert published.diagnosed == [("sw1", 4), ("sw1", 5)]
    assert again.counts["already_diagnosed"] == 2 and again.counts["missed"] == 0


def test_throws_older_than_the_cache_are_counted_and_logged_missed_by_index(tmp_path, records, caplog):
    first, _ = live_diagnoser(tmp_path)
    send(first, *records[:2])
    again, published = live_diagnoser(tmp_path)
    with caplog.at_level(logging.WARNING, logger="railswitch.diagnoser"):
        send(again, *records[5:8])  # throws 2 to 4 ended longer ago than the cache holds
    assert published.diagnosed == [("sw1", 5), ("sw1", 6), ("sw1", 7)]
    assert again.counts["missed"] == 3
    assert [r.getMessage() for r in caplog.records if "missed" in r.getMessage()] == [
        "sw1 throws 2 to 4 missed: they ended while no diagnoser was listening, longer ago than the publisher "
        "keeps throws (and no recorder kept them)"]


def test_a_switch_whose_source_restarted_goes_on_without_a_missed_report(tmp_path, records):
    """A trackside unit restarted numbers its throws from 0 again, later in time: new throws, none missed."""
    first, _ = live_diagnoser(tmp_path)
    send(first, *records[:5])
    later = records[7].t_end_ns - records[0].t_start_ns
    renumbered = [r.model_copy(update={"throw_index": k, "t_start_ns": r.t_start_ns + later,
                                       "t_end_ns": r.t_end_ns + later}) for k, r in enumerate(records[:2])]
    again, published = live_diagnoser(tmp_path)
    send(again, *renumbered)
    assert published.diagnosed == [("sw1", 0), ("sw1", 1)]
    assert again.counts["missed"] == 0 and again.counts["already_diagnosed"] == 0


def stream_of(record: ThrowRecord) -> list:
    """The record as its unit would stream it: start event, one sample per time (seq from the start's nanoseconds
    over the sample period), end event."""
    start = ThrowEvent(switch_id=record.switch_id, throw_index=record.throw_index, direction=record.direction,
                       phase="start", t_ns=record.t_start_ns, reference_t_s=record.reference_t_s,
                       reference_velocity_rad_s=record.reference_velocity_rad_s)
    first = record.t_start_ns // (record.t_offset_ns[1] - record.t_offset_ns[0])
    samples = [MotorSample(switch_id=record.switch_id, seq=first + k, t_ns=record.t_start_ns + offset,
                           current_a=record.current_a[k], angle_rad=record.angle_rad[k],
                           velocity_rad_s=record.velocity_rad_s[k]) for k, offset in enumerate(record.t_offset_ns)]
    return [start, *samples, start.model_copy(update={"phase": "end", "t_ns": record.t_end_ns})]


def stream(live: LiveDiagnoser, *records: ThrowRecord) -> None:
    for record in records:
        for message in stream_of(record):
            live.handle(Received(key_expr(record.switch_id, "throw" if isinstance(message, ThrowEvent) else "motor"),
                                 encode(message), 0.0))


def heard(records: list, keep_s: float = 600.0) -> RecentThrows:
    """A recorder's recent throws after it heard these records' throws as sample streams."""
    recent = RecentThrows(keep_s=keep_s)
    for record in records:
        for message in stream_of(record):
            recent.feed(message)
    return recent


def recorders(recent: RecentThrows):
    """What the diagnoser's recover gets from the recorders on the bus (zenoh_bus.recent_throws): their kept throws
    of a switch that ended after a time, as records."""
    def recover(switch_id: str, after_ns: int) -> list[Received]:
        return [Received(key.replace("/recent", "/record"), payload, 0.0)
                for key, payload in recent.replies({"after_ns": str(after_ns)})
                if switch_id == "*" or key.split("/")[1] == switch_id]
    return recover


def test_a_stream_s_throws_that_no_diagnoser_heard_are_recovered_from_the_recorder_in_order(tmp_path, records):
    """The only diagnoser of a sample stream is down for throws 2 to 4; the recorder heard them. The restarted one
    diagnoses them from the recorder's before the next live throw, and reports none missed."""
    recent = heard(records)
    first, _ = live_diagnoser(tmp_path)
    stream(first, *records[:2])
    again, published = live_diagnoser(tmp_path, recover=recorders(recent))
    stream(again, *records[5:7])
    assert published.diagnosed == [("sw1", i) for i in range(2, 7)]
    assert again.counts["recovered"] == 3 and again.counts["missed"] == 0


def test_a_diagnoser_starting_after_all_were_down_diagnoses_what_the_recorder_kept_since_its_state(tmp_path, records):
    recent = heard(records[:6])
    first, _ = live_diagnoser(tmp_path)
    stream(first, *records[:3])
    again, published = live_diagnoser(tmp_path, recover=recorders(recent))
    again.catch_up()
    assert published.diagnosed == [("sw1", 3), ("sw1", 4), ("sw1", 5)]
    assert again.counts["recovered"] == 3 and again.counts["already_diagnosed"] == 3


def test_throws_the_recorder_no_longer_keeps_are_reported_missed(tmp_path, records):
    recent = heard(records[:6], keep_s=15.0)  # throws end 10 s apart: it keeps the latest two
    first, _ = live_diagnoser(tmp_path)
    stream(first, *records[:1])
    again, published = live_diagnoser(tmp_path, recover=recorders(recent))
    stream(again, *records[6:7])
    assert published.diagnosed == [("sw1", 4), ("sw1", 5), ("sw1", 6)]
    assert again.counts["recovered"] == 2 and again.counts["missed"] == 3


def test_a_live_diagnosis_s_latency_runs_from_its_throw_s_end_arriving(tmp_path, records):
    """latency_ms of a live diagnosis: how long the throw's end waited to be diagnosed (the diagnoser's clock) and the
    diagnosis itself, set in one place (fleet_diagnoser.Diagnoser.diagnose)."""
    store = BaselineStore("poly", tmp_path)
    published = Published()
    live = LiveDiagnoser(Diagnoser("poly", on_state=store.save, stored_state=store.load), published,
                         known=store.known, clock=lambda: 100.0)
    live.handle(Received(key_expr("sw1", "record"), encode(records[0]), 97.5))  # arrived 2.5 s ago
    latency = published.diagnoses[0].latency_ms
    assert 2500.0 < latency < 2500.0 + 60_000.0


class Failing(Diagnoser):
    """A real diagnoser whose diagnosis raises, as a broken estimator or a foreign state would."""

    def diagnose(self, throw, waited_s=0.0):
        raise FloatingPointError("overflow in the rollout")


def test_a_failed_diagnosis_is_published_unknown_with_its_latency_from_the_end_arriving(tmp_path, records):
    published = Published()
    live = LiveDiagnoser(Failing("poly"), published, clock=lambda: 100.0)
    live.handle(Received(key_expr("sw1", "record"), encode(records[0]), 97.5))  # arrived 2.5 s ago
    diagnosis = published.diagnoses[0]
    assert diagnosis.decision == "unknown" and "FloatingPointError" in diagnosis.reason
    assert diagnosis.latency_ms == pytest.approx(2500.0)
    assert live.counts["failed"] == 1
