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
# Broyden's update predicts less of the decrease left than the exact Jacobian does: after a Gauss-Newton step the
# residual is nearly orthogonal to the old Jacobian's columns, and the update corrects them along the step only
# (on the diagnosis's fits the exact prediction was typically well above the update's). So the update alone ends a
# fit only when it predicts a tenth of the tolerance: on poly and nn fits the exact Jacobian would then seldom have
# gone on (and mostly for a decrease too small to matter); at the tolerance itself, many times as often.
BROYDEN_MARGIN = 10.0
GAUSS_NEWTON = 1e-9  # the damping of the step whose decrease `hopeless` judges (_promised): none to speak of


class Algebra:
    """The solver's dense linear algebra through numpy's BLAS and LAPACK: the fastest, its last digits those of the
    kernel OpenBLAS picks for the processor and of its number of threads."""

    def dot(self, x: np.ndarray, y: np.ndarray) -> float:
        """x'y."""
        return float(x @ y)

    def squares(self, r: np.ndarray) -> float:
        """r'r."""
        return self.dot(r, r)

    def quadratic(self, x: np.ndarray, a: np.ndarray) -> float:
        """x'a x."""
        return float(x @ a @ x)

    def gradient(self, a: np.ndarray, r: np.ndarray) -> np.ndarray:
        """a'r."""
        return a.T @ r

    def gram(self, a: np.ndarray) -> np.ndarray:
        """a'a (of a copy: numpy's gemm, the digits the diagnosis's fits were tuned with; a'a of one buffer is syrk's)."""
        return a.T @ a.copy()

    def solve(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """a^-1 b, a symmetric positive definite."""
        return np.linalg.solve(a, b)


class SameOnEveryProcessor(Algebra):
    """The same linear algebra in numbers that do not depend on the processor or the threads: sums in numpy's own
    fixed order (a pairwise sum along a row, rows added one after the other), a'a from BLAS products that are exact
    whatever their order, and a Cholesky factorisation written out. For training, whose fits run for many iterations
    and whose weights should be the same on every machine; slower than BLAS."""

    def dot(self, x: np.ndarray, y: np.ndarray) -> float:
        return float(np.sum(x * y))

    def quadratic(self, x: np.ndarray, a: np.ndarray) -> float:
        return self.dot(self.gradient(a, x), x)

    def gradient(self, a: np.ndarray, r: np.ndarray) -> np.ndarray:
        return np.sum(a * r[:, None], axis=0)

    def gram(self, a: np.ndarray) -> np.ndarray:
        """a'a to 2^-2b of each column's largest entry: every column scaled by a power of two and split into two
        integers of b bits (high, low), where the sum of a'a's n products of b-bit integers stays below 2^53. So
        high'high and high'low are exact in any summation order, with or without fused multiply-adds (Ozaki,
        Ogita, Oishi and Rump, Numer. Algorithms 59, 2012, error-free splitting of matrix products)."""
        bits = (53 - int(np.ceil(np.log2(max(a.shape[0], 2))))) // 2
        scale = np.ldexp(1.0, bits - np.frexp(np.max(np.abs(a), axis=0))[1])  # |a * scale| < 2^bits
        scaled = a * scale
        high = np.rint(scaled)
        low = np.rint((scaled - high) * 2.0**bits)  # |scaled - high| <= 1/2: below 2^(bits - 1)
        cross = high.T @ low
        return (high.T @ high + (cross + cross.T) * 2.0**-bits) / np.outer(scale, scale)

    def solve(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        n = len(b)
        lower = np.zeros_like(a)
        for j in range(n):
            row = lower[j, :j]
            lower[j, j] = np.sqrt(a[j, j] - np.sum(row * row))
            lower[j + 1:, j] = (a[j + 1:, j] - np.sum(lower[j + 1:, :j] * row, axis=1)) / lower[j, j]
        y = np.zeros(n)
        for i in range(n):
            y[i] = (b[i] - np.sum(lower[i, :i] * y[:i])) / lower[i, i]
        x = np.zeros(n)
        for i in range(n - 1, -1, -1):
            x[i] = (y[i] - np.sum(lower[i + 1:, i] * x[i + 1:])) / lower[i, i]
        return x


BLAS = Algebra()
SAME_ON_EVERY_PROCESSOR = SameOnEveryProcessor()


@dataclass
class Solution:
    """Where the solver stopped: parameters, residual and Jacobian there, r'r, iterations, r'r per iteration, and
    how many exact Jacobians it computed (0: its Jacobian is borrowed slopes, updated)."""

    z: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    cost: float
    iterations: int
    history: list[float] = field(default_factory=list)
    linearised: int = 0


def levenberg_marquardt(linearise: Linearise, z0: np.ndarray, *, cost: Callable[[np.ndarray], float] | None = None,
                        residual: Callable[[np.ndarray], np.ndarray] | None = None,
                        lower: np.ndarray | None = None, upper: np.ndarray | None = None,
                        scale: np.ndarray | None = None, iterations: int = 50, tolerance: float = 1e-4,
                        keep_going: Callable[[float, float, int], bool] | None = None,
                        hopeless: Callable[[float, float], bool] | None = None,
                        progress: Callable[[int, float], None] | None = None,
                        jacobian: np.ndarray | None = None,
                        first: tuple[np.ndarray, np.ndarray] | None = None, algebra: Algebra = BLAS) -> Solution:
    """Minimise r'r within [lower, upper] from z0.

    `cost(z)`, when given, evaluates r'r alone for trial points (cheaper than `linearise`, which
    then runs only at accepted points). `residual(z)`, when given instead, evaluates r alone for trial
    points, and the Jacobian at an accepted point is first Broyden's update of the last one (exact along
    the step taken; Madsen, Nielsen and Tingleff, "Methods for non-linear least squares problems", 2004,
    section 3.4): `linearise` runs there unless the update predicts a decrease below a BROYDEN_MARGIN-th of
    the tolerance, so a fit that has converged ends without a Jacobian spent on learning it (the Jacobian it
    returns is then the update). A fit stops when an iteration lowers r'r by less than
    `tolerance` of itself, or the next step is predicted to (by the linearised residual, before the step
    is tried, so a converged fit spends no rollout and no Jacobian on it), when a step is below
    SMALLEST_STEP, when no damped step improves (or the damped step's predicted decrease is below the
    tolerance), after `iterations`, or when `keep_going(cost, relative decrease, iteration)` says no, or when
    `hopeless(cost, decrease)` says yes of the most the linearised residual promises (_promised), asked wherever an
    exact Jacobian has just been computed (the start included).

    `jacobian`, when given (with `residual`), is borrowed for the start: slopes of the same model at z0 that an
    earlier fit computed. The start costs `residual` instead of `linearise`; the borrowed slopes judge whether the fit
    has converged there as Broyden's update would, and take the first step, which Broyden's update then corrects.
    Where that step does not lower r'r at its first try, or the slopes say the fit has not converged but promise
    too little to step, `linearise` runs at the start and the fit goes on from there as without them.

    `first`, when given, is what `linearise` returns at z0 (computed before, to choose the start): the fit does not
    compute it again. `algebra`: how the normal equations are formed and solved (SameOnEveryProcessor: the same
    numbers on any processor and number of threads).
    """
    z0 = np.asarray(z0, dtype=float)
    n = z0.size
    low = np.full(n, -np.inf) if lower is None else np.asarray(lower, dtype=float)
    high = np.full(n, np.inf) if upper is None else np.asarray(upper, dtype=float)
    scale = np.ones(n) if scale is None else np.asarray(scale, dtype=float)
    z = np.clip(z0, low, high)
    borrowed = jacobian is not None and residual is not None  # the first step is the borrowed slopes'
    if borrowed:
        r = residual(z)
    elif first is not None:
        r, jacobian = first
    else:
        r, jacobian = linearise(z)
    exact = not borrowed  # `jacobian` is linearise's at z, not Broyden's update or borrowed
    linearised = int(exact)
    value = algebra.squares(r)
    if not np.isfinite(value):
        raise ValueError("the starting point gives a non-finite residual; start closer")
    damping, k, history = 1e-4, 0, [value]
    while k < iterations:
        k += 1
        move, gradient, hessian = _normal_equations(jacobian * scale, r, z, low, high, algebra)
        if not exact:  # the update only says whether the fit has converged; else the exact Jacobian goes on
            if not move.any() and not borrowed:
                break
            if move.any():
                _, _, predicted, cut = _proposal(z, move, gradient, hessian, damping, scale, low, high, algebra)
                if predicted < tolerance * value / BROYDEN_MARGIN and not cut:
                    break
            if not borrowed or not move.any():
                r, jacobian = linearise(z)
                exact, borrowed, linearised = True, False, linearised + 1
                move, gradient, hessian = _normal_equations(jacobian * scale, r, z, low, high, algebra)
        if not move.any():
            break
        if exact and hopeless is not None and hopeless(value, _promised(move, gradient, hessian, algebra)):
            break
        accepted, trial_linearised, trial_residual = False, None, None
        for attempt in range(MAX_ATTEMPTS):
            step, trial, predicted, cut = _proposal(z, move, gradient, hessian, damping, scale, low, high, algebra)
            # Converged (first attempt) or given up (after a failed one) once the step promises no visible
            # decrease: the linear model's r'r, which is what a step this small would achieve. A step the bounds
            # cut short is not that step: cut along some parameters and whole along others, it may promise an
            # increase where a shorter one promises a decrease (a large obstacle's fit, its supply's step cut at
            # its bound, stopped at its grid point far below the truth), so it is damped and tried again.
            if predicted < tolerance * value:
                if not cut:
                    break
                damping *= 10
                continue
            if residual is not None:
                trial_residual = residual(trial)
                trial_value = algebra.squares(trial_residual)
            elif cost is None:
                trial_linearised = linearise(trial)
                trial_value = algebra.squares(trial_linearised[0])
            else:
                trial_value = cost(trial)
            if np.isfinite(trial_value) and trial_value < value:
                accepted = True
                break
            if borrowed:
                break
            damping *= 10
        if not accepted and borrowed:  # the borrowed slopes did not take a step: the exact ones go on from the start
            r, jacobian = linearise(z)
            exact, borrowed, linearised, k = True, False, linearised + 1, k - 1
            continue
        if not accepted:
            break
        borrowed = False
        decrease = (value - trial_value) / max(value, 1e-300)
        if trial_residual is not None:
            jacobian, r, exact = _broyden(jacobian, trial_residual - r, trial - z, scale), trial_residual, False
        else:
            r, jacobian = trial_linearised if trial_linearised is not None else linearise(trial)
            linearised += 1
        z = trial
        value, damping = algebra.squares(r), max(damping / 10, 1e-9)
        history.append(value)
        if progress is not None:
            progress(k, value)
        if decrease < tolerance or np.max(np.abs(step)) < SMALLEST_STEP:
            break
        if keep_going is not None and not keep_going(value, decrease, k):
            break
    return Solution(z, r, jacobian, value, k, history, linearised)


def _normal_equations(scaled: np.ndarray, r: np.ndarray, z: np.ndarray, low: np.ndarray,
                      high: np.ndarray, algebra: Algebra) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The parameters free to move (not at a bound their gradient points out of), the gradient J'r and
    the Gauss-Newton Hessian J'J of the free ones, in scaled units."""
    gradient = algebra.gradient(scaled, r)
    active = ((z <= low) & (gradient > 0)) | ((z >= high) & (gradient < 0))
    move = ~active
    return move, gradient, algebra.gram(scaled[:, move])


def _promised(move: np.ndarray, gradient: np.ndarray, hessian: np.ndarray, algebra: Algebra) -> float:
    """The decrease of r'r at the minimum of the linearised residual over the free parameters, bounds ignored: g'H^-1 g,
    the most any step can promise (a direction the residual does not see promises without limit)."""
    moving = gradient[move]
    return algebra.dot(moving, algebra.solve(_damped(hessian, GAUSS_NEWTON), moving))


def _damped(hessian: np.ndarray, damping: float) -> np.ndarray:
    """J'J with Marquardt's damping on its diagonal: damping times the diagonal itself."""
    damped = hessian.copy()
    damped.flat[::len(damped) + 1] += damping * (np.diagonal(hessian) + 1e-12)
    return damped


def _proposal(z: np.ndarray, move: np.ndarray, gradient: np.ndarray, hessian: np.ndarray, damping: float,
              scale: np.ndarray, low: np.ndarray, high: np.ndarray,
              algebra: Algebra) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """The damped step (scaled units), the trial point it reaches within the bounds, the decrease of r'r that the
    linearised residual predicts there, and whether the bounds cut the step short."""
    step = np.zeros(z.size)
    moving = gradient[move]
    step[move] = algebra.solve(_damped(hessian, damping), -moving)
    reached = z + step * scale
    trial = np.minimum(np.maximum(reached, low), high)
    taken = ((trial - z) / scale)[move]  # parameters held at a bound do not move
    predicted = -(2.0 * algebra.dot(moving, taken) + algebra.quadratic(taken, hessian))
    return step, trial, predicted, bool((trial != reached).any())


def _broyden(jacobian: np.ndarray, change: np.ndarray, step: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Broyden's rank-one update of `jacobian` after `step` changed the residual by `change`: the least change
    (in scaled units) that makes it exact along the step."""
    u = step / scale
    return jacobian + np.outer(change - jacobian @ step, u / scale) / (u @ u)
