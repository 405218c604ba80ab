"""The simulator's scenario file (TOML): which switches throw, how often, and when faults change.

Example (throw numbers are the 0-based `throw_index` of the messages):

    interval_s = 10.0          # simulated seconds between the starts of a switch's throws
    noise = 0.01

    [[switches]]
    id = "sw1"
    throws = 6

    [[switches]]
    id = "sw2"
    throws = 6
    faults = { left_bolt_offset = 0.05 }          # from the start
    vary = 17                                     # a switch drawn from the population (seed 17) ...
    plant = { "motor.supply_v" = 99.0 }           # ... with these of its own parameters set

    [[switches.changes]]
    throw = 2                                     # before throw 2 ...
    set = { obstacle_friction = 1e5, obstacle_position = 1.1 }

    [[switches.changes]]
    throw = 3                                     # gradual degradation: before each of throws 3 to 5
    until = 5
    add = { bearing_friction = 500.0, "rail.chair_friction_coefficient" = 0.004 }

`set` and `add` take fault parameters and the switch's own parameters alike (the dotted names
of schemas/plant.py), so a cold night or chairs drying out are changes like any other.
"""

import tomllib
from pathlib import Path
from typing import Annotated, Self

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, model_validator

from railswitch.schemas.faults import FAULT_PARAMETERS, check_fault_value
from railswitch.schemas.messages import SwitchId, _check_fault_names, _check_fault_values
from railswitch.schemas.plant import PLANT_PARAMETERS, check_plant_value, check_plant_values

STROKE_S = 6.4  # the modelled machine type's stroke time (models/plant/reference.py); its profile ends 0.6 s later


def is_plant_name(name: str) -> bool:
    """The switch's own parameters have dotted names (motor.supply_v); faults do not."""
    return "." in name


def check_setting(name: str, value: float) -> float:
    return check_plant_value(name, value) if is_plant_name(name) else check_fault_value(name, value)


def _check_settings(values: dict[str, float]) -> dict[str, float]:
    return {name: check_setting(name, value) for name, value in values.items()}


def _check_setting_names(values: dict[str, float]) -> dict[str, float]:
    for name in values:
        if is_plant_name(name):
            if name not in PLANT_PARAMETERS:
                raise ValueError(f"unknown plant parameter {name!r}; accepted: {', '.join(PLANT_PARAMETERS)}")
        else:
            _check_fault_names({name: 0.0})
    return values


FaultValues = Annotated[dict[str, float], AfterValidator(_check_fault_values)]
PlantValues = Annotated[dict[str, float], AfterValidator(check_plant_values)]
Settings = Annotated[dict[str, float], AfterValidator(_check_settings)]
SettingSteps = Annotated[dict[str, float], AfterValidator(_check_setting_names)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


class FaultChange(_Strict):
    """Before throw `throw` (through `until`, for `add`): set, reset or step fault parameters."""

    throw: Annotated[int, Field(ge=0)]
    until: Annotated[int, Field(ge=0)] | None = None
    set: Settings = {}
    add: SettingSteps = {}
    reset: bool = False  # faults back to none (the switch's own parameters stay)

    @model_validator(mode="after")
    def _check(self) -> Self:
        if not (self.set or self.add or self.reset):
            raise ValueError("a change needs set, add or reset")
        if self.until is not None and self.until < self.throw:
            raise ValueError(f"until={self.until} is before throw={self.throw}")
        return self

    def applies_to(self, throw: int) -> tuple[bool, bool]:
        """(set/reset apply before this throw, add applies before this throw)."""
        last = self.throw if self.until is None else self.until
        return throw == self.throw, self.throw <= throw <= last


class SwitchPlan(_Strict):
    """One switch: how many throws, its faults and own parameters at the start, and the changes over its throws."""

    id: SwitchId
    throws: Annotated[int, Field(ge=1, le=1_000_000)]
    faults: FaultValues = {}
    vary: Annotated[int, Field(ge=0, lt=2**32)] | None = None  # draw the switch from the population (seed)
    plant: PlantValues = {}  # its own parameters (over the drawn ones)
    changes: list[FaultChange] = []

    def settings_before(self, throw: int, current: dict[str, float], base: dict[str, float] | None = None) -> dict[str, float]:
        """Faults and own parameters for `throw`, given those in force after the previous one (`base`: the values
        a parameter not yet set steps from, the switch's own); ValueError out of range."""
        settings = dict(current)
        for change in self.changes:
            once, stepping = change.applies_to(throw)
            if once and change.reset:
                settings = {name: value for name, value in settings.items() if is_plant_name(name)}
            if once:
                settings.update(change.set)
            if stepping:
                for name, step in change.add.items():
                    start = (base or {}).get(name, PLANT_PARAMETERS[name].nominal if is_plant_name(name)
                                             else FAULT_PARAMETERS[name].nominal)
                    try:
                        settings[name] = check_setting(name, settings.get(name, start) + step)
                    except ValueError as error:
                        raise ValueError(f"switch {self.id} before throw {throw}: {error}") from None
        return settings

    def schedule(self, base: dict[str, float] | None = None) -> list[dict[str, float]]:
        """The settings of every throw, as the scenario alone would have them (`base`: the switch's own)."""
        settings, out = {**self.faults, **self.plant}, []
        for throw in range(self.throws):
            settings = self.settings_before(throw, settings, base)
            out.append(settings)
        return out


class Scenario(_Strict):
    """A schedule of throws and fault changes for one or more switches."""

    interval_s: Annotated[float, Field(gt=0.0, le=86_400.0)] = 10.0
    rate_hz: Annotated[float, Field(ge=1.0, le=1000.0)] = 50.0
    stroke_s: Annotated[float, Field(ge=2.0, le=14.0)] = STROKE_S  # the point machines' stroke time
    throw_s: Annotated[float, Field(ge=1.0, le=30.0)] | None = None  # end event's time (default stroke_s + 0.6)
    noise: Annotated[float, Field(ge=0.0, le=0.5)] = 0.0
    seed: Annotated[int, Field(ge=0, lt=2**32)] = 0
    switches: Annotated[list[SwitchPlan], Field(min_length=1)]

    @model_validator(mode="after")
    def _check(self) -> Self:
        if self.interval_s <= self.throw_length_s:
            raise ValueError(f"interval_s {self.interval_s:g} must exceed a throw's length ({self.throw_length_s:g} s)")
        ids = [plan.id for plan in self.switches]
        if len(set(ids)) != len(ids):
            raise ValueError(f"switch ids repeat: {ids}")
        for plan in self.switches:
            plan.schedule()  # every stepped value stays in range
        return self


    @property
    def throw_length_s(self) -> float:
        return self.throw_s if self.throw_s is not None else self.stroke_s + 0.6


class ScenarioError(ValueError):
    """A scenario file cannot be used; the message is one line naming the file and the problem."""


def load_scenario(path: str | Path) -> Scenario:
    """Read and check a scenario file."""
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except OSError as error:
        raise ScenarioError(f"cannot read scenario {path}: {error.strerror}") from None
    except tomllib.TOMLDecodeError as error:
        raise ScenarioError(f"scenario {path} is not valid TOML: {error}") from None
    try:
        return Scenario.model_validate(data)
    except ValidationError as error:
        first = error.errors(include_url=False)[0]
        where = ".".join(map(str, first["loc"])) or "file"
        raise ScenarioError(f"scenario {path}: {where}: {first['msg']}") from None
