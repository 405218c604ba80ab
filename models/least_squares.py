"""Bounded Levenberg-Marquardt: the one least-squares solver of training and estimation.

Minimises r(z)'r(z) from the residual and its Jacobian (Gauss-Newton Hessian J'J), with
Marquardt's scaling of the damping by diag(J'J) (Marquardt, J. SIAM 11, 1963) and simple
bounds by projection: a parameter at a bound whose gradient points outwards is held
there for the step, the others move, and the step is clipped to the box. Parameters are
given a scale so that the solver works on numbers of order one.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

Linearise = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]  # z -> (r, dr/dz)
MAX_ATTEMPTS = 12  # damped steps tried per iteration before giving up
SMALLEST_STEP = 1e-6  # in scaled units: a step below this changes nothing a decision can see


@dataclass
class Solution:
    """Where the solver stopped: parameters, residual and Jacobian there, r'r, iterations, r'r per iteration."""

    z: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    cost: float
    iterations: int
    history: list[float] = field(default_factory=list)


def levenberg_marquardt(linearise: Linearise, z0: np.ndarray, *, cost: Callable[[np.ndarray], float] | None = None,
                        lower: np.ndarray | None = None, upper: np.ndarray | None = None,
                        scale: np.ndarray | None = None, iterations: int = 50, tolerance: float = 1e-4,
                        keep_going: Callable[[float, float, int], bool] | None = None,
                        progress: Callable[[int, float], None] | None = None) -> Solution:
    """Minimise r'r within [lower, upper] from z0.

    `cost(z)`, when given, evaluates r'r alone for trial points (cheaper than `linearise`, which
    then runs only at accepted points). A fit stops when an iteration lowers r'r by less than
    `tolerance` of itself, or the next step is predicted to (by the linearised residual, before the step
    is tried, so a converged fit spends no rollout and no Jacobian on it), when a step is below
    SMALLEST_STEP, when no damped step improves (or the damped step's predicted decrease is below the
    tolerance), after `iterations`, or when `keep_going(cost, relative decrease, iteration)` says no.
    """
    z0 = np.asarray(z0, dtype=float)
    n = z0.size
    low = np.full(n, -np.inf) if lower is None else np.asarray(lower, dtype=float)
    high = np.full(n, np.inf) if upper is None else np.asarray(upper, dtype=float)
    scale = np.ones(n) if scale is None else np.asarray(scale, dtype=float)
    z = np.clip(z0, low, high)
    r, jacobian = linearise(z)
    value = float(r @ r)
    if not np.isfinite(value):
        raise ValueError("the starting point gives a non-finite residual; start closer")
    damping, k, history = 1e-4, 0, [value]
    for k in range(1, iterations + 1):
        scaled = jacobian * scale
        gradient = scaled.T @ r
        active = ((z <= low) & (gradient > 0)) | ((z >= high) & (gradient < 0))
        move = ~active
        if not move.any():
            break
        hessian = scaled[:, move].T @ scaled[:, move]
        accepted, trial_linearised = False, None
        for attempt in range(MAX_ATTEMPTS):
            step = np.zeros(n)
            step[move] = np.linalg.solve(hessian + damping * np.diag(np.diag(hessian) + 1e-12), -gradient[move])
            trial = np.clip(z + step * scale, low, high)
            # Converged (first attempt) or given up (after a failed one) once the step promises no visible
            # decrease: the linear model's r'r, which is what a step this small would achieve.
            taken = ((trial - z) / scale)[move]  # parameters held at a bound do not move
            if -(2.0 * gradient[move] @ taken + taken @ hessian @ taken) < tolerance * value:
                break
            if cost is None:
                trial_linearised = linearise(trial)
                trial_value = float(trial_linearised[0] @ trial_linearised[0])
            else:
                trial_value = cost(trial)
            if np.isfinite(trial_value) and trial_value < value:
                accepted = True
                break
            damping *= 10
        if not accepted:
            break
        decrease = (value - trial_value) / max(value, 1e-300)
        z = trial
        r, jacobian = trial_linearised if trial_linearised is not None else linearise(z)
        value, damping = float(r @ r), max(damping / 10, 1e-9)
        history.append(value)
        if progress is not None:
            progress(k, value)
        if decrease < tolerance or np.max(np.abs(step)) < SMALLEST_STEP:
            break
        if keep_going is not None and not keep_going(value, decrease, k):
            break
    return Solution(z, r, jacobian, value, k, history)
