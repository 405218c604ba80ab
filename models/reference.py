"""Reference angular-velocity profiles of the motor's speed controller."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from railswitch.models.drive import DriveParams

THROW_DURATION_S = 7.0
DIRECTIONS = ("left_to_right", "right_to_left")


@dataclass(frozen=True)
class Reference:
    """Piecewise-linear profile through breakpoints, constant outside them."""

    t_s: np.ndarray
    velocity_rad_s: np.ndarray

    def __call__(self, t_s) -> np.ndarray:
        return np.interp(t_s, self.t_s, self.velocity_rad_s)

    def angle_rad(self) -> float:
        """Motor angle the profile asks for (its integral)."""
        return float(np.trapezoid(self.velocity_rad_s, self.t_s))


def direction_sign(direction: str) -> float:
    """+1 for left to right (motor turns forward), -1 for right to left."""
    if direction not in DIRECTIONS:
        raise ValueError(f"direction {direction!r} is not one of {', '.join(DIRECTIONS)}")
    return 1.0 if direction == "left_to_right" else -1.0


def throw_reference(direction: str, drive: DriveParams = DriveParams(), ramp_s: float = 0.4,
                    run_s: float = 6.0) -> Reference:
    """Trapezoid that turns the crank by exactly half a revolution, then holds still until 7 s."""
    plateau = direction_sign(direction) * drive.throw_angle_rad / run_s
    t = np.array([0.0, ramp_s, run_s, run_s + ramp_s, THROW_DURATION_S])
    return Reference(t, np.array([0.0, plateau, plateau, 0.0, 0.0]))
