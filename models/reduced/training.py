"""Training data from the plant and the fits of the reduced rail representations.

Data (paper, section "Hybrid rail switch model"): the plant's motor follows random
references that push the blades back and forth; we record force, position,
velocity and acceleration at the adjuster-rail connection every 0.02 s.

Fits use CasADi's automatic differentiation and Levenberg-Marquardt (models/numerics/least_squares.py), with bounds
(non-negative coefficients, a floor on the mass) built into the parametrisation:
- acausal forms: multiple shooting, each 1 s segment simulated (ROS2) from its
  measured start under the measured force, positions and velocities compared;
- causal map: regression of F on (x, v, a), then fine-tuned inside the full
  reduced switch model against the plant's nominal throws and a stretch of pushes,
  with how F depends on a held at the regression's.
"""
from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import casadi as ca
import numpy as np

from railswitch.models.numerics.buffers import InPlace
from railswitch.models.numerics.integrators import ros2
from railswitch.models.numerics.least_squares import SAME_ON_EVERY_PROCESSOR, levenberg_marquardt
from railswitch.models.plant.high_fidelity import Plant
from railswitch.models.reduced.rail_models import FORCE_SCALE_N, CausalRail, NNRail, Representation
from railswitch.models.reduced.hybrid import OUTPUTS, PARAMETERS, STATES, Compiler, ReducedParams, rolled, stock_rail_force
from railswitch.models.plant.reference import Reference

RATE_HZ = 50.0
SEGMENT_SAMPLES = 50
POSITION_RESIDUAL_M = 0.002
VELOCITY_RESIDUAL_M_S = 0.01
CURRENT_RESIDUAL_A = 0.1
TRAIN_SEEDS = (1, 2, 3)  # 100 s random-push series used for training
VALIDATION_SEEDS = tuple(range(1001, 1026))  # 25 series never used for training


@dataclass(frozen=True)
class RailData:
    """Signals at the adjuster-rail connection, one row per sample."""

    force_n: np.ndarray
    position_m: np.ndarray
    velocity_m_s: np.ndarray
    acceleration_m_s2: np.ndarray


def random_reference(rng: np.random.Generator, duration_s: float, gear_ratio: float = 250.0, *,
                     crank_rad: tuple[float, float] = (0.0, np.pi), speed_rad_s: tuple[float, float] = (40.0, 140.0),
                     ramp_s: tuple[float, float] = (0.3, 0.3), pause_s: tuple[float, float] = (0.2, 1.5)) -> Reference:
    """Random back-and-forth pushes: moves to random crank angles at random motor speeds, with pauses.

    The defaults are the training and validation pushes; `stress_reference` widens every range.
    """
    t, v = [0.0], [0.0]
    crank = 0.0
    while t[-1] < duration_s:
        target = rng.uniform(*crank_rad)
        speed = rng.uniform(*speed_rad_s) * np.sign(target - crank)
        ramp = ramp_s[0] if ramp_s[0] == ramp_s[1] else rng.uniform(*ramp_s)  # a fixed ramp draws nothing
        run = max(abs(target - crank) * gear_ratio / abs(speed) - ramp, 0.05)
        t += [t[-1] + ramp, t[-1] + ramp + run, t[-1] + 2 * ramp + run, t[-1] + 2 * ramp + run + rng.uniform(*pause_s)]
        v += [speed, speed, 0.0, 0.0]
        crank += speed * (run + ramp) / gear_ratio
    return Reference(np.array(t), np.array(v))


def stress_reference(rng: np.random.Generator, duration_s: float, gear_ratio: float = 250.0) -> Reference:
    """Pushes beyond the training ones: past both dead centres, from crawling to nearly twice a
    throw's motor speed, with ramps from 50 to 500 ms and no pause at all to a second's."""
    return random_reference(rng, duration_s, gear_ratio, crank_rad=(-0.2, np.pi + 0.2), speed_rad_s=(10.0, 250.0),
                            ramp_s=(0.05, 0.5), pause_s=(0.0, 1.0))


def settled_state(plant: Plant) -> np.ndarray:
    """The nominal plant closed at the left after 1 s unpowered: where every experiment starts."""
    return plant.run(plant.rest_state(1.0), 1.0, RATE_HZ).states[:, -1]


def random_push_run(plant: Plant, seed: int, duration_s: float):
    """Random pushes through the nominal plant: (reference, signals at the start, trajectory), seeded."""
    reference = random_reference(np.random.default_rng(seed), duration_s, plant.params.drive.gear_ratio)
    state = settled_state(plant)
    trajectory = plant.run(plant.start_throw(state), duration_s, RATE_HZ, reference=reference)
    return reference, plant.signals_at(state), trajectory


def rail_experiment(plant: Plant, seed: int, duration_s: float = 100.0) -> RailData:
    """One series of random pushes through the nominal plant (deterministic for a seed)."""
    _, _, trajectory = random_push_run(plant, seed, duration_s)
    return RailData(trajectory["drive_force_n"], trajectory["rail_position_m"], trajectory["rail_velocity_m_s"],
                    trajectory["rail_acceleration_m_s2"])


def nominal_throw_data(plant: Plant, throws: int = 2) -> RailData:
    """The connection's signals over nominal throws (left to right first), as in normal service."""
    from railswitch.models.plant.reference import DIRECTIONS, throw_reference

    state = settled_state(plant)
    parts = []
    for k in range(throws):
        trajectory = plant.run(plant.start_throw(state), 7.0, RATE_HZ,
                               reference=throw_reference(DIRECTIONS[k % 2], plant.params.drive))
        state = trajectory.states[:, -1]
        parts.append(trajectory)
    return RailData(*(np.concatenate([t[name] for t in parts]) for name in
                      ("drive_force_n", "rail_position_m", "rail_velocity_m_s", "rail_acceleration_m_s2")))


def training_data(plant: Plant, series_seeds=None) -> list[RailData]:
    """Random-push series plus nominal throws."""
    seeds = TRAIN_SEEDS if series_seeds is None else series_seeds
    return [rail_experiment(plant, s) for s in seeds] + [nominal_throw_data(plant)]


@dataclass(frozen=True)
class Residuals:
    """A training stage's residual for the least-squares solver: with its Jacobian (at the points the solver
    accepts) and alone (at its trial points, so that a rejected step costs a residual, not a Jacobian)."""

    linearise: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    cost: Callable[[np.ndarray], float]


# -- acausal: multiple shooting on rail data --------------------------------------------------------
def rail_step_function(representation: Representation, reduced: ReducedParams) -> ca.Function:
    """(x, v, F at sample start, F at sample end, w) -> (x, v) one sample later, as in the reduced switch."""
    s = ca.SX.sym("s", 2)
    force = ca.SX.sym("F", 2)
    w = ca.SX.sym("w", representation.size)

    def port(state, fraction):
        return force[0] + (force[1] - force[0]) * fraction + stock_rail_force(reduced, state[0], state[1])

    def rhs(state, fraction):
        return ca.vertcat(state[1], representation.acceleration(state[0], state[1], port(state, fraction), w))

    def w_rhs(state, fraction, point):  # the same dissipative stand-in W as in the reduced switch
        mass, stiffness, damping = representation.linearisation(point[0], point[1], w)
        return ca.vertcat(state[1], (port(state, fraction) - stiffness * state[0] - damping * state[1]) / mass)

    state = ros2(rhs, s, 1.0 / (RATE_HZ * reduced.substeps), reduced.substeps, w_rhs)
    return ca.Function("rail_step", [s, force, w], [state])


def shooting_segments(data: list[RailData]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment starts (2 x S), forces (2 x N x S as 2N x S) and measured x, v (2N x S)."""
    starts, forces, measured = [], [], []
    for series in data:
        for start in range(0, len(series.force_n) - SEGMENT_SAMPLES - 1, SEGMENT_SAMPLES):
            idx = np.arange(start, start + SEGMENT_SAMPLES + 1)
            starts.append([series.position_m[start], series.velocity_m_s[start]])
            f = series.force_n[idx]
            forces.append(np.vstack([f[:-1], f[1:]]))
            measured.append(np.vstack([series.position_m[idx[1:]], series.velocity_m_s[idx[1:]]]))
    return np.array(starts).T, np.stack(forces, axis=-1), np.stack(measured, axis=-1)


NN_RIDGE = 1e-3  # weight decay of the NN spring and damper: keeps them smooth (no learned steps)


def _map(function: ca.Function, count: int, threads: int, held: tuple[int, ...] = ()) -> ca.Function:
    """`function` over `count` columns, on `threads` threads (each column alone: the same numbers on any number);
    the inputs at `held` are one for every column, not repeated."""
    parallel = {"max_num_threads": threads} if threads > 1 else {}
    return function.map(f"{function.name()}_{count}", "thread" if threads > 1 else "serial", count, list(held), [],
                        parallel)


def shooting_sensitivity_step(representation: Representation, reduced: ReducedParams) -> ca.Function:
    """One sample of a shooting segment carrying the state's derivatives in z: ([x, v, vec(dS/dz)], F at the sample's
    start and end, z) -> the same one sample later.

    The step's own Jacobian (2 x (2 + size)) is taken in reverse, two sweeps whatever the size, and the carried
    derivatives follow by the chain rule, S' = J_s S + J_z: nn's step with 109 weights is 5 500 operations where
    CasADi's forward AD of the rollout carries 109 directions through every operation (105 000)."""
    step = rail_step_function(representation, reduced)
    size = representation.size
    z, s, force = ca.SX.sym("z", size), ca.SX.sym("s", 2), ca.SX.sym("F", 2)
    carried = ca.SX.sym("S", 2, size)
    s_next = step(s, force, representation.weights_from_z(z))
    jacobian = ca.jacobian(s_next, ca.vertcat(s, z))
    s_dot_next = ca.mtimes(jacobian[:, :2], carried) + jacobian[:, 2:]
    return ca.Function("shooting_sensitivity_step", [ca.vertcat(s, ca.vec(carried)), force, z],
                       [ca.vertcat(s_next, ca.vec(s_dot_next))])


def acausal_residuals(representation: Representation, reduced: ReducedParams, data: list[RailData],
                      threads: int = 1) -> Residuals:
    """The scaled shooting errors over all segments (plus weight decay for nn) as functions of z, the segments
    shared among `threads` threads. Their Jacobian rides through each segment with its states
    (shooting_sensitivity_step): the numbers of CasADi's AD of the rollout, nn's linearisation many times faster
    (one series; read from numpy buffers, InPlace)."""
    starts, forces, measured = shooting_segments(data)
    segments, size = starts.shape[1], representation.size
    step = rail_step_function(representation, reduced)
    z = ca.MX.sym("z", size)
    s0 = ca.MX.sym("s0", 2)
    f = ca.MX.sym("f", 2, SEGMENT_SAMPLES)
    states = step.mapaccum("segment", SEGMENT_SAMPLES)(s0, f, ca.repmat(representation.weights_from_z(z), 1,
                                                                          SEGMENT_SAMPLES))
    one = ca.Function("one_segment", [s0, f, z], [states])
    aug0 = ca.MX.sym("aug0", 2 * (1 + size))
    carried = shooting_sensitivity_step(representation, reduced).mapaccum("segment", SEGMENT_SAMPLES)(
        aug0, f, ca.repmat(z, 1, SEGMENT_SAMPLES))
    one_carried = ca.Function("one_segment_sensitivities", [aug0, f, z], [carried])
    alone, with_derivatives = InPlace(_map(one, segments, threads)), InPlace(_map(one_carried, segments, threads))
    S0 = np.asarray(starts)
    A0 = np.vstack([S0, np.zeros((2 * size, segments))])
    F = np.asarray(forces.transpose(0, 2, 1).reshape(2, -1))  # 2 x (N * segments), segment-major
    target = measured.transpose(0, 2, 1).reshape(2, -1)
    scale = np.array([[1.0 / POSITION_RESIDUAL_M], [1.0 / VELOCITY_RESIDUAL_M_S]])
    ridge = np.zeros((0, size))  # weight decay's rows: nn's networks only, not its mass and xfix
    if isinstance(representation, NNRail):
        ridge = np.hstack([np.zeros((size - 2, 2)), np.sqrt(NN_RIDGE) * np.eye(size - 2)])

    def linearise(zv: np.ndarray):
        out = with_derivatives.views(A0, F, np.tile(zv[:, None], (1, segments)))[0]
        r = ((out[:2] - target) * scale).ravel(order="F")
        jacobian = np.empty((r.size, size))
        jacobian[0::2] = out[2::2].T * scale[0]  # vec(dS/dz): x then v for each weight
        jacobian[1::2] = out[3::2].T * scale[1]
        return np.concatenate([r, ridge @ zv]), np.vstack([jacobian, ridge])

    def cost(zv: np.ndarray) -> float:
        predicted = alone.views(S0, F, np.tile(zv[:, None], (1, segments)))[0]
        r = np.concatenate([((predicted - target) * scale).ravel(order="F"), ridge @ zv])
        return SAME_ON_EVERY_PROCESSOR.squares(r)
    return Residuals(linearise, cost)


# -- causal: regression, then fine-tuning inside the reduced switch model ---------------------------
END_MARGIN_M = 0.002
REGRESSION_CHUNK = 1024  # samples of the causal regression per call of its compiled rows
RIDGE = 1e-2  # weight decay of the causal regression
# How F depends on a is the regression's to learn, from the rail's own force and acceleration, under a prior of
# its own on the acceleration input's weights; the fine-tuning inside the switch model then holds them
# (`train`). Fine-tuned freely, they gave the causal rail an inertia far negative and far positive across its
# travel and speeds (floored at 75 kg): at the diagnosis's 10 ms step the current's peak as a bolt set the blades
# moving jumped from one quarter millimetre of the bolt to the next, and a bolt's MSE with it
# (models/reduced/validation.py contact_peaks). Of priors 0.01, 1, 10, 100 and 1000 (all held), 1 follows the 25
# validation series best, in mean and worst position RMSE (better than free, than 0.01 on the hardest three and
# than 1000, the old prior, there), its inertia positive and moderate throughout.
ACCELERATION_INPUT_RIDGE = 1.0


def causal_regression(representation: CausalRail, reduced: ReducedParams, data: list[RailData],
                      threads: int = 1, compiler: Compiler | None = None) -> Residuals:
    """g(x, v, a) minus the port force, in kN, plus a small ridge term, as functions of z.

    The port force is what the representation balances inside the reduced switch:
    the machine's force plus the reduced model's own end stops. One sample's
    residual and gradient are differentiated in SX, then mapped numerically.
    """
    columns = np.vstack([np.concatenate([getattr(d, k) for d in data])
                         for k in ("position_m", "velocity_m_s", "acceleration_m_s2", "force_n")])
    rail = reduced.plant.rail
    free = (columns[0] > rail.left_stock_m + END_MARGIN_M) & (columns[0] < rail.right_stock_m - END_MARGIN_M)
    columns = columns[:, free]  # closed against a stock rail, the force is the end stop's, not the rail's
    z = ca.SX.sym("z", representation.size)
    x, v, a, f = (ca.SX.sym(k) for k in "xvaf")
    r = (representation.force(x, v, a, z) - f - stock_rail_force(reduced, x, v)) / FORCE_SCALE_N
    row = [ca.Function("causal_row", [x, v, a, f, z], [r, ca.jacobian(r, z)]),
           ca.Function("causal_row_alone", [x, v, a, f, z], [r])]  # one sample: no data inside, so they compile
    # REGRESSION_CHUNK samples a call, the loop inside the machine code, the weights held (not copied to every
    # sample) and the numbers read from numpy buffers (InPlace), not converted from DMs: the rows, with their
    # gradients and alone, many times faster, the same numbers bit for bit. The last
    # chunk repeats the last sample, and what it adds is dropped.
    samples = columns.shape[1]
    chunks = -(-samples // REGRESSION_CHUNK)
    columns = np.hstack([columns, np.repeat(columns[:, -1:], chunks * REGRESSION_CHUNK - samples, axis=1)])
    held = (4,)  # the weights: one for every sample
    per_chunk = [_map(function, REGRESSION_CHUNK, 1, held) for function in row]
    rows, alone = (InPlace(_map(function, chunks, threads, held))
                   for function in (compiler(per_chunk) if compiler else per_chunk))
    decay = np.full(representation.size, RIDGE)
    decay[representation.acceleration_input_weights()] = ACCELERATION_INPUT_RIDGE
    ridge = np.diag(np.sqrt(decay))

    def linearise(zv: np.ndarray):
        r_all, j_all = rows.views(columns[0], columns[1], columns[2], columns[3], zv)
        r_all = np.concatenate([r_all.ravel()[:samples], ridge @ zv])
        return r_all, np.vstack([j_all.reshape(representation.size, -1, order="F").T[:samples], ridge])

    def cost(zv: np.ndarray) -> float:
        r_all = np.concatenate([alone.views(columns[0], columns[1], columns[2], columns[3], zv)[0].ravel()[:samples],
                                ridge @ zv])
        return SAME_ON_EVERY_PROCESSOR.squares(r_all)
    return Residuals(linearise, cost)


@dataclass(frozen=True)
class SwitchTarget:
    """A stretch of plant data the full reduced switch model is fitted to."""

    initial_state: np.ndarray  # reduced-model state at the start
    reference: Reference
    current_a: np.ndarray
    rail_position_m: np.ndarray
    rail_velocity_m_s: np.ndarray


SWITCH_DIRECTIONS = 16  # weight directions carried through one sensitivity rollout of the switch stage
SWITCH_CHUNK = 50  # samples per compiled call of the switch stage: one Function, whatever the targets' lengths
_SWITCH_ROWS = [0, 3, 4]  # current, rail position and rail velocity among the reduced model's OUTPUTS
_SWITCH_SCALES = np.array([CURRENT_RESIDUAL_A, POSITION_RESIDUAL_M, VELOCITY_RESIDUAL_M_S])


def switch_functions(reduced) -> list[ca.Function]:
    """The switch stage's two Functions: the model over SWITCH_CHUNK samples, and the same with the forward
    sensitivities of SWITCH_DIRECTIONS weight directions. The weights are an input, so they hold no data and
    depend on the representation alone: one compile per machine, whatever the weights or the targets."""
    size, n, k = reduced.representation.size, len(STATES), SWITCH_DIRECTIONS
    refs, theta, w = ca.MX.sym("refs", 2, SWITCH_CHUNK), ca.MX.sym("theta", len(PARAMETERS)), ca.MX.sym("w", size)
    s0, aug, seeds = ca.MX.sym("s0", n), ca.MX.sym("s_dot", n * (1 + k)), ca.MX.sym("seeds", size * k)
    return [ca.Function("switch_chunk", [s0, refs, theta, w], list(rolled(reduced.step, s0, refs, theta, w))),
            ca.Function("switch_sensitivity_chunk", [aug, refs, theta, seeds, w],
                        list(rolled(reduced.sensitivity_step(k, "w"), aug, refs, theta, seeds, w)))]


def switch_residuals(reduced, targets: list[SwitchTarget], functions: list[ca.Function] | None = None,
                     free: np.ndarray | None = None) -> Residuals:
    """Current, rail position and velocity inside the reduced switch model, as functions of the weights at `free`
    (flat indices; all by default), the others kept at their values in `reduced`.

    The Jacobian comes from forward sensitivities carried through each step (ReducedSwitch.sensitivity_step over
    the weights, SWITCH_DIRECTIONS at a time): the derivatives CasADi's AD of the rollout gives, at a fraction of
    its cost. The model runs in chunks of SWITCH_CHUNK samples through `functions` (switch_functions, compiled or
    not; built here when not given)."""
    size, n, k = reduced.representation.size, len(STATES), SWITCH_DIRECTIONS
    chunk, sensitivity_chunk = (InPlace(f) for f in (functions or switch_functions(reduced)))
    nominal = reduced.vector()
    runs = []
    for target in targets:
        chunks = -(-len(target.current_a) // SWITCH_CHUNK)
        columns = reduced.reference_columns(target.reference, chunks * SWITCH_CHUNK)
        runs.append((target, [columns[:, c * SWITCH_CHUNK:(c + 1) * SWITCH_CHUNK] for c in range(chunks)]))
    measured = [np.vstack([t.current_a, t.rail_position_m, t.rail_velocity_m_s]) for t in targets]
    free = np.arange(size) if free is None else np.asarray(free)
    blocks = [free[first:first + k] for first in range(0, len(free), k)]

    def weights(value: np.ndarray) -> np.ndarray:
        full = reduced.weights.copy()
        full[free] = value
        return full

    def residual(y: np.ndarray, index: int) -> np.ndarray:
        return ((y[_SWITCH_ROWS, :measured[index].shape[1]] - measured[index]) / _SWITCH_SCALES[:, None]).ravel()

    def rolled_out(function: InPlace, start: np.ndarray, chunks: list[np.ndarray], *held) -> np.ndarray:
        state, outputs = start, []
        for columns in chunks:
            state, y = function(state, columns, nominal, *held)
            outputs.append(y)
        return np.hstack(outputs)

    def linearise(value: np.ndarray):
        value = weights(value)
        rs, jacobians = [], []
        for index, (target, chunks) in enumerate(runs):
            columns = []
            for block in blocks:
                directions = np.zeros((size, k))
                directions[block, range(len(block))] = 1.0
                out = rolled_out(sensitivity_chunk, np.concatenate([target.initial_state, np.zeros(n * k)]), chunks,
                                 directions.ravel(order="F"), value)
                y_dot = out[len(OUTPUTS):].reshape(k, len(OUTPUTS), -1)[:len(block), :, :measured[index].shape[1]]
                scaled = y_dot[:, _SWITCH_ROWS] / _SWITCH_SCALES[None, :, None]  # block x signals x samples
                columns.append(scaled.reshape(len(block), -1).T)
            rs.append(residual(out[:len(OUTPUTS)], index))
            jacobians.append(np.hstack(columns))
        return np.concatenate(rs), np.vstack(jacobians)

    def cost(value: np.ndarray) -> float:
        value = weights(value)
        r = np.concatenate([residual(rolled_out(chunk, target.initial_state, chunks, value), index)
                            for index, (target, chunks) in enumerate(runs)])
        return SAME_ON_EVERY_PROCESSOR.squares(r)
    return Residuals(linearise, cost)


# -- the whole recipe per representation ----------------------------------------------------------
@dataclass
class Trained:
    """Weights of one representation and how they were obtained."""

    name: str
    weights: np.ndarray
    stages: dict[str, dict]  # stage -> {"iterations", "cost_start", "cost_end"}


Progress = Callable[[str, int, float], None]


def nominal_switch_targets(plant: Plant, reduced, throws: int = 2) -> list[SwitchTarget]:
    """The plant's nominal throws as targets for the full reduced switch model."""
    from railswitch.models.plant.simulation import SwitchSimulation

    sim = SwitchSimulation(plant, rate_hz=RATE_HZ)
    targets = []
    for _ in range(throws):
        start = plant.signals_at(sim.state)
        throw = sim.throw()
        s0 = reduced.initial_state(start["rail_position_m"], start["angle_rad"], start["velocity_rad_s"],
                                   start["current_a"])
        velocity = np.gradient(throw.samples.rail_position_m, 1.0 / RATE_HZ)
        targets.append(SwitchTarget(s0, throw.reference, throw.samples.signals.current_a, throw.samples.rail_position_m,
                                    velocity))
    return targets


def random_switch_target(plant: Plant, reduced, seed: int, duration_s: float = 30.0) -> SwitchTarget:
    """A stretch of a training random-push series as a target for the full reduced switch model."""
    reference, start, trajectory = random_push_run(plant, seed, duration_s)
    s0 = reduced.initial_state(start["rail_position_m"], start["angle_rad"], start["velocity_rad_s"], start["current_a"])
    return SwitchTarget(s0, reference, trajectory["current_a"], trajectory["rail_position_m"],
                        trajectory["rail_velocity_m_s"])


# A stage runs until a step lowers its cost by less than this fraction. At 1e-6 a stage stopped on plateaus that its
# later steps left (poly's decrease a step fell below it, then rose far above), where the arithmetic's last digits had
# led it (under other BLAS kernels, poly's weights wholly apart and nn's cost far higher); below 1e-9 poly only crawls
# along a direction its cost does not see (far smaller decreases a step, for many steps more).
FIT_TOLERANCE = 1e-9
# A stage's iterations at most (the causal fine-tuning's a quarter): nn's fit ends before. The causal regression
# does not (many more still lower its cost a little); run longer, 60 and 15, the fine-tuning fitted its targets
# closer and the 25 validation series of benchmarks.reduced markedly worse, in mean and worst position RMSE.
STAGE_ITERATIONS = 40


# What training promises across machines of one kind (x86-64 with AVX2 and FMA, this package's wheels) and numbers of
# threads: the weights' largest difference in the solver's order-one parameters z, relative to the parameter or 1
# where it is smaller (weights_difference). The data, training's functions and the solver's arithmetic are the same
# bit for bit there (EXACT machine code, the plant's beam solved in scalar recurrences, SAME_ON_EVERY_PROCESSOR), and
# so are the weights under every OpenBLAS kernel and thread count tried; the bound leaves room for a rounding
# elsewhere that a fit run to its end damps (with BLAS's reordered sums in its solver, poly's on one series moved
# within it). The causal rail's fine-tuning, which ends at its budget, would follow such a rounding further.
REPRODUCIBLE_WEIGHTS = 1e-9


def weights_difference(representation: Representation, weights: np.ndarray, reference: np.ndarray) -> float:
    """The largest difference of `weights` from `reference` in the solver's parameters z (order one), relative to
    the reference's or to 1 where that is smaller: what REPRODUCIBLE_WEIGHTS bounds."""
    z, z_reference = representation.z_from_weights(weights), representation.z_from_weights(reference)
    return float(np.max(np.abs(z - z_reference) / np.maximum(np.abs(z_reference), 1.0)))


def _fit(stage: str, fn: Residuals, z0: np.ndarray, iterations: int,
         progress: Progress | None) -> tuple[np.ndarray, dict]:
    """One training stage: Levenberg-Marquardt, unbounded (bounds live in the parametrisations)."""
    result = levenberg_marquardt(fn.linearise, z0, cost=fn.cost, iterations=iterations, tolerance=FIT_TOLERANCE,
                                 algebra=SAME_ON_EVERY_PROCESSOR,
                                 progress=None if progress is None else (lambda k, cost: progress(stage, k, cost)))
    return result.z, {"iterations": result.iterations, "cost_start": result.history[0], "cost_end": result.cost}


def train(representation: Representation, plant: Plant, *, seed: int = 0, series_seeds=TRAIN_SEEDS,
          iterations: int = STAGE_ITERATIONS, progress: Progress | None = None, threads: int = 1,
          compiler: Compiler | None = None) -> Trained:
    """Fit one representation to plant data, deterministically for a seed (and the same on any number of
    `threads`, which share the data's segments and samples); `compiler` makes the causal regression's
    per-sample functions and the fine-tuning's chunks machine code."""
    from railswitch.models.reduced.hybrid import ReducedSwitch

    data = training_data(plant, series_seeds)
    w0 = representation.initial_weights(seed)
    stages = {}
    if representation.acausal:
        z, stages["shooting"] = _fit("shooting", acausal_residuals(representation, ReducedParams(), data, threads),
                                     representation.z_from_weights(w0), iterations, progress)
        return Trained(representation.name, representation.weights_from_z(z), stages)
    functions = switch_functions(ReducedSwitch(representation, w0))
    with ThreadPoolExecutor(max_workers=1) as pool:
        # The fine-tuning's machine code needs the model's structure, not the regression's weights: it compiles
        # (a C compiler in its own process, the longest compile of training) while the regression runs.
        compiled = None if compiler is None else pool.submit(compiler, functions)
        w, stages["regression"] = _fit("regression", causal_regression(representation, ReducedParams(), data, threads,
                                                                       compiler), w0, iterations, progress)
        functions = functions if compiled is None else compiled.result()
    reduced = ReducedSwitch(representation, w)
    targets = nominal_switch_targets(plant, reduced) + [random_switch_target(plant, reduced, series_seeds[0])]
    # how F depends on a stays the regression's
    free = np.setdiff1d(np.arange(representation.size), representation.acceleration_input_weights())
    z, stages["switch"] = _fit("switch", switch_residuals(reduced, targets, functions, free), w[free],
                               max(iterations // 4, 1), progress)
    w = w.copy()
    w[free] = z
    return Trained(representation.name, w, stages)
