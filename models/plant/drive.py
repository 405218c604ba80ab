"""Gear reduction, crank and linkage: motor rotation to drive-rod and blade translation.

The crank's dead centres at both ends of the stroke lock the rod: there the
rod force produces no torque on the motor, as in a real point machine. The
rod moves the blades through a lever (bell crank) of `linkage_ratio` rod metres
per blade metre; the adjuster and its bolts sit on the rod side, so a bolt
offset of 0.20 m (the top of its range, docs/contracts.md section 2) still lets the blades move.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import casadi as ca


@dataclass(frozen=True)
class DriveParams:
    """Gearbox ratio, crank geometry (rod travel = crank_radius * (1 - cos(angle / ratio))) and linkage.

    Rod coordinates are blade travel coordinates times `linkage_ratio`. The
    stroke covers the blade stroke, the adjuster's free play and a small
    overtravel that presses the blade against the stock rail at each end.
    """

    gear_ratio: float = 250.0
    crank_radius_m: float = 0.244
    rod_left_m: float = 1.956  # rod position at the left dead centre
    linkage_ratio: float = 2.0
    binding_torque_nm: float = 0.0  # a gearbox that binds at one point of the stroke: its extra friction at the motor
    binding_position: float = 0.5  # where, as the share of the rod's stroke from the left dead centre
    binding_width: float = 0.04  # over what share of the stroke (the standard deviation of its bell)

    @property
    def stroke_m(self) -> float:
        return 2.0 * self.crank_radius_m

    @property
    def throw_angle_rad(self) -> float:
        """Motor angle of one throw: half a crank revolution."""
        return math.pi * self.gear_ratio


def adjuster_on_rod(params: DriveParams, rail_m, rail_velocity_m_s):
    """Where the blade's drive point puts the adjuster, in rod coordinates, and its velocity."""
    return params.linkage_ratio * rail_m, params.linkage_ratio * rail_velocity_m_s


def rod_kinematics(params: DriveParams, motor_angle_rad, omega):
    """Rod position, rod velocity and the lever arm d(position)/d(motor angle)."""
    crank = motor_angle_rad / params.gear_ratio
    position = params.rod_left_m + params.crank_radius_m * (1.0 - ca.cos(crank))
    lever_m = params.crank_radius_m * ca.sin(crank) / params.gear_ratio
    return position, lever_m * omega, lever_m


def binding_torque(params: DriveParams, motor_angle_rad, torque_nm, position):
    """The extra friction torque, at the motor, of a gearbox that binds where the rod is at `position` (share of its
    stroke): a bell of `torque_nm` at its height and `params.binding_width` wide. Nothing no mode of the reduced models
    names (schemas/plant.py): an anomaly the plant can show."""
    share = 0.5 * (1.0 - ca.cos(motor_angle_rad / params.gear_ratio))
    return torque_nm * ca.exp(-0.5 * ((share - position) / params.binding_width) ** 2)


def motor_angle_at_rod(params: DriveParams, rod_m: float) -> float:
    """Motor angle (within the first half crank turn) that puts the rod at `rod_m`."""
    cosine = 1.0 - (rod_m - params.rod_left_m) / params.crank_radius_m
    if not -1.0 <= cosine <= 1.0:
        raise ValueError(f"rod position {rod_m} m is outside the crank's stroke")
    return params.gear_ratio * math.acos(cosine)
