"""What a diagnoser does with throws a publisher's cache replays after an outage (docs/contracts.md section 3,
Catching up): a real diagnoser and its switch states on disk, records of the shipped nominal recording, no bus."""
from __future__ import annotations

import logging

import pytest

from railswitch.schemas import encode, key_expr
from railswitch.services.adapters.baseline_store import BaselineStore
from railswitch.services.adapters.zenoh_bus import Received
from railswitch.services.core.fleet_diagnoser import Diagnoser
from railswitch.services.core.live_diagnoser import LiveDiagnoser
from tests.live import RecordSource


class Published:
    """The diagnoses a LiveDiagnoser puts on the bus, by (switch, throw index)."""

    def __init__(self):
        self.diagnosed: list[tuple[str, int]] = []
        self.published = 0

    def put(self, key: str, message) -> None:
        if key.endswith("/diagnosis"):
            self.diagnosed.append((message.switch_id, message.throw_index))


@pytest.fixture()
def records():
    source = RecordSource()
    return [source.next("sw1") for _ in range(8)]


def live_diagnoser(tmp_path) -> tuple[LiveDiagnoser, Published]:
    store = BaselineStore("poly", tmp_path)
    published = Published()
    return LiveDiagnoser(Diagnoser("poly", on_state=store.save, stored_state=store.load), published,
                         known=store.known), published


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
        "keeps throws"]


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
