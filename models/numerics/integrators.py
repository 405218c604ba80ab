"""Fixed-step integration steps built symbolically in CasADi (for reduced models and training).

ROS2 is the two-stage, second-order, L-stable Rosenbrock method of Verwer et al.
(SIAM J. Sci. Comput. 20, 1999), gamma = 1 + 1/sqrt(2). W (the exact AD Jacobian
unless the caller gives a stand-in) is taken at the start of every substep and its
factorisation shared by both stages.

`relax` advances a gating variable (a level between 0 and 1 that relaxes at
state-dependent rates) by the exact solution of its linear equation with the rates
frozen: the Rush-Larsen scheme (Rush and Larsen, IEEE Trans. Biomed. Eng. 25, 1978).
It keeps the level inside [0, 1] for any step, where a linearly implicit step whose
W was taken before a rate switched on would overshoot.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import casadi as ca

ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


def lu_solver(a):
    """Solve a x = b for many b with one symbolic LU of `a` (no pivoting: a = I - gamma*h*J
    is dominated by its identity for the step sizes used); SX drops structural zeros."""
    n = a.shape[0]
    lower = [[None] * n for _ in range(n)]
    upper = [[a[i, j] for j in range(n)] for i in range(n)]
    for k in range(n):
        for i in range(k + 1, n):
            factor = upper[i][k] / upper[k][k]
            lower[i][k] = factor
            for j in range(k, n):
                upper[i][j] = upper[i][j] - factor * upper[k][j]

    def solve(b):
        y = [b[i] for i in range(n)]
        for i in range(n):
            for k in range(i):
                y[i] = y[i] - lower[i][k] * y[k]
        x = [None] * n
        for i in reversed(range(n)):
            total = y[i]
            for j in range(i + 1, n):
                total = total - upper[i][j] * x[j]
            x[i] = total / upper[i][i]
        return ca.vertcat(*x)
    return solve


def ros2(rhs: Callable, state, h: float, substeps: int, w_rhs: Callable | None = None):
    """Advance `state` by `substeps` ROS2 steps of `h`; rhs(state, fraction) with fraction in [0, 1].

    ROS2 is a W-method: it stays second order with any matrix W in place of the
    Jacobian. `w_rhs(x, fraction, point)`, when given, is a stand-in right-hand side
    whose Jacobian at `point` serves as W (for instance one with learned terms
    replaced by their dissipative, frozen-coefficient linearisation, so that
    I - gamma*h*W can never become singular).

    Each stage calls `rhs` at its own point, so whatever `rhs` builds there belongs to that point (the
    reduced switch's sensitivities stand its learned rail in by one such piece per point).
    """
    for k in range(substeps):
        t0, t1 = k / substeps, (k + 1) / substeps
        x = ca.SX.sym("x", state.shape[0])
        stand_in = rhs(x, t0) if w_rhs is None else w_rhs(x, t0, state)
        jacobian = ca.substitute(ca.jacobian(stand_in, x), x, state)
        solve = lu_solver(ca.SX.eye(state.shape[0]) - ROS2_GAMMA * h * jacobian)
        k1 = solve(rhs(state, t0))
        k2 = solve(rhs(state + h * k1, t1) - 2.0 * k1)
        state = state + h * (1.5 * k1 + 0.5 * k2)
    return state


def relax(level, rise_1_s, fall_1_s, h: float):
    """Exact step of d(level)/dt = rise * (1 - level) - fall * level over `h` with the rates frozen.

    The result is a convex combination of the level and its target rise / (rise + fall), so it
    stays in [0, 1] whatever the rates and the step."""
    total = rise_1_s + fall_1_s
    decay = ca.exp(-total * h)
    return decay * level - ca.expm1(-total * h) / (total + 1e-300) * rise_1_s
