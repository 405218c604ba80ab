"""The message contract: validation, JSON round trips, schema export and key expressions."""

import json
import math
from typing import Literal

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import BaseModel, ValidationError

from railswitch.schemas import (CHANNEL_MODELS, CONTRACT_VERSION, DECISIONS, FAULT_PARAMETERS, MODE_PARAMETERS,
                                Commissioning, Diagnosis, FaultCommand, FaultEstimate, FaultTruth, Hypothesis,
                                Message, MessageError, MotorSample, ThrowEvent, check_fault_value, decode,
                                decode_counted, encode, json_schema, key_expr, parse_key_expr)

NAN, INF = float("nan"), float("inf")

MOTOR = MotorSample(
    switch_id="sw-1",
    seq=7,
    t_ns=1_500_000_000,
    current_a=2.5,
    angle_rad=-0.25,
    velocity_rad_s=150.0,
)
THROW = ThrowEvent(
    switch_id="sw-1",
    throw_index=0,
    direction="left_to_right",
    phase="start",
    t_ns=0,
    reference_t_s=[0.0, 0.5, 6.5, 7.0],
    reference_velocity_rad_s=[0.0, 150.0, 150.0, 0.0],
)
TRUTH = FaultTruth(switch_id="sw-1", t_ns=0, left_bolt_offset=0.05, obstacle_friction=1e5)
COMMAND = FaultCommand(switch_id="sw-1", params={"bearing_friction": 5000.0}, reset=True)
HYPOTHESIS = Hypothesis(
    mode="left_bolt", params={"left_bolt_offset": 0.051}, std={"left_bolt_offset": 0.002}, mse=0.01
)
DIAGNOSIS = Diagnosis(
    switch_id="sw-1",
    throw_index=3,
    direction="right_to_left",
    t_start_ns=10,
    t_end_ns=7_000_000_010,
    model="poly",
    decision="left_bolt",
    hypotheses=[HYPOTHESIS, Hypothesis(mode="nominal", params={}, mse=0.4)],
    joint=Hypothesis(mode="joint", params=dict.fromkeys(FAULT_PARAMETERS, 0.0), mse=0.02),
    latency_ms=12.5,
)
EXAMPLES: list[BaseModel] = [MOTOR, THROW, TRUTH, COMMAND, HYPOTHESIS, DIAGNOSIS]


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_every_model_round_trips_through_encode_and_decode(msg: BaseModel) -> None:
    assert decode(type(msg), encode(msg)) == msg


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_every_model_round_trips_through_pydantic_json(msg: BaseModel) -> None:
    assert type(msg).model_validate_json(msg.model_dump_json()) == msg


def test_encode_is_compact_utf8_json() -> None:
    data = encode(MOTOR)
    assert b" " not in data
    assert json.loads(data.decode("utf-8"))["current_a"] == 2.5


@pytest.mark.parametrize("bad", [NAN, INF, -INF])
def test_nan_and_inf_rejected_in_scalar_fields(bad: float) -> None:
    with pytest.raises(ValidationError, match="finite"):
        MotorSample.model_validate(MOTOR.model_dump() | {"current_a": bad})
    with pytest.raises(ValidationError, match="finite"):
        Diagnosis.model_validate(DIAGNOSIS.model_dump() | {"latency_ms": bad})


@pytest.mark.parametrize("field", ["reference_t_s", "reference_velocity_rad_s"])
@pytest.mark.parametrize("bad", [NAN, INF])
def test_nan_and_inf_rejected_inside_reference_lists(field: str, bad: float) -> None:
    with pytest.raises(ValidationError, match="finite"):
        ThrowEvent.model_validate(THROW.model_dump() | {field: [0.0, bad, 7.0, 8.0]})


@pytest.mark.parametrize("field", ["params", "std"])
@pytest.mark.parametrize("bad", [NAN, INF])
def test_nan_and_inf_rejected_inside_hypothesis_dicts(field: str, bad: float) -> None:
    with pytest.raises(ValidationError, match="finite"):
        Hypothesis.model_validate(HYPOTHESIS.model_dump() | {field: {"left_bolt_offset": bad}})


def test_nan_literal_in_json_payload_is_a_message_error() -> None:
    payload = encode(MOTOR).replace(b"150.0", b"NaN")
    with pytest.raises(MessageError, match="validation: velocity_rad_s: Input should be a finite"):
        decode(MotorSample, payload)


@pytest.mark.parametrize(
    "make",
    [
        lambda: FaultCommand(switch_id="a", params={"bolt_offset": 0.1}),
        lambda: Hypothesis(mode="joint", params={"bolt_offset": 0.1}, mse=0.0),
        lambda: Hypothesis(mode="joint", params={}, std={"bolt_offset": 0.1}, mse=0.0),
    ],
)
def test_unknown_fault_name_rejected_naming_it(make) -> None:
    with pytest.raises(ValidationError, match="unknown fault parameter 'bolt_offset'; accepted: "):
        make()


def test_out_of_range_fault_value_rejected_with_the_range() -> None:
    with pytest.raises(ValidationError, match="left_bolt_offset=0.5 is outside .* -0.02 … 0.2 m"):
        FaultCommand(switch_id="a", params={"left_bolt_offset": 0.5})
    with pytest.raises(ValidationError, match="obstacle_friction=400000 .* 0 … 300000 N·s/m"):
        FaultTruth(switch_id="a", t_ns=0, obstacle_friction=4e5)
    with pytest.raises(ValidationError, match="obstacle_position=1 .* 1.02 … 1.18 m"):
        FaultTruth(switch_id="a", t_ns=0, obstacle_position=1.0)


def test_hypothesis_accepts_values_at_or_past_a_bound_but_not_negative_std() -> None:
    assert Hypothesis(mode="left_bolt", params={"left_bolt_offset": 0.25}, mse=0.0)
    with pytest.raises(ValidationError, match="greater than or equal to 0"):
        Hypothesis(mode="left_bolt", params={}, std={"left_bolt_offset": -0.1}, mse=0.0)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("abc", "left_bolt_offset='abc' is not a number"),
        (NAN, "left_bolt_offset=nan is not a finite number"),
        (0.5, "left_bolt_offset=0.5 is outside the accepted range -0.02 … 0.2 m"),
    ],
)
def test_check_fault_value_message_is_one_standalone_line(value: object, message: str) -> None:
    with pytest.raises(ValueError) as info:
        check_fault_value("left_bolt_offset", value)  # type: ignore[arg-type]
    assert str(info.value) == message


def test_check_fault_value_parses_command_line_text() -> None:
    assert check_fault_value("bearing_friction", "2500") == 2500.0
    with pytest.raises(ValueError, match="^unknown fault parameter 'foo'; accepted: left_bolt"):
        check_fault_value("foo", 1.0)


def test_fault_table_matches_the_contract() -> None:
    table = {p.name: (p.mode, p.unit, p.nominal, p.low, p.high) for p in FAULT_PARAMETERS.values()}
    assert table == {
        "left_bolt_offset": ("left_bolt", "m", 0, -0.02, 0.20),
        "right_bolt_offset": ("right_bolt", "m", 0, -0.02, 0.20),
        "bearing_friction": ("missing_bearing", "N·s/m", 0, 0, 10_000),
        "obstacle_friction": ("obstacle", "N·s/m", 0, 0, 300_000),
        "obstacle_position": ("obstacle", "m", 1.10, 1.02, 1.18),
        "drive_friction_nm": ("drive_friction", "N·m", 0, 0, 0.30),
    }
    assert MODE_PARAMETERS["obstacle"] == ("obstacle_friction", "obstacle_position")
    assert DECISIONS == ("nominal", *MODE_PARAMETERS, "unknown")


def test_fault_truth_fills_nominal_position_and_lists_active_modes() -> None:
    assert TRUTH.params()["obstacle_position"] == 1.10
    assert TRUTH.active_modes() == ["left_bolt", "obstacle"]
    assert FaultTruth(switch_id="a", t_ns=0, obstacle_position=1.05).active_modes() == []


def test_fault_command_needs_params_unless_reset() -> None:
    with pytest.raises(ValidationError, match="at least one entry unless reset"):
        FaultCommand(switch_id="a")
    assert FaultCommand(switch_id="a", reset=True).params == {}


@pytest.mark.parametrize("bad_id", ["", "a/b", "sw*", "$x", "a?", "a#", "a b", "x" * 65])
def test_bad_switch_id_rejected_with_reason(bad_id: str) -> None:
    with pytest.raises(ValidationError, match="Zenoh key expression"):
        MotorSample.model_validate(MOTOR.model_dump() | {"switch_id": bad_id})


def test_unknown_decision_needs_a_reason() -> None:
    base = DIAGNOSIS.model_dump() | {"decision": "unknown"}
    for reason in (None, "", "  "):
        with pytest.raises(ValidationError, match="needs a non-empty reason"):
            Diagnosis.model_validate(base | {"reason": reason})
    assert Diagnosis.model_validate(base | {"reason": "cut short"}).reason == "cut short"


def test_diagnosis_cannot_end_before_it_starts() -> None:
    with pytest.raises(ValidationError, match="t_end_ns is before t_start_ns"):
        Diagnosis.model_validate(DIAGNOSIS.model_dump() | {"t_end_ns": 9})


@pytest.mark.parametrize(
    ("times", "speeds", "message"),
    [
        ([0.0, 1.0], [0.0, 1.0, 2.0], "differ in length"),
        ([0.5, 1.0], [0.0, 1.0], "must start at 0"),
        ([0.0, 2.0, 1.0], [0.0, 1.0, 1.0], "non-decreasing"),
        ([0.0], [0.0], "at least 2 items"),
        ([0.0, *range(1, 10_001)], [0.0] * 10_001, "at most 10000 items"),
    ],
)
def test_bad_reference_profile_rejected(
    times: list[float], speeds: list[float], message: str
) -> None:
    fields = {"reference_t_s": times, "reference_velocity_rad_s": speeds}
    with pytest.raises(ValidationError, match=message):
        ThrowEvent.model_validate(THROW.model_dump() | fields)


def test_unknown_fields_are_ignored_and_named_and_messages_frozen() -> None:
    """A newer publisher's extra field neither silences an older subscriber nor passes through unseen."""
    payload = json.dumps(MOTOR.model_dump() | {"unit_serial": "PM-4711", "torque_nm": 1.0}).encode()
    message, extras, encoded = decode_counted(MotorSample, payload)
    assert message == MOTOR and extras == ["torque_nm", "unit_serial"]
    assert "unit_serial" not in encode(message).decode()  # what we pass on is what we understood
    assert encoded == encode(message)  # what a store keeps of it, too
    with pytest.raises(ValidationError, match="frozen"):
        MOTOR.seq = 8  # type: ignore[misc]


def test_a_current_only_sample_and_a_contract_version_are_accepted() -> None:
    sample = decode(MotorSample, b'{"switch_id": "sw1", "seq": 3, "t_ns": 5, "current_a": 1.5}')
    assert sample.angle_rad is None and sample.velocity_rad_s is None and sample.contract == 1
    with pytest.raises(MessageError, match="contract"):
        decode(MotorSample, b'{"switch_id": "sw1", "seq": 3, "t_ns": 5, "current_a": 1.5, "contract": 0}')


NESTED = Diagnosis.model_validate(DIAGNOSIS.model_dump() | {
    "estimate": FaultEstimate(mode="left_bolt", params={"left_bolt_offset": 0.05}, throws=2, since_throw=1),
    "commissioning": Commissioning(state="provisional", throws={"left_to_right": 1}, needed=4)})


VALUE_MAPS = ("params", "std", "nuisance", "throws", "plant", "accepted")  # objects of values, not nested messages
EXTRA = {"unit_serial": "PM-4711"}


def with_extras(payload: dict) -> dict:
    """payload with a newer publisher's field in it and in every message nested in it (alone or in a list)."""
    def nested(key: str, value: object) -> object:
        if isinstance(value, dict) and key not in VALUE_MAPS:
            return with_extras(value)
        if isinstance(value, list):
            return [with_extras(item) if isinstance(item, dict) else item for item in value]
        return value

    return {**EXTRA, **{key: nested(key, value) for key, value in payload.items()}}


@pytest.mark.parametrize(
    ("msg", "nested"),
    [*((m, []) for m in EXAMPLES if not isinstance(m, Diagnosis)),
     (DIAGNOSIS, ["hypotheses", "joint"]),
     (NESTED, ["commissioning", "estimate", "hypotheses", "joint"])],
    ids=lambda v: type(v).__name__ if isinstance(v, BaseModel) else "-".join(v) or "top-level",
)
def test_extra_fields_at_any_depth_are_ignored_and_named_once_by_their_dotted_path(msg, nested) -> None:
    """Two hypotheses carrying the field name it once: the count is of payloads, not of objects in them."""
    message, unknown, _ = decode_counted(type(msg), json.dumps(with_extras(json.loads(encode(msg)))).encode())
    assert message == msg
    assert unknown == [*(f"{name}.unit_serial" for name in nested), "unit_serial"]


def test_a_newer_contract_is_read_as_far_as_known_and_named() -> None:
    payload = json.dumps(MOTOR.model_dump() | {"contract": CONTRACT_VERSION + 1, "torque_nm": 1.0}).encode()
    message, unknown, _ = decode_counted(MotorSample, payload)
    assert message.current_a == MOTOR.current_a and message.contract == CONTRACT_VERSION + 1
    assert unknown == ["torque_nm", f"contract={CONTRACT_VERSION + 1}"]
    assert decode_counted(MotorSample, encode(MOTOR)) == (MOTOR, [], encode(MOTOR))


@pytest.mark.parametrize(
    ("model_cls", "payload", "reason"),
    [
        (MotorSample, MOTOR.model_dump() | {"current_a": "high"}, "current_a: Input should be a valid number"),
        (MotorSample, {"switch_id": "sw-1", "seq": 1}, "t_ns: Field required"),
        (MotorSample, MOTOR.model_dump() | {"current_a": 1e12}, "current_a: Input should be less than or equal"),
        (ThrowEvent, THROW.model_dump() | {"direction": "up"}, "direction: Input should be 'left_to_right'"),
        (Diagnosis, DIAGNOSIS.model_dump() | {"hypotheses": [{"mode": "nominal", "params": {}, "mse": -1.0}]},
         "hypotheses.0.mse: Input should be greater than or equal to 0"),
        (Diagnosis, NESTED.model_dump() | {"estimate": {"mode": "left_bolt", "params": {}, "throws": 0,
                                                        "since_throw": 0}}, "estimate.throws: Input should be"),
        (MotorSample, MOTOR.model_dump() | {"contract": 1001}, "contract: Input should be less than or equal"),
    ],
)
def test_extra_fields_do_not_excuse_a_wrong_type_a_missing_field_or_an_absurd_value(model_cls, payload, reason):
    with pytest.raises(MessageError, match=f"^validation: {reason}"):
        decode_counted(model_cls, json.dumps(with_extras(payload)).encode())


def test_a_non_finite_value_beside_extra_fields_is_refused() -> None:
    payload = json.dumps(with_extras(MOTOR.model_dump())).replace('"current_a": 2.5', '"current_a": NaN')
    with pytest.raises(MessageError, match="validation: current_a: Input should be a finite number"):
        decode_counted(MotorSample, payload.encode())


@pytest.mark.parametrize("model_cls", CHANNEL_MODELS.values(), ids=lambda c: c.__name__)
def test_json_schema_is_deterministic_json_naming_every_field(
    model_cls: type[BaseModel],
) -> None:
    text = json_schema(model_cls)
    assert text == json_schema(model_cls)
    assert set(json.loads(text)["properties"]) == set(model_cls.model_fields)
    assert text == json.dumps(json.loads(text), sort_keys=True, separators=(",", ":"))


def test_key_expr_round_trips() -> None:
    for kind in CHANNEL_MODELS:
        assert parse_key_expr(key_expr("Switch_07", kind)) == ("Switch_07", kind)
    assert key_expr("sw-1", "motor") == "railswitch/sw-1/motor"


@pytest.mark.parametrize(
    "key",
    [
        "railswitch/sw1",
        "railswitch/sw1/motor/x",
        "other/sw1/motor",
        "railswitch/sw1/speed",
        "railswitch/*/motor",
        "railswitch//motor",
    ],
)
def test_parse_key_expr_rejects_other_keys(key: str) -> None:
    with pytest.raises(ValueError, match="key 'railswitch/|is not of the form"):
        parse_key_expr(key)


def test_key_expr_rejects_unknown_kind_and_bad_id() -> None:
    with pytest.raises(ValueError, match="unknown channel kind 'speed'"):
        key_expr("sw1", "speed")
    with pytest.raises(ValueError, match="Zenoh key expression"):
        key_expr("sw/1", "motor")


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"\xff\xfe", "not utf-8"),
        (b'{"switch_id":', "not json"),
        (b"[]", "validation: Input should be an object"),
    ],
)
def test_decode_gives_short_reasons(data: bytes, reason: str) -> None:
    with pytest.raises(MessageError) as info:
        decode(MotorSample, data)
    assert str(info.value) == reason


def bounded(limit: float) -> st.SearchStrategy[float]:
    return st.floats(-limit, limit, allow_nan=False, allow_infinity=False)


@given(current=bounded(1e4), angle=bounded(1e6), velocity=bounded(1e5), t_ns=st.integers(0, 2**63 - 1))
def test_any_plausible_motor_sample_round_trips_exactly(
    current: float, angle: float, velocity: float, t_ns: int
) -> None:
    msg = MotorSample(
        switch_id="sw1",
        seq=0,
        t_ns=t_ns,
        current_a=current,
        angle_rad=angle,
        velocity_rad_s=velocity,
    )
    back = decode(MotorSample, encode(msg))
    assert back == msg
    assert math.copysign(1.0, back.current_a) == math.copysign(1.0, current)


@given(field=st.sampled_from(["current_a", "angle_rad", "velocity_rad_s"]),
       value=st.floats(1e6, 1e308) | st.floats(-1e308, -1e6))
def test_absurd_motor_values_are_rejected(field: str, value: float) -> None:
    values = {"current_a": 0.0, "angle_rad": 0.0, "velocity_rad_s": 0.0, field: value}
    if abs(value) <= {"current_a": 1e4, "angle_rad": 1e6, "velocity_rad_s": 1e5}[field]:
        return
    with pytest.raises(MessageError, match=field):
        decode(MotorSample, json.dumps({"switch_id": "sw1", "seq": 0, "t_ns": 0, **values}).encode())


@given(data=st.one_of(st.binary(max_size=200), st.text(max_size=200).map(str.encode)))
def test_arbitrary_bytes_decode_to_a_model_or_message_error(data: bytes) -> None:
    for model_cls in CHANNEL_MODELS.values():
        try:
            assert isinstance(decode_counted(model_cls, data)[0], model_cls)
        except MessageError:
            pass


class OlderCommissioning(Message):
    """Commissioning as contract 1 had it before several faults were told apart."""

    state: Literal["provisional", "commissioned"]
    throws: dict[Literal["left_to_right", "right_to_left"], int]
    needed: int
    outside_population: list[str] = []


class OlderDiagnosis(Message):
    """The Diagnosis an older reader knows: one fault at most (contract 1 before `faults`, `estimates`, `without`)."""

    switch_id: str
    throw_index: int
    direction: Literal["left_to_right", "right_to_left"]
    t_start_ns: int
    t_end_ns: int
    model: str
    decision: str
    reason: str | None = None
    hypotheses: list[Hypothesis] = []
    joint: Hypothesis | None = None
    estimate: FaultEstimate | None = None
    commissioning: OlderCommissioning | None = None
    signals: list[str] = []
    latency_ms: float


BOLT_ESTIMATE = FaultEstimate(mode="left_bolt", params={"left_bolt_offset": 0.044}, std={"left_bolt_offset": 0.001},
                              throws=3, since_throw=20)
SEVERAL = Diagnosis.model_validate(DIAGNOSIS.model_dump() | {
    "decision": "left_bolt", "faults": ["left_bolt", "missing_bearing"],
    "estimates": [BOLT_ESTIMATE, FaultEstimate(mode="missing_bearing", params={"bearing_friction": 3100.0},
                                               throws=9, since_throw=10)],
    "estimate": BOLT_ESTIMATE,
    "without": [Hypothesis(mode="missing_bearing", params={}, mse=0.03)],
    "commissioning": Commissioning(state="commissioned", throws={"left_to_right": 4, "right_to_left": 4}, needed=4,
                                   accepted={"drive_friction": {"drive_friction_nm": 0.05}})})


def test_an_older_reader_reads_a_diagnosis_of_several_faults_as_its_newest_and_counts_what_it_does_not_know() -> None:
    older, unknown, _ = decode_counted(OlderDiagnosis, encode(SEVERAL))
    assert older.decision == "left_bolt" and older.estimate == BOLT_ESTIMATE
    assert older.commissioning.state == "commissioned"
    assert unknown == ["anomalies", "commissioning.accepted", "commissioning.standing", "estimates", "faults", "features",
                       "tag", "without"]


def test_a_diagnosis_written_before_several_faults_reads_as_faults_unknown() -> None:
    written = json.dumps({k: v for k, v in json.loads(encode(DIAGNOSIS)).items()
                          if k not in ("faults", "estimates", "without")}).encode()
    read = decode(Diagnosis, written)
    assert read.faults is None and read.estimates == [] and read.decision == "left_bolt"
    assert decode(Diagnosis, encode(SEVERAL)) == SEVERAL
