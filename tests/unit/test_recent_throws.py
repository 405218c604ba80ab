"""The recorder's recent throws of a sample stream (services/core/recent_throws.py): the shipped recording's stream
cut into records as the diagnoser would cut it, kept by the switch's own time, filtered by end time."""
from __future__ import annotations

from railswitch.schemas import MotorSample, ThrowEvent, ThrowRecord
from railswitch.services.adapters.recordings import load_recording
from railswitch.services.core.recent_throws import RecentThrows
from railswitch.services.core.records import record_of_throw
from railswitch.services.core.throw_cutter import cut_throws
from tests.live import ROOT

MESSAGES = load_recording(ROOT / "recordings" / "nominal.mcap").messages


def kept(recent: RecentThrows, **parameters: str) -> list[ThrowRecord]:
    return [ThrowRecord.model_validate_json(payload) for _, payload in recent.replies(parameters)]


def test_a_stream_s_complete_throws_are_kept_as_the_records_its_cut_throws_make():
    recent = RecentThrows(keep_s=600.0)
    for message in MESSAGES:
        recent.feed(message)
    expected = [record_of_throw(t) for t in cut_throws(MESSAGES) if t.complete]
    assert len(expected) == 2 and kept(recent) == expected
    assert [key for key, _ in recent.replies({})] == ["railswitch/sw1/recent"] * 2
    assert kept(recent, after_ns=str(expected[0].t_end_ns)) == expected[1:]  # ended after: the second only
    assert kept(recent, after_ns="soon") == [] and recent.bad_queries == 1


def test_throws_older_than_the_window_go_and_a_throw_heard_incomplete_is_not_kept():
    first_end = next(m.t_ns for m in MESSAGES if isinstance(m, ThrowEvent) and m.phase == "end")
    second_end = [m.t_ns for m in MESSAGES if isinstance(m, ThrowEvent) and m.phase == "end"][1]
    recent = RecentThrows(keep_s=(second_end - first_end) * 1e-9 - 0.5)
    for message in MESSAGES:
        recent.feed(message)
    assert [r.t_end_ns for r in kept(recent)] == [second_end]
    lossy = RecentThrows(keep_s=600.0)
    samples = [m for m in MESSAGES if isinstance(m, MotorSample)]
    for message in MESSAGES:
        if message is not samples[len(samples) // 4]:  # a sample lost inside the first throw
            lossy.feed(message)
    assert len(kept(lossy)) == 1 and lossy.not_kept == 1
    assert RecentThrows(keep_s=0.0).replies({}) == []
