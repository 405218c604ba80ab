"""Pydantic models of every payload on the bus and every MCAP channel (docs/contracts.md sections 3 and 4)."""

import json
import re
from typing import Annotated, Generic, Literal, NamedTuple, Self, TypeVar

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from railswitch.schemas.plant import PLANT_PARAMETERS, check_plant_values
from railswitch.schemas.faults import (
    FAULT_MODES,
    FAULT_PARAMETERS,
    Decision,
    FaultMode,
    RailModel,
    check_fault_name,
    check_fault_value,
)

M = TypeVar("M", bound=BaseModel)

SWITCH_ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"


def check_switch_id(value: str) -> str:
    """Return value if it can stand as one chunk of a Zenoh key expression; else ValueError."""
    if not re.fullmatch(SWITCH_ID_PATTERN, value):
        raise ValueError(
            f"switch_id {value!r} must be 1 to 64 letters, digits, '_' or '-' "
            "(it becomes part of a Zenoh key expression)"
        )
    return value


def _check_fault_names(params: dict[str, float]) -> dict[str, float]:
    """Reject keys that are not fault parameter names, naming the bad one."""
    for name in params:
        check_fault_name(name)
    return params


def _check_fault_values(params: dict[str, float]) -> dict[str, float]:
    """Reject unknown names and out-of-range values, as the plant would."""
    return {name: check_fault_value(name, value) for name, value in params.items()}


# Finite floats everywhere come from the model config (allow_inf_nan=False), which also
# reaches list items and dict values; tests/test_schemas.py holds that to account.
SwitchId = Annotated[
    str, AfterValidator(check_switch_id), Field(json_schema_extra={"pattern": SWITCH_ID_PATTERN})
]
TimeNs = Annotated[int, Field(ge=0, description="nanoseconds")]
Index = Annotated[int, Field(ge=0)]
NonNegative = Annotated[float, Field(ge=0)]
Profile = Annotated[list[float], Field(min_length=2, max_length=10_000)]
Direction = Literal["left_to_right", "right_to_left"]
MaybeNonNegative = NonNegative | None


CONTRACT_VERSION = 1  # of every message kind; docs/contracts.md says what a new version may change


class Message(BaseModel):
    """Common base: immutable, no NaN or infinity anywhere, unknown fields ignored.

    A newer publisher may add fields: an older subscriber reads what it knows and drops the rest
    (decode_counted names them, so services count them per field name). Every payload carries the
    contract version it was written to; a newer one is read as far as this version understands it."""

    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True)

    # A payload without it predates the field: version 1. While CONTRACT_VERSION is 1 the default says so;
    # a bump must keep reading a missing version as 1 (tests/unit/test_messages.py holds that to account).
    contract: Annotated[int, Field(ge=1, le=1000)] = CONTRACT_VERSION


# Bounds far beyond any point machine (amperes, radians, rad/s): what lies outside is junk.
Current = Annotated[float, Field(ge=-1e4, le=1e4)]
Angle = Annotated[float, Field(ge=-1e6, le=1e6)]
AngularVelocity = Annotated[float, Field(ge=-1e5, le=1e5)]


class MotorSample(Message):
    """One sample of the point machine's motor: current and, where the unit logs them, angle and angular
    velocity (many installed monitoring units log the current alone)."""

    switch_id: SwitchId
    seq: Index
    t_ns: TimeNs
    current_a: Current
    angle_rad: Angle | None = None
    velocity_rad_s: AngularVelocity | None = None


def _check_profile_breakpoints(t: list[float], velocity: list[float]) -> None:
    """Breakpoints pair up, start at the throw's start and never go back in time."""
    if len(t) != len(velocity):
        raise ValueError("reference_t_s and reference_velocity_rad_s differ in length")
    if t[0] != 0.0:
        raise ValueError("reference_t_s must start at 0")
    if any(b < a for a, b in zip(t, t[1:])):
        raise ValueError("reference_t_s must be non-decreasing")


class ThrowEvent(Message):
    """Start or end of a throw, with the motor's piecewise-linear reference velocity profile."""

    switch_id: SwitchId
    throw_index: Index
    direction: Direction
    phase: Literal["start", "end"]
    t_ns: TimeNs
    reference_t_s: Profile
    reference_velocity_rad_s: Profile

    @model_validator(mode="after")
    def _check_profile(self) -> Self:
        _check_profile_breakpoints(self.reference_t_s, self.reference_velocity_rad_s)
        return self


class FaultTruth(Message):
    """The fault parameters injected in the plant at t_ns, published for evaluation."""

    switch_id: SwitchId
    t_ns: TimeNs
    left_bolt_offset: float = 0.0
    right_bolt_offset: float = 0.0
    bearing_friction: float = 0.0
    obstacle_friction: float = 0.0
    obstacle_position: float | None = None
    drive_friction_nm: float = 0.0
    # The switch's own build and weather where they are not nominal (schemas/plant.py), as simulated.
    plant: Annotated[dict[str, float], AfterValidator(check_plant_values)] = {}

    @field_validator(*FAULT_PARAMETERS)
    @classmethod
    def _check_range(cls, value: float | None, info: ValidationInfo) -> float | None:
        """Every value set lies in the range of docs/contracts.md section 2."""
        return None if value is None else check_fault_value(str(info.field_name), value)

    def params(self) -> dict[str, float]:
        """Every fault parameter, obstacle_position falling back to its nominal when unset."""
        values = self.model_dump(include=set(FAULT_PARAMETERS))
        if values["obstacle_position"] is None:
            values["obstacle_position"] = FAULT_PARAMETERS["obstacle_position"].nominal
        return values

    def active_modes(self) -> list[FaultMode]:
        """Modes with a parameter off nominal; an obstacle counts only with friction > 0."""
        values = self.params()
        values.pop("obstacle_position")  # where an obstacle would sit is no fault by itself
        changed = {
            FAULT_PARAMETERS[n].mode for n, v in values.items() if v != FAULT_PARAMETERS[n].nominal
        }
        return [m for m in FAULT_MODES if m in changed]


class FaultCommand(Message):
    """Set fault parameters of a live simulator; reset first returns the others to nominal."""

    switch_id: SwitchId
    params: Annotated[dict[str, float], AfterValidator(_check_fault_values)] = {}
    reset: bool = False

    @model_validator(mode="after")
    def _check_not_empty(self) -> Self:
        """A command without parameters does nothing unless it resets."""
        if not self.params and not self.reset:
            raise ValueError("params needs at least one entry unless reset is true")
        return self


def _check_plant_names(values: dict[str, float]) -> dict[str, float]:
    for name in values:
        if name not in PLANT_PARAMETERS:
            raise ValueError(f"unknown plant parameter {name!r}; accepted: {', '.join(PLANT_PARAMETERS)}")
    return values


class Hypothesis(Message):
    """Parameters estimated under one fault mode (or all at once: joint) and the fit's error.

    Fault parameters are departures from the switch's commissioned baseline. `unobservable` names the
    ones this throw cannot see (a bolt in the throws it does not drive): their values are held, not
    estimated, and carry no std. `nuisance` holds what the fit estimated of the switch's own build and
    weather (plant parameter names)."""

    mode: Literal["nominal", FaultMode, "joint"]
    params: Annotated[dict[str, float], AfterValidator(_check_fault_names)]
    std: Annotated[dict[str, NonNegative], AfterValidator(_check_fault_names)] = {}
    mse: NonNegative
    unobservable: list[str] = []
    nuisance: Annotated[dict[str, float], AfterValidator(_check_plant_names)] = {}


class FaultEstimate(Message):
    """The decided fault's size, combined over the throws since it appeared that can see it."""

    mode: FaultMode
    params: Annotated[dict[str, float], AfterValidator(_check_fault_names)]
    std: Annotated[dict[str, NonNegative], AfterValidator(_check_fault_names)] = {}
    throws: Annotated[int, Field(ge=1)]  # how many throws were combined
    since_throw: Index  # the first of them


class Commissioning(Message):
    """How far the switch's own baseline is: provisional (judged against the population) until `needed`
    healthy throws each way have been seen, then commissioned (judged against its own baseline). `standing` says
    why a switch cannot be commissioned as healthy (the conditions it was installed with); `accepted` holds what an
    operator took as the switch's own (`railswitch commission SW --accept`): per mode, its parameters' departures as
    accepted, from which its faults are judged since."""

    state: Literal["provisional", "commissioned"]
    throws: dict[Direction, Index]
    needed: Annotated[int, Field(ge=1)]
    outside_population: list[str] = []  # baseline parameters far outside the population's spread
    standing: Annotated[str, Field(max_length=2000)] | None = None
    accepted: dict[FaultMode, Annotated[dict[str, float], AfterValidator(_check_fault_names)]] = {}


class ThrowFeatures(Message):
    """What a point-machine monitor trends of a throw (models/health/features.py says how each is computed from the samples,
    the same from MCAP, CSV or the bus). Currents are magnitudes; a feature the throw's samples cannot give is null."""

    throw_time_s: MaybeNonNegative = None  # motor start to end position
    peak_current_a: MaybeNonNegative = None  # the stroke's highest current, the start-up surge left out
    mean_current_a: MaybeNonNegative = None  # over the stroke
    energy_j: MaybeNonNegative = None  # drawn over the throw, at the point machine's nominal supply voltage
    lock_current_a: MaybeNonNegative = None  # mean current while the crank runs into its locking dead centre
    speed_lag_rad_s: MaybeNonNegative = None  # the motor's largest shortfall below its reference speed (speed logged)


class Anomaly(Message):
    """Something a throw shows that no fault mode names: a quantity of the switch's own (a nuisance) at the edge of
    what the population allows or far from its commissioned level, or a throw no hypothesis explains."""

    quantity: Annotated[str, Field(max_length=64)]  # a plant parameter name, "stroke_current_a" or "residual"
    value: float | None = None
    commissioned: float | None = None
    unit: Annotated[str, Field(max_length=16)] = ""
    reason: Annotated[str, Field(min_length=1, max_length=500)]
    suspects: list[Annotated[str, Field(max_length=64)]] = []  # plant parameters whose change reads like this


Tag = Literal["normal", "fault", "anomaly", "maintenance", "unknown"]


class Diagnosis(Message):
    """The diagnoser's verdict on one throw."""

    switch_id: SwitchId
    throw_index: Index
    direction: Direction
    t_start_ns: TimeNs
    t_end_ns: TimeNs
    model: RailModel
    decision: Decision  # the newest present fault, nominal, or unknown (the throw could not be diagnosed)
    reason: str | None = None
    hypotheses: list[Hypothesis] = []
    joint: Hypothesis | None = None
    estimate: FaultEstimate | None = None  # the decided fault over the throws that see it
    commissioning: Commissioning | None = None
    # Every fault believed present, sorted (empty: nominal); each one's size; and the switch as it is without each
    # present fault this throw could see (how well a repair explains the throw). A payload without `faults` was
    # written before several faults were told apart: its `decision` was its only fault.
    faults: list[FaultMode | Literal["anomaly"]] | None = None
    estimates: list[FaultEstimate] = []
    without: list[Hypothesis] = []
    signals: list[Literal["current_a", "angle_rad", "velocity_rad_s"]] = []  # what the throw's fit used
    # The throw's features; what it shows that no fault names (each also puts "anomaly" in `faults`); and its tag as a
    # monitor's trace list shows it (maintenance: thrown while the switch was in maintenance, kept out of baseline,
    # trends and alarms). A payload without them was written before they were kept.
    features: ThrowFeatures | None = None
    anomalies: list[Anomaly] = []
    tag: Tag | None = None
    latency_ms: NonNegative

    def present(self) -> list[str]:
        """The faults believed present: `faults`, or, from a diagnoser that names one fault at most, the decision's."""
        if self.faults is not None:
            return list(self.faults)
        return [] if self.decision in ("nominal", "unknown") else [self.decision]

    def named(self) -> str:
        """The present faults joined by '+' ('left_bolt+missing_bearing'), nominal, or unknown."""
        return "+".join(self.present()) or ("unknown" if self.decision == "unknown" else "nominal")

    def estimate_of(self, mode: str) -> FaultEstimate | None:
        """A present fault's combined size (`estimates`, or `estimate` from a diagnoser that names one fault)."""
        found = [e for e in self.estimates if e.mode == mode]
        if found:
            return found[0]
        return self.estimate if self.estimate is not None and self.estimate.mode == mode else None

    @model_validator(mode="after")
    def _check_consistency(self) -> Self:
        """The throw ends after it starts, and an unknown decision says why."""
        if self.t_end_ns < self.t_start_ns:
            raise ValueError("t_end_ns is before t_start_ns")
        if self.decision == "unknown" and not (self.reason and self.reason.strip()):
            raise ValueError("decision 'unknown' needs a non-empty reason")
        return self


class CommissionCommand(Message):
    """Restart a switch's commissioning (after maintenance): its baseline is learnt again from the next throws. With
    `accept`, instead take the switch as it now is as its own: its present faults become part of its baseline (a
    standing condition), and faults are judged from there."""

    switch_id: SwitchId
    reason: Annotated[str, Field(max_length=500)] | None = None
    accept: bool = False


class FeatureHealth(Message):
    """One throw feature's trend in one direction against the band its switch's commissioning throws taught: the
    latest value, the band (mean and the limits it may wander within), the slope over the recent throws and its
    state (outside: beyond the band)."""

    name: Annotated[str, Field(max_length=64)]
    direction: Direction
    value: float
    mean: float
    low: float
    high: float
    slope_per_100: float = 0.0
    state: Literal["ok", "outside"] = "ok"


class ParameterHealth(Message):
    """One fault parameter's trend: level (a departure from the baseline) and slope with their standard
    deviations, its maintenance limit, the throws left until it reaches it (median and a 5 %-95 % interval;
    null when it is not heading there) and its own state."""

    name: str
    level: float
    level_std: MaybeNonNegative = None
    slope_per_100: float = 0.0
    slope_std_per_100: MaybeNonNegative = None
    limit: float
    throws_to_limit: MaybeNonNegative = None
    throws_to_limit_low: MaybeNonNegative = None
    throws_to_limit_high: MaybeNonNegative = None
    state: Literal["ok", "watch", "alarm"] = "ok"

    @field_validator("name")
    @classmethod
    def _check_name(cls, value: str) -> str:
        return check_fault_name(value)


class SwitchHealth(Message):
    """A switch's health after a throw (railswitch/<id>/health): each fault parameter fused over its throws,
    the worst one and the switch's state."""

    switch_id: SwitchId
    throw_index: Index  # the throw it refers to
    t_ns: TimeNs  # that throw's end
    model: RailModel
    state: Literal["ok", "watch", "alarm"]
    worst: str | None = None  # the parameter closest to its limit
    throws_to_limit: MaybeNonNegative = None  # the worst parameter's
    parameters: list[ParameterHealth] = []
    features: list[FeatureHealth] = []  # once commissioned, each feature of the throw's direction


MAX_RECORD_SAMPLES = 20_000  # 15 s at 1 kHz and then some; a larger record is junk
RecordValues = Annotated[list[float], Field(min_length=2, max_length=MAX_RECORD_SAMPLES)]


class ThrowRecord(Message):
    """One whole throw as a trackside unit uploads it (railswitch/<id>/record): its direction, reference
    profile and the motor's samples at times from the throw's start (the sample at 0 is the last at rest),
    current and, where logged, angle and angular velocity."""

    switch_id: SwitchId
    throw_index: Index
    direction: Direction
    t_start_ns: TimeNs
    t_end_ns: TimeNs
    reference_t_s: Profile
    reference_velocity_rad_s: Profile
    t_offset_ns: Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=2, max_length=MAX_RECORD_SAMPLES)]
    current_a: Annotated[list[Current], Field(min_length=2, max_length=MAX_RECORD_SAMPLES)]
    angle_rad: Annotated[list[Angle], Field(min_length=2, max_length=MAX_RECORD_SAMPLES)] | None = None
    velocity_rad_s: Annotated[list[AngularVelocity], Field(min_length=2, max_length=MAX_RECORD_SAMPLES)] | None = None

    @model_validator(mode="after")
    def _check_samples(self) -> Self:
        """Signals as long as their times, times going forward within the throw, a profile like a ThrowEvent's."""
        n = len(self.t_offset_ns)
        for name in ("current_a", "angle_rad", "velocity_rad_s"):
            values = getattr(self, name)
            if values is not None and len(values) != n:
                raise ValueError(f"{name} has {len(values)} samples for {n} times")
        if any(b <= a for a, b in zip(self.t_offset_ns, self.t_offset_ns[1:])):
            raise ValueError("t_offset_ns must increase")
        if self.t_end_ns < self.t_start_ns or self.t_offset_ns[-1] > self.t_end_ns - self.t_start_ns:
            raise ValueError("samples after the throw's end, or an end before its start")
        _check_profile_breakpoints(self.reference_t_s, self.reference_velocity_rad_s)
        return self


class SwitchState(Message):
    """What a diagnoser needs to resume a switch (railswitch/<id>/state): its commissioned baseline and health
    tracker after a throw, as the reduced model `model` learnt them. Published after every throw, so the diagnoser
    that takes the switch over (docs/contracts.md, "Elastic shards") goes on from there."""

    switch_id: SwitchId
    model: RailModel
    throw_index: Index  # the throw it follows
    t_ns: TimeNs  # that throw's end
    state: dict  # opaque to the contract: models/diagnosis/switch_diagnoser.py SwitchDiagnoser.state()


Severity = Literal["info", "low", "medium", "high", "critical"]
SEVERITIES: tuple[str, ...] = ("info", "low", "medium", "high", "critical")
AlarmText = Annotated[str, Field(min_length=1, max_length=500)]
AlarmId = Annotated[str, Field(pattern=r"^[a-z_]{1,32}(:[A-Za-z0-9_.-]{1,64}){0,2}$")]


class Alarm(Message):
    """A change of one of a switch's alarms (railswitch/<id>/alarm), published only when something changes: raised,
    escalated, cleared (what caused it is gone, the alarm stays latched until acknowledged) or acknowledged (by
    `railswitch ack`; an acknowledged alarm whose cause is gone is closed). Repeats of an active alarm's cause only
    count and move `last_throw`. `alarm` names the cause: a fault mode, `anomaly:<quantity>` or
    `feature:<name>:<direction>`. `sequence` numbers the switch's alarm changes."""

    switch_id: SwitchId
    alarm: AlarmId
    change: Literal["raised", "escalated", "cleared", "acknowledged"]
    severity: Severity
    cause: Literal["fault", "anomaly", "feature"]
    text: AlarmText  # what an operator reads: the cause and its size
    parameters: dict[str, float] = {}  # the cause's figures (a fault's parameters, an anomaly's value, a feature's)
    first_throw: Index
    last_throw: Index
    count: Annotated[int, Field(ge=1)]  # throws that showed it
    active: bool  # its cause is still there
    acknowledged: bool
    note: Annotated[str, Field(max_length=500)] | None = None  # the acknowledgement's
    sequence: Index
    t_ns: TimeNs  # of the change: the throw's end, or when the acknowledgement arrived
    model: RailModel


class AckCommand(Message):
    """Acknowledge a switch's alarms (`railswitch ack SW`): all of them, or the one named."""

    switch_id: SwitchId
    alarm: AlarmId | None = None
    note: Annotated[str, Field(max_length=500)] | None = None


class MaintenanceCommand(Message):
    """Start or end a switch's maintenance (`railswitch maintenance SW --start/--end`). Meanwhile its throws are
    diagnosed and recorded, tagged maintenance, and raise no alarm and teach no baseline or trend; at its end the
    switch resumes, or with `recommission` learns its baseline again."""

    switch_id: SwitchId
    action: Literal["start", "end"]
    recommission: bool = False
    note: Annotated[str, Field(max_length=500)] | None = None

    @model_validator(mode="after")
    def _check_recommission(self) -> Self:
        if self.recommission and self.action != "end":
            raise ValueError("recommission goes with action 'end'")
        return self


class ServiceStatus(Message):
    """What a live service reports every few seconds on railswitch/@service/<service>/<instance>/status."""

    service: Annotated[str, Field(pattern=r"^[a-z]{1,32}$")]
    instance: SwitchId
    t_ns: TimeNs
    uptime_s: NonNegative
    received: Index  # payloads taken off the bus
    rejected: dict[str, Index] = {}  # per reason
    counters: dict[str, Index] = {}  # the service's own, e.g. diagnosed, written
    ignored_fields: dict[str, Index] = {}  # unknown fields of accepted payloads (a newer publisher's), per name


CHANNEL_MODELS: dict[str, type[Message]] = {
    "motor": MotorSample,
    "throw": ThrowEvent,
    "truth": FaultTruth,
    "diagnosis": Diagnosis,
    "inject": FaultCommand,
    "commission": CommissionCommand,
    "health": SwitchHealth,
    "record": ThrowRecord,
    "state": SwitchState,
    "alarm": Alarm,
    "ack": AckCommand,
    "maintenance": MaintenanceCommand,
}

KEY_PREFIX = "railswitch"
# Liveliness tokens and status of the services. `@service` is a verbatim chunk: no wildcard matches it, so neither
# railswitch/** nor railswitch/*/<kind> sees what is published there, and no switch id can be it.
SERVICE_PREFIX = f"{KEY_PREFIX}/@service"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"  # where a service looks for its router unless told otherwise


def key_expr(switch_id: str, kind: str) -> str:
    """Zenoh key expression and MCAP topic of one switch's channel: railswitch/<id>/<kind>."""
    if kind not in CHANNEL_MODELS:
        accepted = ", ".join(CHANNEL_MODELS)
        raise ValueError(f"unknown channel kind {kind!r}; accepted: {accepted}")
    return f"{KEY_PREFIX}/{check_switch_id(switch_id)}/{kind}"


RECENT_KIND = "recent"  # railswitch/<id>/recent: the recorders' queryable of a stream's recent throws, as records


def recent_key(switch_id: str) -> str:
    """The key of the recorders' recent throws of one switch, or of every switch for `*` (docs/contracts.md section 3,
    Catching up): not a channel, nothing is published there; queries on it are answered with ThrowRecords."""
    return f"{KEY_PREFIX}/{switch_id if switch_id == '*' else check_switch_id(switch_id)}/{RECENT_KIND}"


def parse_key_expr(key: str) -> tuple[str, str]:
    """Inverse of key_expr: (switch_id, kind), or ValueError for any other key."""
    parts = key.split("/")
    if len(parts) != 3 or parts[0] != KEY_PREFIX:
        raise ValueError(f"key {key!r} is not of the form {KEY_PREFIX}/<switch_id>/<kind>")
    switch_id, kind = parts[1], parts[2]
    try:
        key_expr(switch_id, kind)
    except ValueError as e:
        raise ValueError(f"key {key!r}: {e}") from None
    return switch_id, kind


def json_schema(model_cls: type[BaseModel]) -> str:
    """JSON Schema of a model as compact, key-sorted text, identical on every run."""
    return json.dumps(model_cls.model_json_schema(), sort_keys=True, separators=(",", ":"))


class MessageError(ValueError):
    """A payload that could not become a message; str() is a short reason fit for counting."""


def encode(msg: BaseModel) -> bytes:
    """Compact UTF-8 JSON of a message, as published on the bus and stored in MCAP."""
    return msg.model_dump_json().encode()


class Counted(NamedTuple, Generic[M]):
    """A decoded payload: the message, what of the payload this version does not know, and the message's bytes for a
    store that keeps it: the payload as it came when it holds nothing unknown (encoding it again would only cost
    time), else the message as this version encodes it (what it understood)."""

    message: M
    unknown: list[str]
    encoded: bytes


def decode_counted(model_cls: type[M], data: bytes) -> Counted[M]:
    """decode, and what of the payload this version does not know, as names to count (docs/contracts.md,
    "Changing the contract"): every unknown field, nested ones by their dotted path (`estimate.since`, list
    items unnumbered: `hypotheses.note`), and `contract=N` when the payload was written to a newer contract.

    The payload is validated first with unknown fields refused at every depth: one that passes (every payload of a
    publisher of this version) holds nothing unknown, and is neither validated nor encoded again. Any other is
    validated as decode does (unknown fields ignored; a wrong one is refused for its own reason), and the unknown
    fields the first validation refused are its names to count."""
    utf8(data)
    try:
        message = model_cls.model_validate_json(data, extra="forbid")
        unknown, encoded = [], data
    except ValidationError as refused:
        message = decode(model_cls, data)
        unknown = sorted({".".join(str(step) for step in error["loc"] if not isinstance(step, int))
                          for error in refused.errors(include_url=False) if error["type"] == "extra_forbidden"})
        encoded = encode(message)
    if isinstance(message, Message) and message.contract > CONTRACT_VERSION:
        unknown.append(f"contract={message.contract}")
    return Counted(message, unknown, encoded)


def utf8(data: bytes) -> None:
    """MessageError unless data is UTF-8 (JSON's encoding, and what a store keeps as text)."""
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        raise MessageError("not utf-8") from None


def decode(model_cls: type[M], data: bytes) -> M:
    """Parse and validate a payload; every failure is a MessageError with a short reason."""
    utf8(data)
    try:
        return model_cls.model_validate_json(data)
    except ValidationError as e:
        first = e.errors(include_url=False)[0]
        if first["type"] == "json_invalid":
            raise MessageError("not json") from None
        loc = ".".join(map(str, first["loc"]))
        reason = f"{loc}: {first['msg']}" if loc else first["msg"]
        raise MessageError(f"validation: {reason}") from None
