"""Fault augmentation (paper, section "Fault augmentation").

Bolt offsets act inside the adjuster (models/plant/adjuster.py); this file adds the
two rail-side fault components: extra viscous friction where bearings are
stuck or missing, and localised friction around an obstacle.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from railswitch.schemas.faults import FAULT_PARAMETERS

FAULT_ORDER: tuple[str, ...] = tuple(FAULT_PARAMETERS)


@dataclass(frozen=True)
class ObstacleParams:
    """Width of the region around `obstacle_position` where the obstacle rubs."""

    width_m: float = 0.012  # standard deviation of the Gaussian friction profile


def fault_vector(faults: dict[str, float] | None = None) -> np.ndarray:
    """Fault parameters in FAULT_ORDER, nominal where not given."""
    faults = faults or {}
    return np.array([float(faults.get(name, FAULT_PARAMETERS[name].nominal)) for name in FAULT_ORDER])


def unpack(vector) -> dict:
    """Name the entries of a (symbolic or numeric) fault vector."""
    return {name: vector[i] for i, name in enumerate(FAULT_ORDER)}


def bearing_weights(masses_kg: np.ndarray, shape: np.ndarray) -> np.ndarray:
    """Per-node share of `bearing_friction`, spread like the rail's mass.

    Normalised so that for motion in the rail's static shape the added
    friction at the drive point equals `bearing_friction` times its velocity.
    """
    return masses_kg / float(np.sum(masses_kg * shape**2))


def obstacle_profile(params: ObstacleParams, drive_m, obstacle_position):
    """Localised friction weight, 1 at the obstacle, Gaussian around it."""
    return ca.exp(-0.5 * ((drive_m - obstacle_position) / params.width_m) ** 2)
