"""Adjuster: floats on the drive rod between a left and a right bolt.

The free play between the bolts and the adjuster delays the moment the rails
start to move (paper, section "Rail switch model"); a misaligned bolt changes
that free play (section "Fault augmentation"). A positive offset means more
free play, so contact happens later.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from railswitch.models.numerics.smooth import softplus


@dataclass(frozen=True)
class AdjusterParams:
    """Nominal free play on each side and the bolt contact law."""

    free_play_m: float = 0.04  # on the rod, each side
    contact_stiffness_n_m: float = 1.0e6
    contact_damping_s_m: float = 5.0  # Hunt-Crossley lambda / stiffness [s/m]


def unilateral_contact(penetration_m, penetration_rate_m_s, stiffness_n_m: float, damping_s_m: float):
    """Hunt-Crossley contact force, never pulling: k*d*(1 + lambda*d'), zero when apart.

    Dissipative for any penetration history: its power balance against the
    stored k*d^2/2 is -k*lambda*d*d'^2 <= 0.
    """
    depth = ca.fmax(penetration_m, 0.0)
    return ca.fmax(stiffness_n_m * depth * (1.0 + damping_s_m * penetration_rate_m_s), 0.0)


def smooth_contact(penetration_m, penetration_rate_m_s, stiffness_n_m: float, damping_s_m: float,
                   width_m: float = 2e-4):
    """Differentiable stand-in for `unilateral_contact` (softplus depth of `width_m`), for the reduced models."""
    depth = softplus(penetration_m, width_m)
    return stiffness_n_m * depth * (1.0 + damping_s_m * penetration_rate_m_s)


def adjuster_force(params: AdjusterParams, rod_m, rod_velocity_m_s, adjuster_m, adjuster_velocity_m_s,
                   left_bolt_offset, right_bolt_offset, contact=unilateral_contact):
    """Force the bolts exert on the adjuster along the rod (positive pushes to the right).

    All positions are rod coordinates (see models/plant/drive.py). `contact` is the
    contact law: the plant's exact one or `smooth_contact`.
    """
    left_face = rod_m - (params.free_play_m + left_bolt_offset)
    right_face = rod_m + (params.free_play_m + right_bolt_offset)
    relative = rod_velocity_m_s - adjuster_velocity_m_s
    push_right = contact(left_face - adjuster_m, relative, params.contact_stiffness_n_m, params.contact_damping_s_m)
    push_left = contact(adjuster_m - right_face, -relative, params.contact_stiffness_n_m, params.contact_damping_s_m)
    return push_right - push_left


def adjuster_energy(params: AdjusterParams, rod_m, adjuster_m, left_bolt_offset, right_bolt_offset):
    """Elastic energy stored in the bolt contacts."""
    left = ca.fmax(rod_m - (params.free_play_m + left_bolt_offset) - adjuster_m, 0.0)
    right = ca.fmax(adjuster_m - rod_m - (params.free_play_m + right_bolt_offset), 0.0)
    return 0.5 * params.contact_stiffness_n_m * (left**2 + right**2)
