"""Throws as records: a record and the sample stream cut into the same throw, and the intake refusing malformed
records by reason (services/core/records.py, services/core/intake.py)."""
from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from railswitch.schemas import MAX_RECORD_SAMPLES, ThrowRecord, encode, key_expr
from railswitch.services.adapters.recordings import load_recording
from railswitch.services.adapters.zenoh_bus import Received
from railswitch.services.core.intake import Intake
from railswitch.services.core.records import record_of_throw, throw_of_record
from railswitch.services.core.throw_cutter import cut_throws
from tests.live import ROOT

RECORDING = ROOT / "recordings" / "left_bolt.mcap"


@pytest.fixture(scope="module")
def streamed():
    """The complete throws of a committed recording, cut from its sample stream."""
    return [t for t in cut_throws(load_recording(RECORDING).messages) if t.complete]


def test_a_record_on_the_bus_cuts_into_the_throw_its_samples_would_have_given(streamed):
    for throw in streamed:
        back = throw_of_record(ThrowRecord.model_validate_json(encode(record_of_throw(throw))))
        assert (back.start, back.end.t_ns, back.missing_samples) == (throw.start, throw.end.t_ns, 0)
        assert np.array_equal(back.t_s, throw.t_s)  # bit for bit: whole nanoseconds either way
        assert back.signals.names == throw.signals.names
        for name in throw.signals.names:
            assert np.array_equal(getattr(back.signals, name), getattr(throw.signals, name))


def test_a_current_only_record_cuts_into_a_current_only_throw(streamed):
    record = record_of_throw(streamed[0]).model_copy(update={"angle_rad": None, "velocity_rad_s": None})
    assert throw_of_record(record).signals.names == ("current_a",)


def record_payload(n: int = 351, **changes) -> dict:
    """A record of n samples at 1 kHz, as JSON fields; measured values print with 17 significant digits."""
    t_offset = [k * 1_000_000 for k in range(n)]
    rng = np.random.default_rng(0)
    payload = {"switch_id": "sw1", "throw_index": 0, "direction": "left_to_right", "t_start_ns": 10**18,
               "t_end_ns": 10**18 + t_offset[-1], "reference_t_s": [0.0, 0.4, 6.0, 6.4, 7.0],
               "reference_velocity_rad_s": [0.0, 30.0, 30.0, 0.0, 0.0], "t_offset_ns": t_offset,
               "current_a": rng.normal(3.0, 0.1, n).tolist(), "angle_rad": rng.normal(100.0, 10.0, n).tolist(),
               "velocity_rad_s": rng.normal(-30.0, 1.0, n).tolist()}
    return {**payload, **changes}


def offer(intake: Intake, payload: dict | bytes):
    data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
    return intake.message(Received(key_expr("sw1", "record"), data, 0.0))


def test_a_15_s_record_at_1_khz_with_three_signals_is_accepted_though_over_1_mib():
    payload = json.dumps(record_payload(15_001)).encode()
    assert len(payload) > 1 << 20
    intake = Intake(logging.getLogger("test"))
    assert isinstance(offer(intake, payload), ThrowRecord) and not intake.rejected


@pytest.mark.parametrize("changes, reason", [
    ({"current_a": [1.0] * 350}, "record: validation: Value error, current_a has 350 samples for 351 times"),
    ({"t_offset_ns": [0, 2_000_000, 1_000_000] + [k * 1_000_000 for k in range(3, 351)]},
     "record: validation: Value error, t_offset_ns must increase"),
    ({"t_end_ns": 10**18 - 1}, "record: validation: Value error, samples after the throw's end, or an end before its start"),
    ({"current_a": [1e9] * 351}, "record: validation: current_a.0: Input should be less than or equal to 10000"),
])
def test_a_malformed_record_is_refused_and_counted_by_reason(changes, reason):
    intake = Intake(logging.getLogger("test"))
    assert offer(intake, record_payload(**changes)) is None
    assert intake.rejected == {reason: 1}


def test_a_record_of_too_many_samples_is_refused():
    intake = Intake(logging.getLogger("test"))
    n = MAX_RECORD_SAMPLES + 1
    assert offer(intake, record_payload(n, angle_rad=None, velocity_rad_s=None)) is None
    assert list(intake.rejected) == ["record: validation: t_offset_ns: List should have at most 20000 items after "
                                     "validation, not 20001"]


def test_megabytes_of_record_are_refused_unread():
    intake = Intake(logging.getLogger("test"))
    assert offer(intake, b'{"pad": "' + b"x" * (5 << 20) + b'"}') is None
    assert intake.rejected == {"record: payload over 4 MiB": 1}


def test_a_repeated_record_is_refused_as_a_retried_upload():
    intake = Intake(logging.getLogger("test"))
    assert offer(intake, record_payload()) is not None
    assert offer(intake, record_payload()) is None
    later = record_payload(t_start_ns=10**18 + 60 * 10**9, t_end_ns=10**18 + 67 * 10**9)
    assert offer(intake, later) is not None
    assert intake.rejected == {"record: start not after the previous record's (repeated or going back)": 1}


def test_a_record_whose_times_do_not_fit_64_bits_is_refused_before_it_reaches_an_array():
    # Valid for the schema (times are unbounded integers), but its offsets overflow the int64 arrays of the
    # diagnoser: it once raised OverflowError in the diagnoser's loop and stopped the service.
    offsets = [0] + [10**25 + k for k in range(1, 351)]
    intake = Intake(logging.getLogger("test"))
    assert offer(intake, record_payload(t_start_ns=0, t_end_ns=10**30, t_offset_ns=offsets)) is None
    assert intake.rejected == {"record: time or throw index beyond 64 bits": 1}
