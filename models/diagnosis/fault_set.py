"""A switch's present faults: the set each of its throws is tested against (docs/method.md, "Several faults").

Real switches carry several faults at once, start life with conditions, degrade slowly and get repaired. So a
switch's state is a set of confirmed faults, each with its parameters as the latest throw that saw it fitted them.
Every throw is fitted as the switch now is (its confirmed faults free, models/diagnosis/switch_diagnoser.py), as the same
plus one more fault of each mode it does not have, and as the same without each confirmed fault the throw can see;
this module holds the set and the rules that change it:

- **Add** a fault when its hypothesis beats the switch as it now is (models/diagnosis/isolation.py, its evidence added up
  over the latest throws that could see it) and fits best of those detected. A confirmed fault is never dropped
  because a new one fits better alone: the new one is tested on top of it.
- **Cannot tell apart**: when two detected modes fit a throw alike (isolation.separable), that direction cannot
  separate them; nothing is added and the next throw of the other direction decides (a bolt that direction cannot
  see, when it shows neither).
- **Repair**: a fault whose presence test (the switch as it is against the same without the fault) fails on the
  latest throw that sees it, its size back at its reference, is gone when its size dropped suddenly on two throws in
  a row that see it (a repair is sudden; one throw can misfit), or when its presence has failed on as many throws in
  a row as evidence is added up over, and on their sum (it faded). A bolt back within its adjustment is gone at once.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from railswitch.models.diagnosis.estimation import DRIVING_BOLT
from railswitch.models.diagnosis.isolation import EVIDENCE_THROWS, Evidence, accumulated
from railswitch.schemas.faults import FAULT_PARAMETERS, MODE_PARAMETERS

# Each mode's size: the parameter whose departure from its reference says how large the fault is.
MAGNITUDE = {"left_bolt": "left_bolt_offset", "right_bolt": "right_bolt_offset", "missing_bearing": "bearing_friction",
             "obstacle": "obstacle_friction", "drive_friction": "drive_friction_nm"}
# A repair is a sudden drop: the size fell by more than this many of the two fits' standard deviations together, to
# within RETURN_SIGMAS of its reference.
DROP_SIGMAS = 3.0
RETURN_SIGMAS = 2.0


def observable(mode: str, direction: str) -> bool:
    """A bolt shows only in the throws it drives; every other mode in both directions."""
    return mode not in DRIVING_BOLT.values() or DRIVING_BOLT[direction] == mode


@dataclass
class Fault:
    """A confirmed fault: the throw that confirmed it, its parameters (the model's values) and size (departure from its
    reference, with the fit's standard deviation) at the latest throw that saw it, the evidence of its presence from
    those throws (latest first), and their reports, which its combined size is made of."""

    mode: str
    since: int
    values: dict[str, float]
    size: float = 0.0
    size_std: float = 0.0
    presence: list[Evidence] = field(default_factory=list)
    track: deque = field(default_factory=deque, repr=False)
    dropped: bool = False  # the latest throw that saw it showed it gone at once: a repair, if the next one agrees
    absent: int = 0  # throws in a row that saw it and did not show it

    def to_dict(self) -> dict:
        return {"mode": self.mode, "since": self.since, "values": dict(self.values), "size": self.size,
                "size_std": self.size_std}

    @classmethod
    def from_dict(cls, data: dict, tracked: int) -> Fault:
        return cls(str(data["mode"]), int(data["since"]), {k: float(v) for k, v in data["values"].items()},
                   float(data.get("size", 0.0)), float(data.get("size_std", 0.0)), track=deque(maxlen=tracked))


@dataclass(frozen=True)
class Undecided:
    """Modes one throw showed alike: the direction it ran in cannot separate them, the next throw of the other decides."""

    modes: tuple[str, ...]  # the best fit first
    direction: str
    throw: int
    values: dict[str, dict[str, float]] = field(default_factory=dict)  # each mode's fit of that throw

    def describe(self) -> str:
        other = "right to left" if self.direction == "left_to_right" else "left to right"
        return (f"{' or '.join(self.modes)}: a {self.direction.replace('_', ' ')} throw cannot tell them apart; "
                f"deciding on the next {other} throw")


def decide_between(undecided: Undecided, direction: str, detected: list[str]) -> str | None:
    """The mode a throw of the other direction settles an undecided pair on: the first of them it detects (best fit
    first), else a bolt of the pair this direction cannot see (the other modes show in both directions and this throw
    shows none of them), else none (what the earlier throw showed is gone)."""
    for mode in detected:
        if mode in undecided.modes:
            return mode
    unseen = [mode for mode in undecided.modes if not observable(mode, direction)]
    return unseen[0] if len(unseen) == 1 else None


def repaired(fault: Fault, now: Evidence, size: float, size_std: float, small: bool, sudden_only: bool = False) -> bool:
    """Whether a confirmed fault is gone after a throw that sees it. A bolt back within its adjustment (`small`) is, at
    once (it shows only every other throw). Another is when its size is no fault (`small`: an obstacle below its
    tolerance), or this throw does not show it and its size is back at its reference (within RETURN_SIGMAS of the
    fit's standard deviation), and it either dropped suddenly since the throw that saw it before (a repair: it must
    have done so on two throws that see it in a row, since one throw can misfit, a throw that starts short after a
    loose bolt say) or has faded: not shown by EVIDENCE_THROWS throws in a row that saw it, nor by their presence
    added up. `sudden_only`: a sudden drop alone counts (the throw shows a new fault, which may bend the rest).
    Updates `fault.dropped` and `fault.absent`."""
    bolt = fault.mode in DRIVING_BOLT.values()
    if small and bolt:
        return not sudden_only or fault.size - size > DROP_SIGMAS * float(np.hypot(fault.size_std, size_std))
    fault.absent = fault.absent + 1 if not now.detected else 0
    back = small or not now.detected and abs(size) <= RETURN_SIGMAS * size_std
    dropped = back and fault.size - size > DROP_SIGMAS * float(np.hypot(fault.size_std, size_std))
    if dropped:
        confirmed, fault.dropped = fault.dropped, True
        return confirmed
    fault.dropped = False
    faded = fault.absent >= EVIDENCE_THROWS and not accumulated(now, fault.presence).detected
    return back and not sudden_only and faded


def size_of(mode: str, departures: dict[str, float]) -> float:
    """A fault's size from its parameters' departures from their references (a bolt either way)."""
    value = departures[MAGNITUDE[mode]]
    return abs(value) if mode in DRIVING_BOLT.values() else value


def describe_standing(mode: str, departures: dict[str, float], bearing_per_chair_loss: float,
                      machine_friction_nm: float) -> str:
    """A standing condition in an operator's words: how much more the rollers lose, how much more the point machine
    rubs, how far a bolt is off its mark, where an obstacle sits."""
    if mode == "missing_bearing":
        return f"rolling losses {1.0 + departures['bearing_friction'] / bearing_per_chair_loss:.1f}x"
    if mode == "drive_friction":
        return f"point machine friction {1.0 + departures['drive_friction_nm'] / machine_friction_nm:.1f}x"
    if mode == "obstacle":
        return (f"an obstacle of {departures['obstacle_friction']:.0f} N·s/m at "
                f"{departures.get('obstacle_position', FAULT_PARAMETERS['obstacle_position'].nominal):.2f} m")
    name = MODE_PARAMETERS[mode][0]
    return f"{mode.replace('_', ' ')} {departures[name] * 1e3:+.0f} mm off its mark"

