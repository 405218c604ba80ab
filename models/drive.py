"""Gear reduction and crank: motor rotation to drive-rod translation.

The crank's dead centres at both ends of the stroke lock the rod: there the
rod force produces no torque on the motor, as in a real point machine.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import casadi as ca


@dataclass(frozen=True)
class DriveParams:
    """Gearbox ratio and crank geometry (rod travel = crank_radius * (1 - cos(angle / ratio)))."""

    gear_ratio: float = 250.0
    crank_radius_m: float = 0.123
    rod_left_m: float = 0.977  # rod position at the left dead centre

    @property
    def stroke_m(self) -> float:
        return 2.0 * self.crank_radius_m

    @property
    def throw_angle_rad(self) -> float:
        """Motor angle of one throw: half a crank revolution."""
        return math.pi * self.gear_ratio


def rod_kinematics(params: DriveParams, motor_angle_rad, omega):
    """Rod position, rod velocity and the lever arm d(position)/d(motor angle)."""
    crank = motor_angle_rad / params.gear_ratio
    position = params.rod_left_m + params.crank_radius_m * (1.0 - ca.cos(crank))
    lever_m = params.crank_radius_m * ca.sin(crank) / params.gear_ratio
    return position, lever_m * omega, lever_m
