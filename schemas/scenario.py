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

    [[switches.changes]]
    throw = 2                                     # before throw 2 ...
    set = { obstacle_friction = 1e5, obstacle_position = 1.1 }

    [[switches.changes]]
    throw = 3                                     # gradual degradation: before each of throws 3 to 5
    until = 5
    add = { bearing_friction = 500.0 }
"""

import tomllib
from pathlib import Path
from typing import Annotated, Self

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, model_validator

from railswitch.schemas.faults import FAULT_PARAMETERS, check_fault_value
from railswitch.schemas.messages import SwitchId, _check_fault_names, _check_fault_values

THROW_S = 7.0  # a throw's duration (models/reference.py THROW_DURATION_S); an interval must exceed it
FaultValues = Annotated[dict[str, float], AfterValidator(_check_fault_values)]
FaultSteps = Annotated[dict[str, float], AfterValidator(_check_fault_names)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


class FaultChange(_Strict):
    """Before throw `throw` (through `until`, for `add`): set, reset or step fault parameters."""

    throw: Annotated[int, Field(ge=0)]
    until: Annotated[int, Field(ge=0)] | None = None
    set: FaultValues = {}
    add: FaultSteps = {}
    reset: bool = False

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
    """One switch: how many throws, its faults at the start and the changes over its throws."""

    id: SwitchId
    throws: Annotated[int, Field(ge=1, le=1_000_000)]
    faults: FaultValues = {}
    changes: list[FaultChange] = []

    def faults_before(self, throw: int, current: dict[str, float]) -> dict[str, float]:
        """The faults for `throw`, given those in force after the previous one; ValueError out of range."""
        faults = dict(current)
        for change in self.changes:
            once, stepping = change.applies_to(throw)
            if once and change.reset:
                faults = {}
            if once:
                faults.update(change.set)
            if stepping:
                for name, step in change.add.items():
                    value = faults.get(name, FAULT_PARAMETERS[name].nominal) + step
                    try:
                        faults[name] = check_fault_value(name, value)
                    except ValueError as error:
                        raise ValueError(f"switch {self.id} before throw {throw}: {error}") from None
        return faults

    def schedule(self) -> list[dict[str, float]]:
        """The faults of every throw, as the scenario alone would have them."""
        faults, out = dict(self.faults), []
        for throw in range(self.throws):
            faults = self.faults_before(throw, faults)
            out.append(faults)
        return out


class Scenario(_Strict):
    """A schedule of throws and fault changes for one or more switches."""

    interval_s: Annotated[float, Field(gt=THROW_S, le=86_400.0)] = 10.0
    rate_hz: Annotated[float, Field(ge=1.0, le=1000.0)] = 50.0
    noise: Annotated[float, Field(ge=0.0, le=0.5)] = 0.0
    seed: Annotated[int, Field(ge=0, lt=2**32)] = 0
    switches: Annotated[list[SwitchPlan], Field(min_length=1)]

    @model_validator(mode="after")
    def _check(self) -> Self:
        ids = [plan.id for plan in self.switches]
        if len(set(ids)) != len(ids):
            raise ValueError(f"switch ids repeat: {ids}")
        for plan in self.switches:
            plan.schedule()  # every stepped value stays in range
        return self


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
