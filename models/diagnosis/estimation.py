"""Parameter estimation for one throw (paper, section "Fault diagnosis").

A hypothesis frees some of the reduced model's parameters (faults and the switch's own
build and weather, models/reduced/hybrid.py PARAMETERS) within bounds, holds the others, and
fits the model to the throw's measured current, angle and angular velocity (or the current
alone, where a unit logs nothing else), each scaled by its range, so the cost is the mean
squared error of the scaled signals.
Bounded Levenberg-Marquardt (models/numerics/least_squares.py): every step from an exact Jacobian, trial
points judged by their residual, and at an accepted point Broyden's update of the last Jacobian
deciding first whether the fit has converged (one that has ends on that update). Where the error
is multimodal (a bolt offset or an obstacle position moves the instant something happens, not
only its size) the best of a grid of cheap residual evaluations (the model at its 20 ms training
step, GRID_RATE_HZ) starts it, or the hypothesis's fit to the switch's previous throw where that
fits better; on a throw where nothing has changed (SETTLED) a fault can only be a small one, and the
grid shrinks to what a small fault can be.

The model runs on its own grid (`MODEL_RATE_HZ`, one integration step per model sample)
in compiled chunks of `CHUNK_SAMPLES`, as many as the throw needs; the residual compares
the model, interpolated linearly at each sample's time, with the sample. So one compiled
estimator serves throws of any length and any sample rate. Forward sensitivities ride
through the chunks for the Jacobian.

Standard deviations are the Gauss-Newton covariance with the residual variance, widened by
N / N_eff: the residual of a reduced model is smooth model error, not white noise, and
counts as N_eff independent samples (effective_samples). What the model's error does to
an estimate beyond that is the caller's to add (models/diagnosis/switch_diagnoser.py).

The rail is not measured, so each throw starts from a given rail position: the end of
the previous throw's fit, or the closed position.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from railswitch.models.numerics.buffers import InPlace
from railswitch.models.numerics.statistics import effective_samples
from railswitch.models.numerics.least_squares import levenberg_marquardt
from railswitch.models.reduced.hybrid import OUTPUTS, PARAMETERS, STATES, Compiler, ReducedSwitch, kernels, rolled
from railswitch.models.plant.reference import Reference
from railswitch.models.plant.signals import SIGNAL_NAMES as MEASURED
from railswitch.models.plant.signals import MotorSignals

# The model's grid: 10 ms, half the step the rails are trained at. On the 20 ms step itself an event (a bolt
# taking up its play, an obstacle met) that moves across a step boundary leaves ripples in the error surface
# where the solver stalls (it stopped a twin throw's bolt well short of its length, and the estimates' error widened).
MODEL_RATE_HZ = 100.0
# Model samples per compiled call: 1 s. A throw's rollout is a whole number of chunks, so a shorter chunk
# wastes less past the throw's last sample (with 2 s chunks, a 7 s throw ran a whole second past its end).
CHUNK_SAMPLES = 100
# The grid ranks starting points 20 mm (a bolt, an obstacle's position) or a factor of two (a friction) apart:
# which basin a point lies in, not where in it the minimum is. The ripples of a 20 ms step (above) are far
# smaller than that, so the grid runs the model at the step it was trained at, in half as many steps.
GRID_RATE_HZ = 50.0
# Grid points evaluated in one mapped call: every hypothesis's grid of a throw at once (37 points for the
# switch's hypotheses, models/diagnosis/switch_diagnoser.py) and each fault mode's warm start (4). A point costs what a
# rollout does whether it is used or padding, so the capacity is what a throw needs; a settled throw (below)
# needs the bolt's mark, the obstacle's grid at its lesser friction and their warm starts (12).
GRID_CAPACITY = 41
SETTLED_CAPACITY = 12
# A throw is settled when the switch's previous throw in its direction was healthy and this one's nominal fit
# is within this share of that one's MSE: nothing has changed beyond what a healthy switch's MSE varies by from
# one throw to the next (about sqrt(2 / N_eff), N_eff the throw's effective samples). A fault that has
# appeared on a settled throw is a small one, so a settled throw ranks each hypothesis's `settled_grid`
# (HypothesisSpec) and its warm start: none for a bearing's or the point machine's friction (their error
# surface has one basin, which the warm start is in), a small obstacle's positions for the obstacle (one
# fitted to a healthy throw sits at an end of the travel with no friction, where its position has no slope,
# so from there it misses a new one), its mark (0) for a bolt: its offset moves the instant the blades do, so a bolt
# that moves 10 mm raises the nominal fit's MSE well beyond SETTLED (poly, both directions), and one a settled
# throw can hide is within a few millimetres of its warm fit or its mark. On every settled throw of poly and
# nn (switches of the population), the bolt's whole grid (12 points) had started it at its mark or its warm fit.
SETTLED = 0.1
# Order-one scales of the parameters for the solver.
SCALES = {"left_bolt_offset": 0.05, "right_bolt_offset": 0.05, "bearing_friction": 5e3,
          "obstacle_friction": 1e5, "obstacle_position": 0.05, "drive_friction_nm": 0.05,
          "motor.coulomb_friction_nm": 0.05, "motor.torque_constant_nm_a": 0.01, "motor.resistance_ohm": 1.0,
          "motor.supply_v": 10.0, "rail.chair_friction_coefficient": 0.01}
# A fault's parameter whose error surface may hold more than one basin near the fit (HypothesisSpec.scanned),
# where the solver stops in the first it meets. A bolt's did: the causal rail's, as fine-tuned before its inertia
# was held (models/reduced/training.py), was a sawtooth with teeth a few millimetres wide that stopped a bolt well short of
# its length; poly's and nn's have shallow ripples closer together, some of them lower than where the solver stops.
# So once a scanned hypothesis fits a throw best and explains a tenth of the nominal fit's misfit (SCAN_WHEN), its
# parameter is tried at SCAN_CAPACITY points SCAN_STEP apart around the fit, the rest held, and refitted from the
# lowest where that is lower: at least two points on every tooth, over several teeth either side.
SCAN_STEP = 0.0015
SCAN_CAPACITY = 16
SCAN_OFFSETS = SCAN_STEP * np.concatenate([np.arange(-SCAN_CAPACITY // 2, 0), np.arange(1, SCAN_CAPACITY // 2 + 1)])
SCAN_WHEN = 0.9
SCAN_ROUNDS = 3
TOLERANCE = 1e-4  # relative decrease of the MSE below which a fit has converged
# A fit that cannot beat a fault already shown stops (ThrowEstimator.fit_all): where its objective less this many
# times what its linearisation promises at most is still above that fault's. On faulty throws (benchmarks.diagnosis's
# cases, seeds 7 and 11), what a fit went on to gain from its start was typically about its first linearisation's
# promise and seldom more than this margin times it (more only where the promise was a tiny part of the objective);
# the fault that ended best would have been stopped only at a margin close to one, had every other fault been fitted
# before it (its start less that margin times its promise is above the next best fault's end).
HOPELESS_MARGIN = 5.0
# On a settled throw, a fault mode's fit that starts where its fit of the switch's previous throw in the same direction
# ended borrows that fit's Jacobian for its first step (Slopes; levenberg_marquardt's `jacobian`) instead of computing
# one (ThrowEstimator.fit_all says where not): the model's slopes there are the same but for the throw's start and
# the weather, which a throw or two moves little.
# On poly's commissioning throws the borrowed slopes (computed one throw before) predicted the first step's decrease
# close to what the exact ones did. Slopes last computed this many throws back are not
# borrowed: the fit computes them again, so Broyden's updates never stand in for them for long.
SLOPES_AGE = 2
OUTPUTS_KEPT = 32  # rollouts a prepared throw keeps (more than a throw's fits take)
START_SIGMAS = 3.0  # fault modes start the nominal fit's nuisances within this many prior std of their means
# The label of the hypothesis that is the switch as it now is without one of its present faults (a repair): WITHOUT
# + mode.
WITHOUT = "without:"
# A bolt drives the blades in one direction only (the left bolt from left to right).
DRIVING_BOLT = {"left_to_right": "left_bolt", "right_to_left": "right_bolt"}
_MEASURED_ROWS = [OUTPUTS.index(name) for name in MEASURED]


@dataclass(frozen=True)
class Measurement:
    """One throw's samples after its start (times from the start event), its direction and reference,
    and the state it starts from."""

    direction: str
    reference: Reference
    t_s: np.ndarray
    signals: MotorSignals
    start_angle_rad: float
    start_rail_m: float

    def scales(self) -> np.ndarray:
        """Range of each measured signal over the throw (the residual's scale)."""
        return np.maximum(np.ptp(self.signals.matrix(), axis=0), 1e-6)


@dataclass(frozen=True)
class HypothesisSpec:
    """What one hypothesis frees (with bounds) and holds; parameters neither freed nor held are nominal.

    A free parameter with a prior (mean, standard deviation) pays for straying from it: the fit is the
    maximum a posteriori one, MSE + w * sum(((value - mean) / std)^2), w the variance of the throw's
    measurement noise over its number of residuals (a parameter k standard deviations off costs what
    k^2 independent residuals' worth of misfit would, which is also the scale of the F test)."""

    mode: str  # nominal, a fault mode, or joint
    free: dict[str, tuple[float, float]]
    fixed: dict[str, float] = field(default_factory=dict)
    grid: tuple[dict[str, float], ...] = ()  # starting points to pick the best of (free parameters only)
    prior: dict[str, tuple[float, float]] = field(default_factory=dict)
    log_prior: tuple[str, ...] = ()  # parameters whose prior is on log(value) (a positive, skewed spread)
    # the grid a settled throw ranks beside the warm start (ThrowEstimator.fit_all; SETTLED); None: `grid`
    settled_grid: tuple[dict[str, float], ...] | None = None
    scanned: tuple[str, ...] = ()  # free parameters whose fit is checked by a scan around it (SCAN_STEP)
    initial: dict[str, float] = field(default_factory=dict)  # where free parameters start when a start does not say

    def within_priors(self, values: dict[str, float], sigmas: float) -> dict[str, float]:
        """`values` with each parameter that has a prior brought to within `sigmas` standard deviations of its
        mean (on log(value) for log priors)."""
        out = dict(values)
        for name, (mean, std) in self.prior.items():
            if name in out:
                low, high = mean - sigmas * std, mean + sigmas * std
                if name in self.log_prior:
                    out[name] = float(np.exp(np.clip(np.log(max(out[name], 1e-300)), low, high)))
                else:
                    out[name] = float(np.clip(out[name], low, high))
        return out

    def grid_names(self) -> set[str]:
        """The parameters its grid sets."""
        return {name for point in self.grid for name in point}

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the free parameters, in `free` order."""
        return np.array([low for low, _ in self.free.values()]), np.array([high for _, high in self.free.values()])


@dataclass(frozen=True)
class Prior:
    """A hypothesis's priors as extra residuals sqrt(w) (value - mean) / std (on log(value) for log priors),
    over the vector of its free parameters (or a matrix of such vectors, one per column)."""

    picked: list[int]  # the free parameters (positions in spec.free) that have a prior
    size: int  # number of free parameters
    mean: np.ndarray
    root_weight: np.ndarray
    logs: np.ndarray

    @classmethod
    def of(cls, spec: HypothesisSpec, weight: float) -> Prior:
        free = list(spec.free)
        picked = [i for i, n in enumerate(free) if n in spec.prior]
        return cls(picked, len(free), np.array([spec.prior[free[i]][0] for i in picked]),
                   np.sqrt(weight) / np.array([spec.prior[free[i]][1] for i in picked]),
                   np.array([free[i] in spec.log_prior for i in picked], dtype=bool))

    @property
    def rows(self) -> int:
        return len(self.picked)

    def residuals(self, z: np.ndarray) -> np.ndarray:
        values = z[self.picked]
        logs = self.logs.reshape((-1,) + (1,) * (z.ndim - 1))
        transformed = np.where(logs, np.log(np.maximum(values, 1e-300)), values)
        return (self.root_weight * (transformed.T - self.mean)).T

    def charge(self, z: np.ndarray) -> np.ndarray:
        """What the priors add to r'r at z (a vector: a number; a matrix: one per column)."""
        return np.sum(self.residuals(z) ** 2, axis=0)

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        rows = np.zeros((self.rows, self.size))
        slope = np.where(self.logs, 1.0 / np.maximum(z[self.picked], 1e-300), 1.0)
        rows[range(self.rows), self.picked] = self.root_weight * slope
        return rows


@dataclass(frozen=True)
class Slopes:
    """A fit's Jacobian where it ended, as the model's own slopes: the derivative of each measured signal at each
    sample with respect to each free parameter, unscaled, each signal's over its largest in half precision (a step
    needs their direction, not their last digits: half the memory of single precision, and on healthy throws the
    fits ended a negligible part of their standard deviations from where single precision's did). The next throw's
    fit of the same hypothesis borrows them where it starts at `z`."""

    free: tuple[str, ...]
    z: np.ndarray  # the free parameters' values where the slopes hold
    rows: tuple[int, ...]  # the measured signals (PreparedThrow.rows)
    period_s: float  # the samples' period
    derivative: np.ndarray  # signals x samples x free parameters, each signal's and parameter's over its largest
    largest: np.ndarray  # signals x 1 x free parameters: the largest magnitude of each signal's slope
    age: int  # throws since they were last computed exactly (0: in this one)

    @classmethod
    def of(cls, jacobian: np.ndarray, throw: PreparedThrow, free: list[str], z: np.ndarray, age: int) -> Slopes:
        """From the data rows of a fit's Jacobian (scaled as ThrowEstimator._scaled scales the residual)."""
        signals, samples = throw.measured.shape[1], throw.measured.shape[0]
        derivative = jacobian.reshape(signals, samples, len(free)) * (np.sqrt(throw.measured.size) /
                                                                      throw.inverse_scale[:, None, None])
        # each signal's and parameter's largest over the samples, reduced along contiguous rows (several times faster
        # than a reduction over the middle axis of signals x samples x parameters: a settled throw makes four)
        largest = np.maximum(np.abs(derivative.transpose(0, 2, 1).copy()).max(axis=2)[:, None, :], 1e-300)
        return cls(tuple(free), z.copy(), tuple(throw.rows), throw.period_s, (derivative / largest).astype(np.float16),
                   largest, age)

    def scaled(self, throw: PreparedThrow, free: list[str], z: np.ndarray) -> np.ndarray | None:
        """The slopes as rows of `throw`'s Jacobian over `free` at `z`, or None where they are not the model's there:
        another start, other parameters or signals, another sample rate, too old (SLOPES_AGE). A throw with fewer
        samples takes the first ones; one with more extends the last (the blades locked, the motor stopped)."""
        if (self.age >= SLOPES_AGE or tuple(free) != self.free or tuple(throw.rows) != self.rows
                or not np.array_equal(z, self.z) or abs(throw.period_s - self.period_s) > 1e-3 * self.period_s):
            return None
        samples = throw.measured.shape[0]
        derivative = self.derivative[:, :samples]
        if samples > derivative.shape[1]:
            derivative = np.pad(derivative, ((0, 0), (0, samples - derivative.shape[1]), (0, 0)), mode="edge")
        rows = derivative * (self.largest * throw.inverse_scale[:, None, None] / np.sqrt(throw.measured.size))
        return rows.reshape(-1, len(free))  # float16 times float64: float64


@dataclass(frozen=True)
class Estimate:
    """One hypothesis fitted: the values of its free parameters, their standard deviations (the fit's own,
    widened for correlated residuals), every parameter's value, and the fit's MSE and residual."""

    mode: str
    params: dict[str, float]
    std: dict[str, float]
    values: dict[str, float]  # every parameter at the fit (held ones included)
    mse: float  # of the data alone
    objective: float  # MSE plus what the priors charge: what hypotheses are compared by
    iterations: int
    residual: np.ndarray  # scaled residuals of the signals measured (current, angle, velocity), one column each
    effective_samples: float
    prior_weight: float = 0.0  # w of HypothesisSpec: what one unit of (value - mean)^2 / std^2 adds to objective
    slopes: Slopes | None = None  # the fit's Jacobian where it ended, for the next throw's fit to borrow

    @property
    def prior_charge(self) -> float:
        """What the priors charge this fit, in units of (value - mean)^2 / std^2 summed (0 without priors)."""
        return (self.objective - self.mse) / self.prior_weight if self.prior_weight > 0 else 0.0

    def kept(self, slopes: bool) -> Estimate:
        """The estimate as a later throw reads it: without its residual (an empty one with a column per signal
        measured) and, unless `slopes`, without its slopes."""
        return replace(self, residual=np.empty((0, self.residual.shape[1])), slopes=self.slopes if slopes else None)


@dataclass(frozen=True)
class _Timeline:
    """Where a throw's samples fall among the model's samples at one rate, and the reference per chunk."""

    refs: list[np.ndarray]  # per chunk, 2 x samples per chunk flattened column by column (as the chunks take them)
    index: np.ndarray  # per sample: the model sample at or before it (0: the start)
    fraction: np.ndarray  # per sample: how far towards the next model sample
    on_grid: bool  # every sample at a model sample

    @classmethod
    def of(cls, reduced: ReducedSwitch, m: Measurement, chunk: int) -> _Timeline:
        position = np.asarray(m.t_s, dtype=float) * reduced.rate_hz
        index = np.floor(position + 1e-9).astype(int)
        fraction = np.clip(position - index, 0.0, 1.0)
        fraction[fraction < 1e-9] = 0.0
        # model samples after the start that the samples need: up to the last one's, and the next where it
        # falls between two (column 0 of the model's outputs is the start itself)
        needed = int(np.max(index + (fraction > 0)))
        chunks = max(1, int(np.ceil(needed / chunk)))
        columns = reduced.reference_columns(m.reference, chunks * chunk)  # every chunk's at once, then split
        refs = [columns[:, c * chunk:(c + 1) * chunk].ravel(order="F") for c in range(chunks)]
        return cls(refs, index, fraction, not fraction.any())

    def at_samples(self, y: np.ndarray) -> np.ndarray:
        """Model values (... x model samples, the start first) interpolated at the samples' times: ... x N."""
        if self.on_grid:  # samples at model samples (a rate that divides the model's): nothing to interpolate
            return y[..., self.index]
        nxt = np.minimum(self.index + 1, y.shape[-1] - 1)
        return y[..., self.index] * (1.0 - self.fraction) + y[..., nxt] * self.fraction


@dataclass(frozen=True)
class PreparedThrow:
    """A measurement prepared for the model: its start state and where its samples fall on the model's
    samples (and on the grid's)."""

    s0: np.ndarray
    model: _Timeline  # at MODEL_RATE_HZ
    grid: _Timeline  # at GRID_RATE_HZ
    measured: np.ndarray  # N x signals measured
    inverse_scale: np.ndarray  # per signal measured
    rows: list[int]  # the measured signals' rows among MEASURED (all three, or the current alone)
    start: np.ndarray  # every output (OUTPUTS) at the start: at rest, no drive force
    period_s: float  # the samples' period
    # the model's outputs (ThrowEstimator.all_outputs) at the parameter vectors evaluated so far, the latest
    # OUTPUTS_KEPT: a fit that starts where another candidate was judged, or the decided fit's outputs, are there
    outputs: dict[tuple[int, bytes], np.ndarray] = field(default_factory=dict, compare=False, repr=False)

    @property
    def samples(self) -> int:
        """Model samples of the rollout, the start first."""
        return 1 + CHUNK_SAMPLES * len(self.model.refs)


class ThrowEstimator:
    """Fits hypotheses to throws of any length and rate; build once (compiled once), call per throw."""

    CAPACITIES = (SETTLED_CAPACITY, GRID_CAPACITY)  # of the grid's mapped calls
    MODEL_CAPACITIES = (SCAN_CAPACITY, GRID_CAPACITY)  # of the mapped calls at the model's rate

    def __init__(self, reduced: ReducedSwitch, compiler: Compiler | None = None, directions: tuple[int, ...] = (4, 5, 7, 9)):
        """`reduced` must run at MODEL_RATE_HZ; `directions` are the numbers of free parameters the compiled
        Jacobians serve (a hypothesis uses the smallest that fits); `compiler` makes machine code."""
        if reduced.rate_hz != MODEL_RATE_HZ:
            raise ValueError(f"the estimator's model runs at {MODEL_RATE_HZ:g} samples/s, not {reduced.rate_hz:g}")
        self.reduced = reduced
        self.directions = tuple(sorted(directions))
        n, p, c = len(STATES), len(PARAMETERS), CHUNK_SAMPLES
        s0, refs, theta = ca.MX.sym("s0", n), ca.MX.sym("refs", 2, c), ca.MX.sym("theta", p)
        networks = kernels(reduced.representation, reduced.weights, compiler)  # the learned rail's, if any
        state, outputs = rolled(reduced.fixed_step(networks), s0, refs, theta)
        chunk = ca.Function("model_chunk", [s0, refs, theta], [state, outputs])
        measured = ca.Function("measured_chunk", [s0, refs, theta], [state, outputs[_MEASURED_ROWS, :]])
        self.coarse = ReducedSwitch(reduced.representation, reduced.weights, reduced.params, GRID_RATE_HZ)
        g = self.grid_chunk = round(CHUNK_SAMPLES * GRID_RATE_HZ / MODEL_RATE_HZ)
        grid_refs = ca.MX.sym("refs", 2, g)
        state, outputs = rolled(self.coarse.fixed_step(networks), s0, grid_refs, theta)
        coarse = ca.Function("grid_chunk", [s0, grid_refs, theta], [state, outputs[_MEASURED_ROWS, :]])
        functions = [chunk, *[measured.map(f"model_chunk_grid{c}", "serial", c, [1], []) for c in self.MODEL_CAPACITIES],
                     *[coarse.map(f"coarse_chunk_grid{c}", "serial", c, [1], []) for c in self.CAPACITIES]]
        for k in self.directions:
            aug, seeds = ca.MX.sym("s_dot", n * (1 + k)), ca.MX.sym("seeds", p * k)
            step = reduced.fixed_sensitivity_step(k, networks)
            state, outputs = rolled(step, aug, refs, theta, seeds)
            rows = [j * len(OUTPUTS) + i for j in range(1, k + 1) for i in _MEASURED_ROWS]  # derivative rows
            functions.append(ca.Function(f"sensitivity_chunk{k}", [aug, refs, theta, seeds],
                                         [state, outputs[_MEASURED_ROWS, :], outputs[rows, :]]))
        if compiler is not None:
            functions = compiler(functions)
        self._chunk, *rest = [InPlace(f) for f in functions]
        self._batches, rest = dict(zip(self.MODEL_CAPACITIES, rest)), rest[len(self.MODEL_CAPACITIES):]
        self._grids, sensitivities = dict(zip(self.CAPACITIES, rest)), rest[len(self.CAPACITIES):]
        self._sensitivity = dict(zip(self.directions, sensitivities))

    # -- the model over one throw -------------------------------------------------------------
    def prepare(self, m: Measurement | PreparedThrow) -> PreparedThrow:
        """The measurement prepared for the model (one already prepared as it is)."""
        if isinstance(m, PreparedThrow):
            return m
        s0 = self.reduced.initial_state(m.start_rail_m, m.start_angle_rad)
        rows = [MEASURED.index(name) for name in m.signals.names]
        start = np.array([s0[STATES.index(name)] if name in STATES else 0.0 for name in OUTPUTS])
        period = float(np.median(np.diff(m.t_s))) if len(m.t_s) > 1 else float(m.t_s[0])
        return PreparedThrow(s0, _Timeline.of(self.reduced, m, CHUNK_SAMPLES),
                             _Timeline.of(self.coarse, m, self.grid_chunk), m.signals.matrix(), 1.0 / m.scales(), rows,
                             start, period)

    @staticmethod
    def _at_samples(y: np.ndarray, throw: PreparedThrow) -> np.ndarray:
        """Model values (... x model samples, the start first) interpolated at the samples' times: ... x N."""
        return throw.model.at_samples(y)

    def all_outputs(self, theta: np.ndarray, throw: PreparedThrow) -> np.ndarray:
        """Every output of the model (OUTPUTS), 6 x (1 + model samples), the start first (read only: it is kept with
        the throw, PreparedThrow.outputs)."""
        key = (id(self), np.asarray(theta, dtype=float).tobytes())  # a throw another estimator prepared is its own
        if key in throw.outputs:
            return throw.outputs[key]
        y = np.empty((len(OUTPUTS), throw.samples))
        y[:, 0], state = throw.start, throw.s0
        for c, refs in enumerate(throw.model.refs):
            state, y[:, 1 + c * CHUNK_SAMPLES:1 + (c + 1) * CHUNK_SAMPLES] = self._chunk.views(state, refs, theta)
        y.flags.writeable = False
        if len(throw.outputs) >= OUTPUTS_KEPT:
            del throw.outputs[next(iter(throw.outputs))]
        throw.outputs[key] = y
        return y

    def _scaled(self, differences: np.ndarray, throw: PreparedThrow) -> np.ndarray:
        """Differences (signals measured x N) scaled, stacked signal by signal, over sqrt(their number): r'r is
        the MSE."""
        return (differences * throw.inverse_scale[:, None]).ravel() / np.sqrt(differences.size)

    def residuals(self, theta: np.ndarray, throw: PreparedThrow) -> np.ndarray:
        measured = [_MEASURED_ROWS[row] for row in throw.rows]  # the signals measured, among OUTPUTS
        return self._scaled(self._at_samples(self.all_outputs(theta, throw)[measured], throw) - throw.measured.T, throw)

    def cost(self, theta: np.ndarray, throw: PreparedThrow) -> float:
        return _squares(self.residuals(theta, throw))

    def costs(self, thetas: np.ndarray, throw: PreparedThrow, coarse: bool = False) -> np.ndarray:
        """r'r of many parameter vectors (columns), GRID_CAPACITY to a mapped call, the smallest that takes them;
        `coarse`: with the model at GRID_RATE_HZ (what the grid ranks its points by)."""
        timeline, chunk, capacities = ((throw.grid, self.grid_chunk, self._grids) if coarse
                                       else (throw.model, CHUNK_SAMPLES, self._batches))
        out = []
        for first in range(0, thetas.shape[1], GRID_CAPACITY):
            batch = thetas[:, first:first + GRID_CAPACITY]
            count = batch.shape[1]
            capacity = min(c for c in capacities if c >= count)
            evaluate = capacities[capacity]
            batch = np.hstack([batch, np.repeat(batch[:, :1], capacity - count, axis=1)])
            states = np.repeat(throw.s0[:, None], capacity, axis=1)
            start = np.repeat(throw.start[_MEASURED_ROWS, None, None], capacity, axis=2)
            blocks = [start]
            for refs in timeline.refs:
                states, y = evaluate(states, refs, batch)
                blocks.append(y.reshape(len(MEASURED), chunk, capacity, order="F"))
            y = np.moveaxis(np.concatenate(blocks, axis=1)[throw.rows, :, :count], 2, 0)  # G x signals x samples
            differences = (timeline.at_samples(y) - throw.measured.T) * throw.inverse_scale[:, None]  # as _scaled
            with np.errstate(over="ignore", invalid="ignore"):
                out.append(np.mean(differences**2, axis=(1, 2)))
        values = np.concatenate(out)
        return np.where(np.isfinite(values), values, np.inf)

    def objectives(self, thetas: np.ndarray, throw: PreparedThrow, prior: Prior, index: list[int]) -> np.ndarray:
        """What a fit minimises (MSE plus the priors' charge) at many parameter vectors (columns); `index`: where
        the free parameters `prior` charges sit among PARAMETERS."""
        return self.costs(thetas, throw) + prior.charge(thetas[index])

    def linearise(self, theta: np.ndarray, throw: PreparedThrow, index: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Residual and its Jacobian columns for the parameters at `index`."""
        k = min((d for d in self.directions if d >= len(index)), default=None)
        if k is None:
            raise ValueError(f"{len(index)} free parameters; the estimator serves at most {self.directions[-1]}")
        seeds = np.zeros((len(PARAMETERS), k))
        seeds[index, range(len(index))] = 1.0
        seeds = seeds.ravel(order="F")
        aug = np.concatenate([throw.s0, np.zeros(len(STATES) * k)])
        y, dy = np.empty((len(MEASURED), throw.samples)), np.empty((len(MEASURED) * k, throw.samples))
        y[:, 0], dy[:, 0] = throw.start[_MEASURED_ROWS], 0.0
        for c, refs in enumerate(throw.model.refs):
            columns = slice(1 + c * CHUNK_SAMPLES, 1 + (c + 1) * CHUNK_SAMPLES)
            aug, y[:, columns], dy[:, columns] = self._sensitivity[k].views(aug, refs, theta, seeds)
        r = self._scaled(self._at_samples(y[throw.rows], throw) - throw.measured.T, throw)
        # every free parameter's derivative rows at once, (parameter, signal measured) x N, scaled as _scaled does
        rows = [j * len(MEASURED) + i for j in range(len(index)) for i in throw.rows]
        scale = np.tile(throw.inverse_scale, len(index))[:, None]
        if throw.model.on_grid:  # one gather, then the scaling in place
            scaled = dy[np.ix_(rows, throw.model.index)]
            scaled *= scale
        else:
            scaled = self._at_samples(dy[rows], throw) * scale
        scaled /= np.sqrt(r.size)
        return r, scaled.reshape(len(index), -1).T

    # -- hypotheses ------------------------------------------------------------------------
    def fit(self, spec: HypothesisSpec, throw: PreparedThrow, start: dict[str, float] | None = None,
            iterations: int = 20, rival: float = np.inf, prior_weight: float = 0.0, beaten: float = np.inf,
            slopes: Slopes | None = None, keep_slopes: bool = False,
            linearised: tuple[np.ndarray, np.ndarray] | None = None) -> Estimate:
        """Fit one hypothesis from `start` (a warm start or its grid's best point; elsewhere held or nominal).

        With `rival` (the lowest objective another hypothesis reached), the fit stops early once it is
        above the rival and, at its latest rate of decrease, would still be above it after its remaining
        iterations: a hypothesis that cannot fit best is not refined further. With `beaten` (the objective of a
        fault already found in the throw), it stops where not even HOPELESS_MARGIN times all that its
        linearisation promises would bring it below `beaten`. `prior_weight` is w of HypothesisSpec. `slopes` (the
        hypothesis's Jacobian where its fit of the switch's previous throw ended) are borrowed for the first step
        where the fit starts there (SLOPES_AGE) and no fault has been found in the throw (the test of `beaten` is
        asked of exact Jacobians); `keep_slopes`: the estimate keeps its own for the next throw. `linearised`: the
        data's residual and Jacobian at the start (linearise's, computed to choose it), not computed again.
        """
        free = list(spec.free)
        low, high = spec.bounds()
        theta, index = self._start(spec, start)
        prior = Prior.of(spec, prior_weight)

        def at(values: np.ndarray) -> np.ndarray:
            full = theta.copy()
            full[index] = values
            return full

        if not free:
            r = self.residuals(theta, throw)
            return self._estimate(spec.mode, theta, [], {}, r, float(r @ r), 0, len(throw.rows))

        def with_priors(r: np.ndarray, jacobian: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return np.concatenate([r, prior.residuals(z)]), np.vstack([jacobian, prior.jacobian(z)])

        def linearise(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return with_priors(*self.linearise(at(z), throw, index), z)

        def residual(z: np.ndarray) -> np.ndarray:
            return np.concatenate([self.residuals(at(z), throw), prior.residuals(z)])

        def keep_going(cost: float, decrease: float, k: int) -> bool:  # can it still beat the rival?
            return cost * (1.0 - decrease) ** (iterations - k) <= rival

        def hopeless(cost: float, promised: float) -> bool:  # could it still beat the fault found?
            return cost - HOPELESS_MARGIN * promised > beaten

        z0 = theta[index]  # within the bounds (_start)
        borrowed = None if slopes is None or np.isfinite(beaten) else slopes.scaled(throw, free, z0)
        first = None if linearised is None else with_priors(*linearised, z0)
        solution = levenberg_marquardt(linearise, z0, residual=residual, lower=low, upper=high,
                                       scale=np.array([SCALES[n] for n in free]), iterations=iterations,
                                       tolerance=TOLERANCE, keep_going=keep_going,
                                       hopeless=hopeless if np.isfinite(beaten) else None,
                                       jacobian=None if borrowed is None else np.vstack([borrowed, prior.jacobian(z0)]),
                                       first=first)
        data_rows = solution.residual.size - prior.rows
        r = solution.residual[:data_rows]
        n_eff = effective_samples(r.reshape(len(throw.rows), -1).T)
        std = self._std(solution.jacobian, r, low, high, prior_weight, n_eff)
        age = 0 if solution.linearised else slopes.age + 1  # no exact Jacobian: the borrowed ones, updated
        return self._estimate(spec.mode, at(solution.z), free, dict(zip(free, std)), r, solution.cost,
                              solution.iterations, len(throw.rows), n_eff, prior_weight if prior.rows else 0.0,
                              Slopes.of(solution.jacobian[:data_rows], throw, free, solution.z, age) if keep_slopes
                              else None)

    def _estimate(self, mode: str, theta: np.ndarray, free: list[str], std: dict[str, float], r: np.ndarray,
                  objective: float, iterations: int, signals: int, n_eff: float | None = None,
                  prior_weight: float = 0.0, slopes: Slopes | None = None) -> Estimate:
        values = dict(zip(PARAMETERS, (float(v) for v in theta)))
        residual = r.reshape(signals, -1).T * np.sqrt(r.size)
        return Estimate(mode, {n: values[n] for n in free}, std, values, float(r @ r), objective, iterations, residual,
                        effective_samples(residual) if n_eff is None else n_eff, prior_weight, slopes)

    @staticmethod
    def _std(jacobian: np.ndarray, r: np.ndarray, low: np.ndarray, high: np.ndarray, prior_weight: float,
             n_eff: float) -> np.ndarray:
        """Laplace covariance of the data and the priors (the priors' rows follow the data's in `jacobian`).

        The data's information is J'J over the residual variance, counted on N_eff effective samples
        rather than N (a residual that is smooth model error rather than white noise carries less); a
        prior's is 1 / std^2. No information means the range."""
        n = r.size
        data, prior = jacobian[:n], jacobian[n:]
        variance = float(r @ r) * n / max(n - jacobian.shape[1], 1)  # per scaled sample (r is divided by sqrt(n))
        n_eff = max(n_eff, jacobian.shape[1] + 1.0)
        information = (n_eff / max(variance, 1e-300)) * (data.T @ data)
        if len(prior) and prior_weight > 0:
            information = information + (prior.T @ prior) / prior_weight
        std = np.sqrt(np.clip(np.diag(np.linalg.pinv(information)), 0.0, None))
        return np.where(np.isfinite(std) & (std > 0), np.minimum(std, high - low), high - low)

    @staticmethod
    def noise_weight(throw: PreparedThrow) -> float:
        """The white measurement noise's variance (scaled, per residual, from the median second difference
        of each signal) over the number of residuals: the least w of HypothesisSpec."""
        second = np.diff(throw.measured * throw.inverse_scale[None, :], n=2, axis=0)
        noise = np.median(np.abs(second), axis=0) / (0.6745 * np.sqrt(6.0))  # a white sequence's MAD, per signal
        return float(np.mean(noise**2)) / throw.measured.size

    def grid_starts(self, specs: list[HypothesisSpec], base: dict[str, float], throw: PreparedThrow,
                    warm: dict[str, dict[str, float]] | None = None, settled: bool = False
                    ) -> tuple[dict[str, dict], dict[str, float]]:
        """Each hypothesis's best grid point by residual alone (every grid point of the throw in one batch, the
        model at GRID_RATE_HZ), with `base` (the nominal fit) everywhere else; a hypothesis's `warm` values
        (its fit to the switch's previous throw) compete as one more point. On a `settled` throw a hypothesis
        with warm values ranks its settled_grid instead of its grid. Also each ranked hypothesis's MSE at its best
        point (a lone candidate is not evaluated)."""
        warm = warm or {}

        def grid(spec: HypothesisSpec) -> tuple[dict[str, float], ...]:
            use_settled = settled and spec.settled_grid is not None and spec.mode in warm
            return spec.settled_grid if use_settled else spec.grid

        points = [(spec.mode, {**base, **spec.fixed, **point}) for spec in specs for point in grid(spec)]
        points += [(spec.mode, {**base, **spec.fixed, **_free(spec, warm[spec.mode])})
                   for spec in specs if spec.mode in warm]
        count = Counter(mode for mode, _ in points)
        best = {mode: point for mode, point in points if count[mode] == 1}  # a lone candidate needs no ranking
        ranked = [(mode, point) for mode, point in points if count[mode] > 1]
        lowest: dict[str, float] = {}
        if ranked:
            costs = self.costs(np.column_stack([self.reduced.vector(p) for _, p in ranked]), throw, coarse=True)
            for (mode, point), cost in zip(ranked, costs):
                if mode not in lowest or cost < lowest[mode]:
                    lowest[mode], best[mode] = float(cost), point
        return best, lowest

    def fit_all(self, m: Measurement | PreparedThrow, specs: dict[str, HypothesisSpec], model_weight: float = 0.0,
                decide: Callable[[dict[str, Estimate]], str] | None = None,
                warm: dict[str, dict[str, float]] | None = None, settled_mse: float | None = None,
                slopes: dict[str, Slopes] | None = None) -> dict[str, Estimate]:
        """The nominal hypothesis first; each fault mode started from the nominal fit (its own parameters from
        their grid), the most promising first (the lowest MSE at its start, where its start was ranked), and
        stopped once it cannot beat the best so far; joint last, from the best mode.

        `decide(the estimates so far)` names the fault they show ("nominal": none). Once one is shown, a fault mode
        fitted after it stops where it cannot beat that fault's objective (`beaten` of fit): the throw's decision is
        the shown fault with the lowest objective, so what the fit would refine changes no decision. The joint
        fit runs only when a fault is shown (a throw that shows none needs no joint fit); without `decide`, every
        fit runs to its end and the joint one always. On poly's faulty throws of benchmarks.diagnosis's cases (seed
        7), the modes that did not end best took markedly less time a throw than run to their ends; those ending
        three times the best's objective or more, fewer Jacobians each. A shown fault's evidence is what the decision
        reads; that of a mode stopped short of its minimum is understated (its estimates are where it stopped).

        `warm` holds each hypothesis's values fitted to the switch's previous throw in the same direction. A
        switch changes little from one throw to the next, so a fit started there converges in fewer
        iterations; it is only a candidate: the nominal fit starts from it where its objective is lower than
        the nominal values', a fault mode where it beats the mode's grid points, and the joint fit where it
        beats the best mode's fit and that fit joined with each other mode's own parameters as that mode fitted
        them (a small obstacle's position, say, which the joint fit cannot find from no obstacle: started at the
        best mode alone, on population switches with a missing bearing, it crept for several times as many
        iterations to a worse end than it reached from the joined start). `settled_mse` is the nominal fit's MSE on that
        throw when it was healthy: a throw whose nominal fit is within SETTLED of it is settled (grid_starts).
        `slopes` are those fits' Jacobians where they ended: on a settled throw, a fault mode's fit that starts there
        borrows them (fit). Not on a throw that is not settled: there the fault modes' fits to a switch whose fault
        persisted, borrowing, ended where the fault's size combined over its throws was further from the truth
        (benchmarks.fleet, poly, seed 1: a larger median relative error, and the truth not always within two standard
        deviations). Nor the nominal fit, which every test of a fault and the
        switch's commissioned levels read: borrowed in commissioning, its fits moved within the solver's tolerance,
        and with them the bolts' estimates of later faulty throws (benchmarks.diagnosis, seed 7: more left bolts
        further from the truth than closer).

        Every hypothesis of the throw shares one prior weight, so their objectives compare: the larger of
        the throw's noise (noise_weight) and `model_weight`, the residual variance over the effective number
        of samples that the model's own error leaves on a healthy throw."""
        throw = self.prepare(m)
        weight = max(self.noise_weight(throw), model_weight)
        warm = warm or {}
        start, linearised = (self._nominal_start(specs["nominal"], throw, weight, warm["nominal"]) if "nominal" in warm
                             else (None, None))
        if specs["nominal"].grid:  # the switch's present faults each back at its reference compete as starts too
            base = warm.get("nominal", {})
            start = self._lowest_start(specs["nominal"], throw, weight,
                                       [start or {}, *({**base, **point} for point in specs["nominal"].grid)])
            linearised = None if start is not warm.get("nominal") else linearised
        out = {"nominal": self.fit(specs["nominal"], throw, start, prior_weight=weight, linearised=linearised)}
        # The switch without each of its present faults (a repair): from the present fit, the fault's own parameters
        # at their reference (the spec holds them there).
        removals = {label: self.fit(specs[label], throw, out["nominal"].values, prior_weight=weight)
                    for label in specs if label.startswith(WITHOUT)}
        # A nuisance the nominal fit had to push far from its prior is the fault's effect absorbed (chairs five
        # times as dry for a missing bearing): the fault modes start it at its prior's edge, since from the
        # nominal's place the fault's parameter and the nuisance trade along a valley too flat to leave.
        # The present faults (the nominal spec's `initial`: their latest estimates) start the fault modes where they
        # were, not where the nominal fit took them: a throw that shows a new fault bends them in the fit without it
        # (drive friction appearing took a long bolt to a negative offset, and the drive-friction fit started there
        # stayed).
        nominal = specs["nominal"].within_priors({**out["nominal"].values, **specs["nominal"].initial}, START_SIGMAS)
        modes = [mode for mode in specs if mode not in ("nominal", "joint") and not mode.startswith(WITHOUT)]
        settled = settled_mse is not None and out["nominal"].mse <= (1.0 + SETTLED) * settled_mse
        starts, lowest = self.grid_starts([specs[mode] for mode in modes], nominal, throw, warm, settled)
        for mode in sorted(modes, key=lambda mode: lowest.get(mode, -np.inf)):  # unranked ones first, in order
            rival = min(estimate.objective for estimate in out.values())
            shown = "nominal" if decide is None else decide(out)
            out[mode] = self.fit(specs[mode], throw, starts.get(mode, nominal), rival=rival, prior_weight=weight,
                                 beaten=np.inf if shown == "nominal" else out[shown].objective,
                                 slopes=(slopes or {}).get(mode) if settled else None, keep_slopes=True)
        out = {"nominal": out["nominal"], **{mode: out[mode] for mode in modes}, **removals}  # in the specs' order
        best = min(modes, key=lambda mode: out[mode].objective) if modes else "nominal"  # a scan keeps it best
        if specs[best].scanned and out[best].objective < SCAN_WHEN * out["nominal"].objective:
            out[best] = self.scanned(specs[best], throw, out[best], weight)
        if "joint" in specs and (decide is None or decide(out) != "nominal"):
            own = {mode: set(specs[mode].free) - set(specs["nominal"].free) for mode in modes}
            joined = [{**out[best].values, **{name: out[mode].values[name] for name in own[mode]}}
                      for mode in modes if mode != best and own[mode]]
            start = self._lowest_start(specs["joint"], throw, weight,
                                       [out[best].values, *joined, *([warm["joint"]] if "joint" in warm else [])])
            out["joint"] = self.fit(specs["joint"], throw, start, prior_weight=weight)
        return out

    def scanned(self, spec: HypothesisSpec, throw: PreparedThrow, estimate: Estimate, weight: float) -> Estimate:
        """`estimate` of `spec`, or its refit from the lowest point of a scan of each scanned parameter around
        it (SCAN_OFFSETS, the other parameters held) where that point's objective is lower; again around the
        refit, up to SCAN_ROUNDS scans, while they find lower ground."""
        prior = Prior.of(spec, weight)
        index = [PARAMETERS.index(n) for n in spec.free]
        for name in spec.scanned:
            low, high = spec.free[name]
            for _ in range(SCAN_ROUNDS):
                points = np.clip(estimate.values[name] + SCAN_OFFSETS, low, high)
                thetas = np.column_stack([self.reduced.vector({**estimate.values, name: p}) for p in points])
                objectives = self.objectives(thetas, throw, prior, index)
                k = int(np.argmin(objectives))
                if objectives[k] >= estimate.objective * (1.0 - TOLERANCE):
                    break
                refit = self.fit(spec, throw, {**estimate.values, name: float(points[k])}, prior_weight=weight)
                if refit.objective >= estimate.objective:
                    break
                estimate = refit
        return estimate

    def _nominal_start(self, spec: HypothesisSpec, throw: PreparedThrow, weight: float, warm: dict[str, float]
                       ) -> tuple[dict[str, float], tuple[np.ndarray, np.ndarray] | None]:
        """The nominal fit's start, as _lowest_start chooses between the nominal values ({}) and `warm` (the switch's
        previous nominal fit), with the data's residual and Jacobian there where it is `warm`: `warm`, which starts
        nearly every throw's nominal fit (a switch changes little between throws), is judged by its linearisation,
        which the fit then starts from instead of computing it again (one rollout fewer a throw)."""
        prior = Prior.of(spec, weight)
        theta, index = self._start(spec, warm)
        r, jacobian = self.linearise(theta, throw, index)
        warm_objective = _squares(r) + float(prior.charge(theta[index]))
        if self._start_objective(spec, prior, throw, {}) <= warm_objective:  # the first of equals, as _lowest_start
            return {}, None
        return warm, (r, jacobian)

    def _lowest_start(self, spec: HypothesisSpec, throw: PreparedThrow, weight: float,
                      candidates: list[dict[str, float]]) -> dict[str, float]:
        """The candidate start of `spec` whose objective (MSE and priors' charge) is lowest, the first of equals
        ({}: the nominal values): one rollout each (a mapped call costs its capacity's rollouts, SCAN_CAPACITY at
        least)."""
        if len(candidates) == 1:
            return candidates[0]
        prior = Prior.of(spec, weight)
        return min(candidates, key=lambda candidate: self._start_objective(spec, prior, throw, candidate))

    def _start_objective(self, spec: HypothesisSpec, prior: Prior, throw: PreparedThrow,
                         candidate: dict[str, float]) -> float:
        """What a fit of `spec` minimises (MSE and the priors' charge) where it would start from `candidate`."""
        theta, index = self._start(spec, candidate)
        return self.cost(theta, throw) + float(prior.charge(theta[index]))

    def _start(self, spec: HypothesisSpec, start: dict[str, float] | None) -> tuple[np.ndarray, list[int]]:
        """The parameter vector a fit of `spec` starts from (`start`'s values of its free parameters, within their
        bounds; its held ones; nominal elsewhere) and where its free parameters sit in it."""
        low, high = spec.bounds()
        theta = self.reduced.vector({**spec.fixed, **_free(spec, {**spec.initial, **(start or {})})})
        index = [PARAMETERS.index(n) for n in spec.free]
        theta[index] = np.clip(theta[index], low, high)
        return theta, index

    def simulate(self, m: Measurement | PreparedThrow, values: dict[str, float]) -> dict[str, np.ndarray]:
        """The model's outputs at the samples' times under `values` (nominal elsewhere)."""
        throw = self.prepare(m)
        return dict(zip(OUTPUTS, self._at_samples(self.all_outputs(self.reduced.vector(values), throw), throw)))


def _squares(r: np.ndarray) -> float:
    """r'r, infinite where it is not finite."""
    value = float(r @ r)
    return value if np.isfinite(value) else np.inf


def _free(spec: HypothesisSpec, values: dict[str, float]) -> dict[str, float]:
    """The values of `spec`'s free parameters among `values`."""
    return {name: value for name, value in values.items() if name in spec.free}
