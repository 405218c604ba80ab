"""Fault-parameter estimation for one throw (paper, section "Fault diagnosis").

Each hypothesis (nominal, one per fault mode, joint) frees its parameters within
the ranges of docs/contracts.md section 2 and fits the reduced switch model to the
throw's measured current, angle and angular velocity, each scaled by its range,
so the cost is the mean squared error of the three scaled signals. Bounded
Levenberg-Marquardt on CasADi's exact Jacobian (Gauss-Newton Hessian), a coarse
grid of cheap residual evaluations as global start where the error is
multimodal (a bolt offset or an obstacle position moves the instant something
happens, not only its size), standard deviations from the Gauss-Newton Hessian
and the residual variance. The residual, its Jacobians (forward sensitivities
along one, two or all fault parameters) and the grid's costs are CasADi
Functions built (and compiled) once per estimator and reused for every throw.
A fit stops when the MSE falls by less than TOLERANCE in an iteration, a change
no decision can see, or when it can no longer fit better than another hypothesis.

The rail is not measured, so each throw starts from a given rail position: the
end of the previous throw's fit, or the closed position.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from railswitch.models.faults import FAULT_ORDER, fault_vector
from railswitch.models.least_squares import levenberg_marquardt
from railswitch.models.reduced import OUTPUTS, Compiler, ReducedSwitch
from railswitch.models.reference import Reference
from railswitch.models.signals import SIGNAL_NAMES as MEASURED
from railswitch.models.signals import MotorSignals
from railswitch.schemas.faults import FAULT_PARAMETERS, MODE_PARAMETERS
# Order-one scales of the parameters for the solver.
SCALES = {"left_bolt_offset": 0.05, "right_bolt_offset": 0.05, "bearing_friction": 5e3,
          "obstacle_friction": 1e5, "obstacle_position": 0.05}
# Derivative directions of the compiled linearisations: one- and two-parameter modes, the joint fit.
LINEARISED_DIRECTIONS = (1, 2, len(FAULT_ORDER))
TOLERANCE = 1e-4  # relative decrease of the MSE below which a fit has converged
HYPOTHESES: dict[str, tuple[str, ...]] = {"nominal": (), **MODE_PARAMETERS, "joint": tuple(FAULT_ORDER)}
# A bolt drives the blades in one direction only (the left bolt from left to right).
DRIVING_BOLT = {"left_to_right": "left_bolt", "right_to_left": "right_bolt"}
# Cheap global starts: residual-only evaluations on a coarse grid, refined once by evaluating the
# neighbours half a step away along the parameter that moves where things happen (a bolt offset,
# the obstacle position); the best point starts the solver. The bolt that does not drive this
# throw (it shows only at the start of the throw) has no grid: it starts where earlier throws left it.
GRID_STEP = {"left_bolt_offset": 0.02, "right_bolt_offset": 0.02, "obstacle_position": 0.02}
_BOLT_GRID = np.arange(-0.02, 0.2001, GRID_STEP["left_bolt_offset"])
_OBSTACLE_GRID = [{"obstacle_position": p, "obstacle_friction": f}
                  for p in np.arange(1.02, 1.1801, GRID_STEP["obstacle_position"]) for f in (3e4, 1.5e5)]
GRID_STARTS: dict[str, dict[str, list[dict[str, float]]]] = {
    direction: {
        bolt: [{MODE_PARAMETERS[bolt][0]: b} for b in _BOLT_GRID],
        "missing_bearing": [{"bearing_friction": f} for f in (0.0, 1e3, 3e3, 6e3, 1e4)],
        "obstacle": _OBSTACLE_GRID,
    } for direction, bolt in DRIVING_BOLT.items()
}
_GRID_SIZES = {sum(len(points) for points in grids.values()) for grids in GRID_STARTS.values()}
assert len(_GRID_SIZES) == 1, "one mapped grid Function serves both directions"
_GRID_SIZE = _GRID_SIZES.pop()


class InPlace:
    """A CasADi Function evaluated on its own numpy buffers: no DM is made per call.

    Arguments are copied into the input buffers (column-major, as CasADi stores them); the outputs
    come back as new arrays shaped like the Function's outputs. One set of buffers per Function, so
    calls must not overlap (the diagnoser diagnoses in one thread).
    """

    def __init__(self, function: ca.Function):
        self.function = function
        self._buffer, self._trigger = function.buffer()
        self._inputs = [np.zeros(function.nnz_in(i)) for i in range(function.n_in())]
        self._outputs = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
        self._shapes = [function.size_out(i) for i in range(function.n_out())]
        for i, slot in enumerate(self._inputs):
            self._buffer.set_arg(i, memoryview(slot))
        for i, slot in enumerate(self._outputs):
            self._buffer.set_res(i, memoryview(slot))

    def __call__(self, *args) -> list[np.ndarray]:
        for slot, value in zip(self._inputs, args, strict=True):
            slot[:] = np.asarray(value, dtype=float).ravel(order="F")
        self._trigger()
        return [out.reshape(shape, order="F").copy() for out, shape in zip(self._outputs, self._shapes)]


@dataclass(frozen=True)
class Measurement:
    """One throw's N samples after its start, its direction and reference, and the state it starts from."""

    direction: str
    reference: Reference
    signals: MotorSignals
    start_angle_rad: float
    start_rail_m: float
    # Faults known from earlier throws that this throw cannot show (the other direction's bolt):
    # held at these values in every hypothesis that does not free them.
    background: dict[str, float] = field(default_factory=dict)

    def scales(self) -> np.ndarray:
        """Range of each measured signal over the throw (the residual's scale)."""
        return np.maximum(np.ptp(self.signals.matrix(), axis=0), 1e-6)


@dataclass(frozen=True)
class Estimate:
    """One hypothesis fitted: its free parameters, their standard deviations and the fit's MSE."""

    mode: str
    params: dict[str, float]
    std: dict[str, float]
    mse: float
    iterations: int
    residual: np.ndarray  # scaled residuals of current, angle and velocity, one column each


def _estimate(mode: str, params: dict, std: dict, r: np.ndarray, iterations: int) -> Estimate:
    """An Estimate from the solver's residual vector (divided by sqrt(3N), stacked signal by signal)."""
    return Estimate(mode, params, std, float(r @ r), iterations, r.reshape(len(MEASURED), -1).T * np.sqrt(r.size))


def _bounds(names) -> tuple[np.ndarray, np.ndarray]:
    return (np.array([FAULT_PARAMETERS[n].low for n in names]), np.array([FAULT_PARAMETERS[n].high for n in names]))


class ThrowEstimator:
    """Fits every hypothesis to throws of `samples` samples; build once, call per throw."""

    def __init__(self, reduced: ReducedSwitch, samples: int, compiler: Compiler | None = None):
        """`compiler` turns the estimator's Functions into machine code (None: interpreted)."""
        self.reduced = reduced
        self.samples = samples
        theta = ca.MX.sym("theta", len(FAULT_ORDER))
        s0 = ca.MX.sym("s0", reduced.step.size1_in(0))
        refs = ca.MX.sym("refs", 2, samples)
        measured = ca.MX.sym("measured", samples, len(MEASURED))
        inverse_scale = ca.MX.sym("inverse_scale", 1, len(MEASURED))
        inputs = [theta, s0, refs, measured, inverse_scale]

        def scaled(signals):
            """N x 3 signals scaled, stacked signal by signal and divided by sqrt(3N), so that r'r is
            the mean squared error of the scaled signals."""
            return ca.vec(signals * ca.repmat(inverse_scale, samples, 1)) / np.sqrt(samples * len(MEASURED))

        def measured_rows(outputs):
            """The measured signals of a 6 x N block of outputs (or of their derivatives), N x 3."""
            return ca.horzcat(*[outputs[OUTPUTS.index(name), :].T for name in MEASURED])

        y, _ = reduced._rollout(samples)(s0, refs, theta, reduced.weights)
        residual = scaled(measured_rows(y) - measured)
        functions = [ca.Function("throw_residual", inputs, [residual])]
        for k in LINEARISED_DIRECTIONS:  # residual and its derivative along k fault directions
            seeds = ca.MX.sym("seeds", len(FAULT_ORDER), k)
            y, y_dot = reduced.sensitivity_rollout(samples, k)(s0, refs, theta, seeds, reduced.weights)
            blocks = [y_dot[j * len(OUTPUTS):(j + 1) * len(OUTPUTS), :] for j in range(k)]
            jacobian = ca.horzcat(*[scaled(measured_rows(block)) for block in blocks])
            functions.append(ca.Function(f"throw_linearised{k}", [*inputs, seeds],
                                         [scaled(measured_rows(y) - measured), jacobian]))
        cost = ca.Function("throw_cost", inputs, [ca.sumsqr(residual)])
        # Every grid start in one call; only theta is mapped, the throw's data is shared.
        functions.append(cost.map("throw_grid", "serial", _GRID_SIZE, list(range(1, len(inputs))), []))
        if compiler is not None:
            functions = compiler(functions)
        self._residual, *linearised, self._grid = [InPlace(f) for f in functions]
        self._linearised = dict(zip(LINEARISED_DIRECTIONS, linearised))

    def _data(self, m: Measurement) -> tuple:
        s0 = self.reduced.initial_state(m.start_rail_m, m.start_angle_rad)
        return s0, self.reduced.reference_columns(m.reference, self.samples), m.signals.matrix(), 1.0 / m.scales()[None, :]

    def _residuals(self, theta: np.ndarray, data: tuple) -> np.ndarray:
        return self._residual(theta, *data)[0].ravel()

    def _cost(self, theta: np.ndarray, data: tuple) -> float:
        r = self._residuals(theta, data)
        cost = float(r @ r)
        return cost if np.isfinite(cost) else np.inf

    def _linearise(self, theta: np.ndarray, data: tuple, index: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Residual and its Jacobian columns for the parameters at `index`."""
        k = min(d for d in LINEARISED_DIRECTIONS if d >= len(index))
        seeds = np.zeros((len(FAULT_ORDER), k))
        seeds[index, range(len(index))] = 1.0
        r, j = self._linearised[k](theta, *data, seeds)
        return r.ravel(), j[:, :len(index)]

    def fit(self, mode: str, m: Measurement, data: tuple | None = None, start: dict[str, float] | None = None,
            iterations: int = 20, rival: float = np.inf) -> Estimate:
        """Fit one hypothesis from `start` (warm start or grid point; nominal elsewhere).

        With `rival` (the lowest MSE another hypothesis reached), the fit stops early once it is above
        the rival and, at its latest rate of decrease, would still be above it after its remaining
        iterations: a hypothesis that cannot fit best is not refined further.
        """
        data = data if data is not None else self._data(m)
        free = list(HYPOTHESES[mode])
        theta = fault_vector({**m.background, **{k: v for k, v in (start or {}).items() if k in free}})
        if not free:
            return _estimate(mode, {}, {}, self._residuals(theta, data), 0)
        index = [FAULT_ORDER.index(n) for n in free]
        low, high = _bounds(free)

        def at(values: np.ndarray) -> np.ndarray:
            full = theta.copy()
            full[index] = values
            return full

        def keep_going(cost: float, decrease: float, k: int) -> bool:  # can it still beat the rival?
            return cost * (1.0 - decrease) ** (iterations - k) <= rival

        solution = levenberg_marquardt(lambda z: self._linearise(at(z), data, index), theta[index],
                                       cost=lambda z: self._cost(at(z), data), lower=low, upper=high,
                                       scale=np.array([SCALES[n] for n in free]), iterations=iterations,
                                       tolerance=TOLERANCE, keep_going=keep_going)
        return _estimate(mode, {n: float(v) for n, v in zip(free, solution.z)},
                         self._std(solution.jacobian, solution.cost, free), solution.residual, solution.iterations)

    def _std(self, jacobian: np.ndarray, cost: float, free: list[str]) -> dict[str, float]:
        """Gauss-Newton covariance: residual variance times (J'J)^-1; no information means the range."""
        n = jacobian.shape[0]
        variance = cost * n / max(n - len(free), 1)  # per scaled sample (r is divided by sqrt(n))
        low, high = _bounds(free)
        try:
            covariance = variance / n * np.linalg.inv(jacobian.T @ jacobian)
            std = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        except np.linalg.LinAlgError:
            std = high - low
        std = np.where(np.isfinite(std), np.minimum(std, high - low), high - low)
        return {name: float(s) for name, s in zip(free, std)}

    def grid_starts(self, m: Measurement, data: tuple) -> dict[str, dict[str, float]]:
        """The best point of each mode's coarse grid, by residual alone (all grids in one call)."""
        grids = GRID_STARTS[m.direction]
        points = [p for mode_points in grids.values() for p in mode_points]
        thetas = np.column_stack([fault_vector({**m.background, **p}) for p in points])
        costs = self._grid(thetas, *data)[0].ravel()
        costs = np.where(np.isfinite(costs), costs, np.inf)
        best, lowest, first = {}, {}, 0
        for mode, mode_points in grids.items():
            k = int(np.argmin(costs[first:first + len(mode_points)]))
            best[mode], lowest[mode] = mode_points[k], costs[first + k]
            first += len(mode_points)
        for mode, point in list(best.items()):  # halve the step around the best point
            for name in [name for name in GRID_STEP if name in point]:
                for value in (point[name] - GRID_STEP[name] / 2, point[name] + GRID_STEP[name] / 2):
                    if FAULT_PARAMETERS[name].low <= value <= FAULT_PARAMETERS[name].high:
                        neighbour = {**point, name: value}
                        cost = self._cost(fault_vector({**m.background, **neighbour}), data)
                        if cost < lowest[mode]:
                            best[mode], lowest[mode] = neighbour, cost
        return best

    def fit_all(self, m: Measurement) -> dict[str, Estimate]:
        """Every hypothesis (grid-started), then the joint fit warm-started from the best of them."""
        data = self._data(m)
        out = {"nominal": self.fit("nominal", m, data)}
        starts = self.grid_starts(m, data)
        for mode in MODE_PARAMETERS:
            rival = min(estimate.mse for estimate in out.values())
            out[mode] = self.fit(mode, m, data, starts.get(mode), rival=rival)
        best = min(MODE_PARAMETERS, key=lambda mode: out[mode].mse)
        out["joint"] = self.fit("joint", m, data, out[best].params)
        return out

    def simulate(self, m: Measurement, faults: dict[str, float]) -> dict[str, np.ndarray]:
        """The reduced model's outputs and final state for this throw under `faults` (and the background)."""
        s0 = self.reduced.initial_state(m.start_rail_m, m.start_angle_rad)
        return self.reduced.simulate(s0, m.reference, self.samples, {**m.background, **faults})
