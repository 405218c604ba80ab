"""The fault modes and parameters of docs/contracts.md section 2, as data shared by every part."""

from dataclasses import dataclass
from typing import Literal, get_args

from railswitch.schemas.ranges import check_in_range

FaultMode = Literal["left_bolt", "right_bolt", "missing_bearing", "obstacle", "drive_friction"]
Decision = Literal["nominal", FaultMode, "unknown"]

FAULT_MODES: tuple[FaultMode, ...] = get_args(FaultMode)

RailModel = Literal["poly", "nn", "causal"]  # the reduced rail representations a diagnosis can use
RAIL_MODELS: tuple[RailModel, ...] = get_args(RailModel)
DECISIONS: tuple[Decision, ...] = get_args(Decision)


@dataclass(frozen=True)
class FaultParameter:
    """One injectable fault parameter: the mode it belongs to, SI unit, nominal value and range."""

    name: str
    mode: FaultMode
    unit: str
    nominal: float
    low: float
    high: float


FAULT_PARAMETERS: dict[str, FaultParameter] = {
    p.name: p
    for p in (
        FaultParameter("left_bolt_offset", "left_bolt", "m", 0.0, -0.02, 0.20),
        FaultParameter("right_bolt_offset", "right_bolt", "m", 0.0, -0.02, 0.20),
        FaultParameter("bearing_friction", "missing_bearing", "N·s/m", 0.0, 0.0, 10_000.0),
        FaultParameter("obstacle_friction", "obstacle", "N·s/m", 0.0, 0.0, 300_000.0),
        # Nominal position is only a placeholder: it matters only when obstacle_friction > 0.
        FaultParameter("obstacle_position", "obstacle", "m", 1.10, 1.02, 1.18),
        # Coulomb friction added inside the point machine (gearbox and motor wear), at the motor shaft;
        # the range reaches 2.5 times the motor's own nominal 0.12 N·m.
        FaultParameter("drive_friction_nm", "drive_friction", "N·m", 0.0, 0.0, 0.30),
    )
}

MODE_PARAMETERS: dict[FaultMode, tuple[str, ...]] = {
    mode: tuple(p.name for p in FAULT_PARAMETERS.values() if p.mode == mode)
    for mode in FAULT_MODES
}


def check_fault_name(name: str) -> str:
    """Return name if it is a fault parameter, else raise ValueError listing the accepted names."""
    if name not in FAULT_PARAMETERS:
        accepted = ", ".join(FAULT_PARAMETERS)
        raise ValueError(f"unknown fault parameter {name!r}; accepted: {accepted}")
    return name


def check_fault_value(name: str, value: float | str) -> float:
    """Return value as a float if name is known and value finite and in range; else ValueError.

    Strings are parsed, so a command line can pass the text after NAME= unchanged.
    """
    p = FAULT_PARAMETERS[check_fault_name(name)]
    return check_in_range(name, value, p.low, p.high, p.unit)
