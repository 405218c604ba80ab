"""The fault modes and parameters of docs/contracts.md section 2, as data shared by every part."""

from dataclasses import dataclass
from typing import Literal, get_args

from railswitch.schemas.ranges import Ranged

FaultMode = Literal["left_bolt", "right_bolt", "missing_bearing", "obstacle", "drive_friction"]
Decision = Literal["nominal", FaultMode, "unknown"]

FAULT_MODES: tuple[FaultMode, ...] = get_args(FaultMode)

RailModel = Literal["poly", "nn", "causal"]  # the reduced rail representations a diagnosis can use
RAIL_MODELS: tuple[RailModel, ...] = get_args(RailModel)
DECISIONS: tuple[Decision, ...] = get_args(Decision)


@dataclass(frozen=True, kw_only=True)
class FaultParameter(Ranged):
    """One injectable fault parameter: its SI unit, nominal value and range, and the mode it belongs to."""

    mode: FaultMode


FAULT_PARAMETERS: dict[str, FaultParameter] = {
    p.name: p
    for p in (
        FaultParameter("left_bolt_offset", "m", 0.0, -0.02, 0.20, mode="left_bolt"),
        FaultParameter("right_bolt_offset", "m", 0.0, -0.02, 0.20, mode="right_bolt"),
        FaultParameter("bearing_friction", "N·s/m", 0.0, 0.0, 10_000.0, mode="missing_bearing"),
        FaultParameter("obstacle_friction", "N·s/m", 0.0, 0.0, 300_000.0, mode="obstacle"),
        # Nominal position is only a placeholder: it matters only when obstacle_friction > 0.
        FaultParameter("obstacle_position", "m", 1.10, 1.02, 1.18, mode="obstacle"),
        # Coulomb friction added inside the point machine (gearbox and motor wear), at the motor shaft;
        # the range reaches 2.5 times the motor's own nominal 0.12 N·m.
        FaultParameter("drive_friction_nm", "N·m", 0.0, 0.0, 0.30, mode="drive_friction"),
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
    return FAULT_PARAMETERS[check_fault_name(name)].check(value)
