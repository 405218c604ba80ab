"""Reference angular-velocity profiles of the motor's speed controller."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from railswitch.models.plant.drive import DriveParams

THROW_DURATION_S = 7.0  # the reference profile of the machine type modelled: a 6.4 s stroke, then still
STROKE_S = 6.4
DIRECTIONS = ("left_to_right", "right_to_left")


@dataclass(frozen=True)
class Reference:
    """Piecewise-linear profile through breakpoints, constant outside them."""

    t_s: np.ndarray
    velocity_rad_s: np.ndarray

    def __call__(self, t_s) -> np.ndarray:
        return np.interp(t_s, self.t_s, self.velocity_rad_s)

    def linear_pieces(self, start_s: np.ndarray, end_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The profile on each interval from `start_s` to `end_s` as intercept + slope * t: the line of the piece
        that holds the whole interval, or the chord where an interval spans a breakpoint. Intervals of one piece
        get the same two numbers to the last bit (the plant's integrator stops only where they change)."""
        start_s, end_s = np.asarray(start_s, dtype=float), np.asarray(end_s, dtype=float)
        t, v = self.t_s, self.velocity_rad_s
        first = self(start_s)
        slope = (self(end_s) - first) / (end_s - start_s)  # outside the breakpoints exactly 0: the held value
        intercept = first - slope * start_s
        piece = np.searchsorted(t, start_s, side="right") - 1  # the piece that starts at or before the interval
        within = (piece >= 0) & (piece < len(t) - 1)
        within[within] = end_s[within] <= t[piece[within] + 1]
        k = piece[within]
        slope[within] = (v[k + 1] - v[k]) / (t[k + 1] - t[k])
        intercept[within] = v[k] - slope[within] * t[k]
        return intercept, slope

    def angle_rad(self) -> float:
        """Motor angle the profile asks for (its integral)."""
        return float(np.trapezoid(self.velocity_rad_s, self.t_s))


def direction_sign(direction: str) -> float:
    """+1 for left to right (motor turns forward), -1 for right to left."""
    if direction not in DIRECTIONS:
        raise ValueError(f"direction {direction!r} is not one of {', '.join(DIRECTIONS)}")
    return 1.0 if direction == "left_to_right" else -1.0


def throw_reference(direction: str, drive: DriveParams = DriveParams(), stroke_s: float = STROKE_S,
                    duration_s: float = THROW_DURATION_S, ramp_s: float = 0.4) -> Reference:
    """Trapezoid that turns the crank by exactly half a revolution in `stroke_s` (ramps included), then holds
    still until `duration_s`. Point machines of other types (or gearings) stroke faster or slower."""
    if not 2 * ramp_s < stroke_s <= duration_s:
        raise ValueError(f"a stroke of {stroke_s:g} s must be longer than its two {ramp_s:g} s ramps and end "
                         f"by the throw's {duration_s:g} s")
    run_s = stroke_s - ramp_s
    plateau = direction_sign(direction) * drive.throw_angle_rad / run_s
    t = np.array([0.0, ramp_s, run_s, stroke_s, duration_s])
    return Reference(t, np.array([0.0, plateau, plateau, 0.0, 0.0]))
