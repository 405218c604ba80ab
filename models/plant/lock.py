"""End-position lock of the point machine.

Each end has a hook. It latches when the blade has closed against that end's
stock rail and the rod has reached that end of its stroke, and it lets go as
the driving bolt reaches the adjuster's closed position (the left hook as the
left bolt does, the right as the right). While latched it holds the blade
against moving away. So the blades start to move only when a bolt reaches the
adjuster, a misaligned bolt delays that moment, and a blade that did not close
is not caught. The hook's latch level (0 to 1) is a state, so a blade moving
into the closed position is never pulled in.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from railswitch.models.plant.adjuster import AdjusterParams
from railswitch.models.plant.drive import DriveParams
from railswitch.models.numerics.smooth import smooth_step, softplus


@dataclass(frozen=True)
class LockParams:
    slack_m: float = 0.002  # blade travel the latched hook allows
    stiffness_n_m: float = 2.0e6  # at the blade's drive point
    end_zone_m: float = 0.004  # rod travel from a dead centre within which the hook latches
    latch_rate_1_s: float = 200.0
    switch_width_m: float = 2e-4  # width of the smooth on/off conditions


@dataclass(frozen=True)
class LockTerms:
    force_n: object  # on the blades, positive to the right
    energy_j: object  # stored while latched
    # Each hook's level relaxes between 0 (released) and 1 (latched):
    # d(level)/dt = latch * (1 - level) - release * level, both rates >= 0 (left, right).
    latch_1_s: object
    release_1_s: object
    d_hooks: object  # latch-level derivatives (left, right)


def lock_terms(lock: LockParams, drive: DriveParams, adjuster: AdjusterParams, left_stock_m: float,
               right_stock_m: float, rail_m, rod_m, hooks, left_bolt_offset, right_bolt_offset,
               depth_width_m: float | None = None) -> LockTerms:
    """Force, energy and hook dynamics. `depth_width_m` rounds the holding spring (reduced models)."""
    w = lock.switch_width_m
    hook_left, hook_right = hooks[0], hooks[1]
    left_face = rod_m - (adjuster.free_play_m + left_bolt_offset)
    right_face = rod_m + (adjuster.free_play_m + right_bolt_offset)
    left_out = rail_m - (left_stock_m + lock.slack_m)  # > 0: a blade closed at the left moves away
    right_out = (right_stock_m - lock.slack_m) - rail_m
    at_left_end = smooth_step(drive.rod_left_m + lock.end_zone_m - rod_m, w)
    at_right_end = smooth_step(rod_m - (drive.rod_left_m + drive.stroke_m - lock.end_zone_m), w)
    released_left = smooth_step(left_face - drive.linkage_ratio * left_stock_m, w)
    released_right = smooth_step(drive.linkage_ratio * right_stock_m - right_face, w)
    closed_left, closed_right = smooth_step(-left_out, w), smooth_step(-right_out, w)
    d_left = lock.latch_rate_1_s * ((1 - hook_left) * closed_left * at_left_end - hook_left * released_left)
    d_right = lock.latch_rate_1_s * ((1 - hook_right) * closed_right * at_right_end - hook_right * released_right)
    if depth_width_m is None:
        left_depth, right_depth = ca.fmax(left_out, 0.0), ca.fmax(right_out, 0.0)
    else:
        left_depth, right_depth = softplus(left_out, depth_width_m), softplus(right_out, depth_width_m)
    k = lock.stiffness_n_m
    force = k * (hook_right * right_depth - hook_left * left_depth)
    energy = 0.5 * k * (hook_left * left_depth**2 + hook_right * right_depth**2)
    return LockTerms(force, energy, lock.latch_rate_1_s * ca.vertcat(closed_left * at_left_end, closed_right * at_right_end),
                     lock.latch_rate_1_s * ca.vertcat(released_left, released_right), ca.vertcat(d_left, d_right))


def latched_hooks(lock: LockParams, drive: DriveParams, left_stock_m: float, right_stock_m: float,
                  rail_m: float, rod_m: float) -> tuple[float, float]:
    """Hook levels of a switch at rest: latched at an end where the blade is closed and the rod arrived."""
    left = rail_m <= left_stock_m + lock.slack_m and rod_m <= drive.rod_left_m + lock.end_zone_m
    right = rail_m >= right_stock_m - lock.slack_m and rod_m >= drive.rod_left_m + drive.stroke_m - lock.end_zone_m
    return float(left), float(right)
