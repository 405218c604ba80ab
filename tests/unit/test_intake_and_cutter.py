"""The intake and the throw cutter against any payload and any order of events (fuzzed)."""
from __future__ import annotations

import json

from hypothesis import given, settings
from hypothesis import strategies as st

from railswitch.schemas import (
    CHANNEL_MODELS,
    encode,
    key_expr,
)
from railswitch.services.adapters.zenoh_bus import Received
from railswitch.services.core.intake import Intake
from railswitch.services.core.throw_cutter import ThrowCutter
from tests.live import motor_sample, throw_event

KINDS = list(CHANNEL_MODELS)


# -- the schema layer and the intake, fuzzed --------------------------------------------------
@settings(max_examples=300, deadline=None)
@given(key=st.one_of(st.sampled_from([key_expr(s, k) for s in ("sw1", "ghost") for k in KINDS]), st.text(max_size=40)),
       payload=st.one_of(st.binary(max_size=300), st.dictionaries(
           st.sampled_from(["switch_id", "seq", "t_ns", "current_a", "angle_rad", "velocity_rad_s", "throw_index",
                            "direction", "phase", "reference_t_s", "reference_velocity_rad_s", "params", "x"]),
           st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=8),
                     st.lists(st.floats(), max_size=3)), max_size=8).map(lambda d: json.dumps(d).encode())))
def test_intake_turns_any_payload_into_a_message_or_a_counted_rejection(key, payload):
    import logging

    intake = Intake(logging.getLogger("fuzz"))
    message = intake.message(Received(key, payload, 0.0))  # never raises
    if message is not None:
        assert type(message) is CHANNEL_MODELS[key.split("/")[2]] and message.switch_id == key.split("/")[1]
    elif not key.startswith("railswitch/@service/"):
        assert sum(intake.rejected.values()) == 1  # every refusal is counted


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["sample", "start", "end"]), st.integers(0, 5),
                          st.integers(0, 100 * 10**9)), max_size=60))
def test_throw_cutter_survives_any_order_of_events_and_samples(steps):
    problems = []
    cutter = ThrowCutter(on_problem=lambda switch_id, reason: problems.append(reason))
    emitted = []
    for seq, (kind, index, t_ns) in enumerate(steps):
        message = motor_sample(seq, t_ns) if kind == "sample" else throw_event(kind, index, t_ns)
        throw = cutter.feed(message)
        if throw is not None:
            emitted.append(throw)
    emitted.extend(cutter.flush())
    starts = sum(1 for kind, _, _ in steps if kind == "start")
    assert len(emitted) <= starts
    assert all(t.end is None or t.end.throw_index == t.start.throw_index for t in emitted)


def test_a_sample_stream_survives_one_time_from_the_future():
    import logging

    intake = Intake(logging.getLogger("test"))
    key = key_expr("sw1", "motor")
    assert intake.message(Received(key, encode(motor_sample(0, 10)), 0.0)) is not None
    assert intake.message(Received(key, encode(motor_sample(1, 10**18)), 0.0)) is not None  # a bad clock value
    accepted = [intake.message(Received(key, encode(motor_sample(k, 10 + k)), 0.0)) for k in range(2, 102)]
    assert sum(m is not None for m in accepted) >= 50  # the genuine clock is followed again after a resync


def test_a_throw_without_an_end_is_emitted_incomplete_when_the_next_starts():
    cutter = ThrowCutter()
    assert cutter.feed(throw_event("start", 0, 0)) is None
    cutter.feed(motor_sample(1, 20_000_000))
    abandoned = cutter.feed(throw_event("start", 1, 10**9))
    assert abandoned is not None and abandoned.end is None and abandoned.start.throw_index == 0


def test_a_newer_publishers_fields_are_accepted_counted_per_kind_and_name_and_logged_once(caplog):
    import logging

    intake = Intake(logging.getLogger("test"))
    newer = {"unit_serial": "PM-4711", "contract": 2}
    for seq in range(3):
        payload = json.dumps(json.loads(encode(motor_sample(seq, 10 + seq))) | newer).encode()
        assert intake.message(Received(key_expr("sw1", "motor"), payload, 0.0)) is not None
    start = json.dumps(json.loads(encode(throw_event("start", 0, 10))) | {"unit_serial": "PM-4711"}).encode()
    assert intake.message(Received(key_expr("sw1", "throw"), start, 0.0)) is not None
    assert intake.ignored == {"motor: unit_serial": 3, "motor: contract=2": 3, "throw: unit_serial": 1}
    assert not intake.rejected
    logged = [r.getMessage() for r in caplog.records if "does not know" in r.getMessage()]
    assert len(logged) == 3 and any(line.endswith("motor: contract=2 (further ones are counted)") for line in logged)


def test_a_refused_payload_counts_as_rejected_not_as_ignored():
    import logging

    intake = Intake(logging.getLogger("test"))
    payload = json.dumps(json.loads(encode(motor_sample(0, 10, "sw2"))) | {"unit_serial": "PM-4711"}).encode()
    assert intake.message(Received(key_expr("sw1", "motor"), payload, 0.0)) is None
    assert intake.rejected == {"motor: switch_id differs from the key": 1} and not intake.ignored
