"""Reduced hybrid switch model: the plant's motor, controller, drive and adjuster, one learned rail.

Written as CasADi's system-identification example does it: the ODE once in
SX, a fixed-step integrator step per sample, rolled over a throw with `mapaccum`.
Every non-smooth law of the plant (free play, stock-rail contact, voltage limit)
is replaced by a smooth one, so outputs have exact derivatives with respect to
the fault parameters.

Each integration step splits the state in two (Strang splitting): the lock's hook
levels relax exactly over half a step (Rush-Larsen, models/numerics/integrators.py), the
six mechanical and electrical states take one ROS2 step (stiff-stable, so obstacle
friction and contacts of any size are safe) with the hooks held, and the hooks relax
over the other half. A hook lets go at up to 200/s, within one 20 ms sample, and the
rate switches on only once the driving bolt arrives: a Rosenbrock step whose W was
taken before that overshot the level below zero, and a negative hook turned the
lock's holding spring into one that pushes the blade away (energy from nowhere, and
the rollout diverged). The exact relaxation keeps every level in [0, 1].
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import lru_cache

import casadi as ca
import numpy as np

from railswitch.models.plant.adjuster import adjuster_force, smooth_contact
from railswitch.models.plant.drive import adjuster_on_rod, rod_kinematics
from railswitch.models.numerics.integrators import relax, ros2
from railswitch.models.plant.faults import FAULT_ORDER, obstacle_profile
from railswitch.models.plant.rail_beam import GRAVITY_M_S2, RailBeam
from railswitch.models.plant.lock import LockTerms, latched_hooks, lock_terms
from railswitch.models.plant.motor import controller, motor_derivatives
from railswitch.models.plant.high_fidelity import PlantParams
from railswitch.models.reduced.rail_models import Representation
from railswitch.models.plant.reference import DIRECTIONS, Reference
from railswitch.models.numerics.smooth import smooth_clip
from railswitch.schemas.faults import FAULT_PARAMETERS

STATES = ("angle_rad", "velocity_rad_s", "integral_v", "current_a", "rail_position_m", "rail_velocity_m_s",
          "hook_left", "hook_right")
# What a real switch's own build and weather change that the reduced model can show (plant variables,
# schemas/plant.py): estimated beside the faults. The motor's Coulomb friction here is the whole point
# machine's; the fault drive_friction_nm adds to it.
NUISANCES = ("motor.coulomb_friction_nm", "motor.torque_constant_nm_a", "motor.resistance_ohm", "motor.supply_v",
             "rail.chair_friction_coefficient")
PARAMETERS = FAULT_ORDER + NUISANCES  # the reduced model's parameter vector
_KNOWN = frozenset(PARAMETERS)
OUTPUTS = ("current_a", "angle_rad", "velocity_rad_s", "rail_position_m", "rail_velocity_m_s", "drive_force_n")


@dataclass(frozen=True)
class ReducedParams:
    """Integration and smoothing settings of the reduced model."""

    plant: PlantParams = field(default_factory=PlantParams)
    substeps: int = 1  # integration steps per sample, at least; more where a sample is longer than max_step_s
    # The longest integration step: the one the rail representations are trained at (models/reduced/training.py).
    # A learned causal map is not dissipative by construction, and past its training step its
    # explicitly treated part grows (the causal rail diverged at 10 Hz in one step per sample).
    max_step_s: float = 0.02
    # Contacts softer than the plant's: the reduced model needs their effect, not their stiffness.
    stock_stiffness_n_m: float = 1.0e6  # end stops at 1.00 m and 1.20 m, seen at the drive point
    contact_damping_s_m: float = 1.0  # Hunt-Crossley lambda of every reduced-model contact
    bolt_stiffness_n_m: float = 2.5e5  # along the rod (1e6 N/m at the blades through the lever)
    lock_stiffness_n_m: float = 1.0e6
    # The hook's release rate: None keeps the plant's. It sets how soon the blades follow the driving
    # bolt, so a slower one reads as a bolt offset (a bolt then fits longer than it is).
    latch_rate_1_s: float | None = None
    contact_width_m: float = 2e-4
    voltage_corner_v: float = 1.0
    # The bearing fault's port: drive-point damping = gain * bearing_friction + offset (N·s/m), one
    # (gain, offset) while the blades move left to right and one while they move right to left, blended
    # by the sign of their velocity over `port_velocity_m_s`. The plant spreads bearing friction along
    # flexible rails; calibrated per representation (`railswitch calibrate`, stored with the model's weights).
    bearing_port: tuple[tuple[float, float], tuple[float, float]] = ((1.0, 0.0), (1.0, 0.0))  # (gain, offset) in DIRECTIONS order
    port_velocity_m_s: float = 0.002
    # The chairs' Coulomb friction beyond the nominal one (which the learned rail holds), at the drive
    # point, smoothed over this speed: slow enough that a coefficient below nominal never makes the rail
    # accelerate itself near rest.
    chair_friction_speed_m_s: float = 0.01

    def steps_per_sample(self, rate_hz: float) -> int:
        """`substeps`, or more so that no step is longer than `max_step_s`."""
        return max(self.substeps, math.ceil(1.0 / (rate_hz * self.max_step_s) - 1e-9))


BearingPort = dict[str, dict[str, float]]  # per direction of motion: {"gain": ..., "offset_s_m": ...}
NEUTRAL_PORT: BearingPort = {direction: {"gain": 1.0, "offset_s_m": 0.0} for direction in DIRECTIONS}


def port_pairs(port: BearingPort) -> tuple[tuple[float, float], tuple[float, float]]:
    """A bearing port as ReducedParams holds it: (gain, offset) per direction, in DIRECTIONS order."""
    return tuple((port[d]["gain"], port[d]["offset_s_m"]) for d in DIRECTIONS)


def stock_rail_force(params: ReducedParams, x, v):
    """Smooth end stops where the blades meet the left and right stock rails."""
    rail = params.plant.rail
    left = smooth_contact(rail.left_stock_m - x, -v, params.stock_stiffness_n_m, params.contact_damping_s_m,
                          params.contact_width_m)
    right = smooth_contact(x - rail.right_stock_m, v, params.stock_stiffness_n_m, params.contact_damping_s_m,
                           params.contact_width_m)
    return left - right


UNROLLED = 50  # steps written out one after another in a rolled-out Function's inner loop


def rolled(step: ca.Function, s0, refs, *held):
    """`step` (state, ref, *held) -> (state, output) once per column of `refs`, every call on the same `held`
    arguments: (the last state, the outputs side by side).

    A mapaccum over the samples would take each held argument as one column per sample, and for a learned
    rail's weights that is a megabyte copied per throw (a fifth of the causal rail's rollout). So the steps run
    UNROLLED at a time with the held arguments passed once, and only those blocks go through a mapaccum."""
    blocks = refs.shape[1] // UNROLLED
    state, outputs = s0, []
    if blocks:
        s, r = ca.MX.sym("s", s0.shape[0]), ca.MX.sym("refs", 2, UNROLLED)
        symbols = [ca.MX.sym(f"held{i}", x.shape[0], x.shape[1]) for i, x in enumerate(held)]
        block = ca.Function(f"{step.name()}_block", [s, r, *symbols], list(_unrolled(step, s, r, *symbols)))
        states, out = block.mapaccum(f"{step.name()}_blocks", blocks)(s0, refs[:, :blocks * UNROLLED],
                                                                       *[ca.repmat(x, 1, blocks) for x in held])
        state, outputs = states[:, -1], [out]
    if refs.shape[1] > blocks * UNROLLED:
        state, tail = _unrolled(step, state, refs[:, blocks * UNROLLED:], *held)
        outputs.append(tail)
    return state, ca.horzcat(*outputs)


def _unrolled(step: ca.Function, s0, refs, *held):
    """`step` once per column of `refs`, written out: (the last state, the outputs side by side)."""
    state, columns = s0, []
    for k in range(refs.shape[1]):
        state, column = step(state, refs[:, k], *held)
        columns.append(column)
    return state, ca.horzcat(*columns)


class StandIns:
    """The rail's learned features (Representation.features) at each point a step asks for them, stood in by
    q + J (u - u0), where q, J and u0 are placeholder symbols that `resolved` replaces with the features at
    u = (x, v), their Jacobian there and u itself: the same values, and a forward derivative J du.

    Differentiated as written, a network carries every one of K directions through each of its hidden
    units; stood in, it carries two (its Jacobian with respect to x and v, made once per point) and each
    direction costs a product with that Jacobian. The derivatives are the same, to the rounding.

    With `kernels` (Functions of (x, v) at fixed weights: the features, and the features with their Jacobian;
    Representation.kernel_code), each point's stand-in is made by one call of a kernel and the step is valid at
    those weights only; with `slopes` False, q alone stands in (a step that is not differentiated). A point asked
    for again (a stage's and the integrator's W at the same state) gets the same stand-in, so one call serves both.
    """

    def __init__(self, representation: Representation, w, kernels: tuple[ca.Function, ca.Function] | None = None,
                 slopes: bool = True):
        x, v = ca.SX.sym("x"), ca.SX.sym("v")
        if kernels is not None:
            self._features = kernels[1] if slopes else kernels[0]
        else:
            made = representation.features_jacobian(x, v, w)
            self._features = None if made is None else ca.Function("features", [x, v, w], list(made))
        self._calls, self._slopes, self._w = kernels is not None, slopes, w
        self._points: list[tuple[ca.SX, ca.SX, ca.SX]] = []  # (x, v, what stands in there)
        self._symbols: list[ca.SX] = []
        self._definitions: list[ca.SX] = []

    def __call__(self, x, v, w):
        if self._features is None:
            return None
        if not ca.is_equal(w, self._w):
            raise ValueError("stand-ins are made for one weights symbol")
        for x0, v0, stand_in in self._points:
            if ca.is_equal(x, x0) and ca.is_equal(v, v0):
                return stand_in
        made = self._features(x, v) if self._calls else self._features(x, v, w)
        value = made if not self._slopes else made[0]
        q = ca.SX.sym("q", value.shape[0])
        self._symbols.append(q)
        self._definitions.append(ca.densify(value))
        stand_in = q
        if self._slopes:
            jacobian = ca.reshape(made[1], value.shape[0], 2)  # a kernel's comes as one column
            slope, u0 = ca.SX.sym("J", *jacobian.shape), ca.SX.sym("u0", 2)
            self._symbols += [slope, u0]
            self._definitions += [ca.densify(jacobian), ca.vertcat(x, v)]
            stand_in = q + ca.mtimes(slope, ca.vertcat(x, v) - u0)
        self._points.append((x, v, stand_in))
        return stand_in

    def resolved(self, expressions: list[ca.SX]) -> list[ca.SX]:
        """`expressions` with every stand-in's placeholders replaced by what they stand for."""
        if not self._symbols:
            return expressions
        if not self._calls:
            _, out = ca.substitute_inplace(self._symbols, self._definitions, expressions, False)
            return out
        # Definitions holding calls are not for substitute_inplace (tried: the steps' outputs came back NaN): one
        # placeholder at a time, into the definitions after it (a later point is made of earlier features) and the
        # expressions.
        pending, out = list(self._definitions), list(expressions)
        for symbol in self._symbols:
            definition, pending = pending[0], pending[1:]
            replaced = ca.substitute(pending + out, [symbol], [definition])
            pending, out = replaced[:len(pending)], replaced[len(pending):]
        return out


def with_weights(step: ca.Function, weights: np.ndarray) -> ca.Function:
    """`step` (an SX Function whose last input is the rail's weights) with the weights fixed at `weights`: every
    product and sum of weights alone is done once, here, instead of at each step (causal's chunk and its Jacobian
    chunks a little faster), and no weights are copied per call."""
    args = [ca.SX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(step.n_in() - 1)]
    return ca.Function(step.name(), args, step.call([*args, ca.DM(weights)]), step.name_in()[:-1], step.name_out())


Compiler = Callable[[list[ca.Function]], list[ca.Function]]
"""Turns Functions into equivalent ones (for instance machine code); the edge that owns compilers and caches
gives one to the models (services/adapters/compiled.py). None keeps CasADi's interpreted evaluation. One that
compiles C may also make kernels: `kernel(name, body, inputs, outputs)` -> a Function from a C body (CasADi's
Function.jit; `inputs` and `outputs` map names to sizes), which goes into the machine code of whatever calls it."""


def kernels(representation: Representation, weights: np.ndarray, compiler: Compiler | None
            ) -> tuple[ca.Function, ca.Function] | None:
    """The representation's features and features with their Jacobian at `weights` as kernels of `compiler`
    (Representation.kernel_code), or None where it has no kernel code or the compiler makes no kernels."""
    make = getattr(compiler, "kernel", None)
    code = representation.kernel_code(weights) if make is not None else None
    if code is None:
        return None
    inputs = {"x": 1, "v": 1}
    made = (make(f"{representation.name}_features", code.features, inputs, {"q": code.size}),
            make(f"{representation.name}_features_jacobian", code.jacobian, inputs, {"q": code.size, "J": 2 * code.size}))
    return None if None in made else made  # a kernel the compiler refused: both written out


class ReducedSwitch:
    """Reduced switch with one rail representation; Functions built once, reused for every throw."""

    def __init__(self, representation: Representation, weights: np.ndarray, params: ReducedParams = ReducedParams(),
                 rate_hz: float = 50.0, compiler: Compiler | None = None):
        self.representation = representation
        self.weights = np.asarray(weights, dtype=float)
        self.params = params
        self.rate_hz = rate_hz
        self._adjuster = replace(params.plant.adjuster, contact_stiffness_n_m=params.bolt_stiffness_n_m,
                                 contact_damping_s_m=params.contact_damping_s_m)
        self._lock_params = replace(params.plant.lock, stiffness_n_m=params.lock_stiffness_n_m,
                             latch_rate_1_s=params.latch_rate_1_s or params.plant.lock.latch_rate_1_s)
        beam = RailBeam(params.plant.rail)
        # The chairs' normal forces seen at the drive point for motion in the rails' static shape (virtual work).
        self._chair_normal_n = float(GRAVITY_M_S2 * np.sum(beam.masses_kg * beam.shape))
        self._nominal_nuisance = {name: float(getattr(getattr(params.plant, name.split(".")[0]), name.split(".")[1]))
                                  for name in NUISANCES}
        self._nominal = {**{name: FAULT_PARAMETERS[name].nominal for name in FAULT_ORDER}, **self._nominal_nuisance}
        self.step = self._build_step()
        self.compiler = compiler

    def nominal(self) -> dict[str, float]:
        """Every parameter at its nominal value: faults none, the switch as built."""
        return dict(self._nominal)

    def vector(self, values: dict[str, float] | None = None) -> np.ndarray:
        """The parameter vector (PARAMETERS order): nominal where not given."""
        full = {**self._nominal, **(values or {})}
        unknown = full.keys() - _KNOWN
        if unknown:
            raise ValueError(f"unknown parameters {sorted(unknown)}; accepted: {', '.join(PARAMETERS)}")
        return np.array([full[name] for name in PARAMETERS], dtype=float)

    def _lock(self, s, theta) -> LockTerms:
        """The end-position lock at state `s` (rod from the motor angle, blades at the drive point)."""
        p = self.params.plant
        faults = dict(zip(PARAMETERS, ca.vertsplit(theta)))
        rod_m = rod_kinematics(p.drive, s[0], s[1])[0]
        return lock_terms(self._lock_params, p.drive, self._adjuster, p.rail.left_stock_m, p.rail.right_stock_m, s[4],
                          rod_m, s[6:8], faults["left_bolt_offset"], faults["right_bolt_offset"],
                          self.params.contact_width_m)

    def _ode(self, s, omega_ref, theta, w, frozen_rail=None, features=None):
        """Derivative and outputs; with `frozen_rail` (a state), the rail is its linear stand-in there.
        `features(x, v, w)` makes the rail's learned features at a point (default: the representation's)."""
        features = features or self.representation.features
        p = self.params.plant
        angle, omega, integral, current, x, v = (s[i] for i in range(6))
        faults = dict(zip(PARAMETERS, ca.vertsplit(theta)))
        motor = replace(p.motor, coulomb_friction_nm=faults["motor.coulomb_friction_nm"] + faults["drive_friction_nm"],
                        torque_constant_nm_a=faults["motor.torque_constant_nm_a"],
                        emf_constant_v_s=faults["motor.torque_constant_nm_a"], resistance_ohm=faults["motor.resistance_ohm"],
                        supply_v=faults["motor.supply_v"])
        chairs = ((faults["rail.chair_friction_coefficient"] - self._nominal_nuisance["rail.chair_friction_coefficient"])
                  * self._chair_normal_n * ca.tanh(v / self.params.chair_friction_speed_m_s))
        rod_m, rod_velocity, lever_m = rod_kinematics(p.drive, angle, omega)
        adjuster_m, adjuster_velocity = adjuster_on_rod(p.drive, x, v)

        def contact(pen, rate, k, damping):
            return smooth_contact(pen, rate, k, damping, self.params.contact_width_m)

        rod_force = adjuster_force(self._adjuster, rod_m, rod_velocity, adjuster_m, adjuster_velocity,
                                   faults["left_bolt_offset"], faults["right_bolt_offset"], contact)
        drive_force = p.drive.linkage_ratio * rod_force
        lock = self._lock(s, theta)
        external = (drive_force + lock.force_n + stock_rail_force(self.params, x, v)
                    - self._bearing_damping(faults["bearing_friction"], v) * v
                    - faults["obstacle_friction"] * obstacle_profile(p.obstacle, x, faults["obstacle_position"]) * v
                    - chairs)
        rail = self.representation
        if frozen_rail is None:
            acceleration = rail.acceleration(x, v, external, w, features(x, v, w))
        else:
            x0, v0 = frozen_rail[4], frozen_rail[5]
            at_point = features(x0, v0, w)
            mass, stiffness, damping = rail.linearisation(x0, v0, w, at_point)
            base = rail.acceleration(x0, v0, 0.0, w, at_point)  # constant: no derivative reaches W
            acceleration = base + (external - stiffness * (x - x0) - damping * (v - v0)) / mass

        def clip(value, limit):
            return smooth_clip(value, limit, self.params.voltage_corner_v)

        voltage, d_integral = controller(p.controller, motor, omega_ref, omega, integral, 1.0, clip)
        d_current, d_omega = motor_derivatives(motor, voltage, current, omega, rod_force * lever_m)
        derivative = ca.vertcat(omega, d_omega, d_integral, d_current, v, acceleration, lock.d_hooks)
        return derivative, ca.vertcat(current, angle, omega, x, v, drive_force + lock.force_n)

    def _bearing_damping(self, bearing_friction, v):
        """Drive-point damping of the bearing fault through the port of the blades' direction of motion."""
        (gain_right, offset_right), (gain_left, offset_left) = self.params.bearing_port
        rightwards = 0.5 * (1.0 + ca.tanh(v / self.params.port_velocity_m_s))
        return (rightwards * (gain_right * bearing_friction + offset_right)
                + (1.0 - rightwards) * (gain_left * bearing_friction + offset_left))

    def _build_step(self, kernels: tuple[ca.Function, ca.Function] | None = None) -> ca.Function:
        """One sample (`_sample`) as a Function; with `kernels` (StandIns), its features made by calls of them,
        valid at their weights only."""
        symbols = self._step_symbols()
        if kernels is None:
            state, output = ca.cse(list(self._sample(*symbols, self.representation.features)))
        else:
            calls = StandIns(self.representation, symbols[3], kernels, slopes=False)
            state, output = ca.cse(calls.resolved(list(self._sample(*symbols, calls))))
        return ca.Function("sample_step", list(symbols), [state, output], ["s", "ref", "theta", "w"], ["s_next", "y"])

    def fixed_step(self, kernels: tuple[ca.Function, ca.Function] | None = None) -> ca.Function:
        """`step` with the rail's weights fixed at this switch's: (s, ref, theta) -> (s_next, y). With `kernels`
        (Functions of (x, v) made from Representation.kernel_code at these weights), the features are made by
        calls of them: the same values to the rounding."""
        return with_weights(self.step if kernels is None else self._build_step(kernels), self.weights)

    def fixed_sensitivity_step(self, directions: int, kernels: tuple[ca.Function, ca.Function] | None = None
                               ) -> ca.Function:
        """`sensitivity_step` over the parameters with the rail's weights fixed at this switch's, `kernels` as for
        `fixed_step`."""
        return with_weights(self.sensitivity_step(directions, kernels=kernels), self.weights)

    def _step_symbols(self) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX]:
        """The state, the reference at the sample interval's start and end, the parameters and the rail's weights."""
        return (ca.SX.sym("s", len(STATES)), ca.SX.sym("ref", 2), ca.SX.sym("theta", len(PARAMETERS)),
                ca.SX.sym("w", self.representation.size))

    def _sample(self, s, ref, theta, w, features: Callable) -> tuple[ca.SX, ca.SX]:
        """The state one sample later and the outputs there: `substeps` split steps (see the module's
        docstring), the reference linear over the sample, the rail's features made by `features`."""
        substeps = self.params.steps_per_sample(self.rate_hz)
        h = 1.0 / (self.rate_hz * substeps)
        mechanical = len(STATES) - 2  # the hook levels are the last two states

        def relax_hooks(state, duration):
            lock = self._lock(state, theta)
            return ca.vertcat(state[:mechanical], relax(state[mechanical:], lock.latch_1_s, lock.release_1_s, duration))

        state = s
        for k in range(substeps):
            state = relax_hooks(state, h / 2)
            hooks = state[mechanical:]

            def omega_ref(fraction, k=k):  # fraction of this substep -> reference
                return ref[0] + (ref[1] - ref[0]) * (k + fraction) / substeps

            def rhs(x, fraction, hooks=hooks, omega_ref=omega_ref):
                return self._ode(ca.vertcat(x, hooks), omega_ref(fraction), theta, w, features=features)[0][:mechanical]

            def w_rhs(x, fraction, point, hooks=hooks, omega_ref=omega_ref):
                return self._ode(ca.vertcat(x, hooks), omega_ref(fraction), theta, w, frozen_rail=point,
                                 features=features)[0][:mechanical]

            state = ca.vertcat(ros2(rhs, state[:mechanical], h, 1, w_rhs), hooks)
            state = relax_hooks(state, h / 2)
        _, output = self._ode(state, ref[1], theta, w)  # the outputs need no acceleration: no features
        return state, output

    @lru_cache(maxsize=8)
    def rollout(self, samples: int) -> ca.Function:
        """(s0, refs 2xN, theta, w) -> outputs 6xN at the N sample times after the start (theta: PARAMETERS)."""
        function = self._rollout(samples)
        return function if self.compiler is None else self.compiler([function])[0]

    def _rollout(self, samples: int) -> ca.Function:
        s0 = ca.MX.sym("s0", len(STATES))
        refs = ca.MX.sym("refs", 2, samples)
        theta = ca.MX.sym("theta", len(PARAMETERS))
        w = ca.MX.sym("w", self.representation.size)
        state, outputs = rolled(self.step, s0, refs, theta, w)
        return ca.Function("rollout", [s0, refs, theta, w], [outputs, state],
                           ["s0", "refs", "theta", "w"], ["y", "s_end"])

    def sensitivity_step(self, directions: int, wrt: str = "theta",
                         kernels: tuple[ca.Function, ca.Function] | None = None) -> ca.Function:
        """One sample carrying K forward sensitivities: (s and its K derivatives stacked, ref, theta, the K
        seeds flattened, w) -> (the same one sample later, outputs 6 and their derivatives 6K). The seeds are
        over the parameters (P x K, `wrt` "theta": the diagnosis) or over the rail's weights (size x K, `wrt`
        "w": training).

        The sensitivities ride through each step in SX as K extra 8-vectors of state: the same numbers
        as CasADi's forward derivative of a rollout, at a small part of its cost, which recomputes
        each step's nominal values inside its derivative. Over the parameters, a learned rail's features enter
        through their stand-ins (StandIns): its networks carry two directions instead of K (causal's Jacobian
        chunks markedly faster, the more so the larger K). Over the weights, the derivatives run through
        the networks' insides, so the step is differentiated as written. `kernels`: as for `fixed_step` (over the
        parameters only)."""
        n = len(STATES)
        s, ref, theta, w = self._step_symbols()
        varied = {"theta": theta, "w": w}[wrt]
        state_seeds, parameter_seeds = ca.SX.sym("S", n, directions), ca.SX.sym("D", varied.shape[0], directions)
        point, seeds = ca.vertcat(s, varied), ca.vertcat(state_seeds, parameter_seeds)
        if wrt == "w":
            s_next, y = self.step(s, ref, theta, w)
            expressions = [s_next, ca.jtimes(s_next, point, seeds), y, ca.jtimes(y, point, seeds)]
        else:
            stand_ins = StandIns(self.representation, w, kernels)
            s_next, y = self._sample(s, ref, theta, w, stand_ins)
            expressions = stand_ins.resolved([s_next, ca.jtimes(s_next, point, seeds), y, ca.jtimes(y, point, seeds)])
        s_next, s_next_dot, y, y_dot = ca.cse(expressions)
        return ca.Function("sensitivity_step", [ca.vertcat(s, ca.vec(state_seeds)), ref, theta, ca.vec(parameter_seeds), w],
                           [ca.vertcat(s_next, ca.vec(s_next_dot)), ca.vertcat(y, ca.vec(y_dot))],
                           ["s_dot", "ref", "theta", "seeds", "w"], ["s_dot_next", "y_dot"])

    def sensitivity_rollout(self, samples: int, directions: int) -> ca.Function:
        """(s0, refs 2xN, theta, seeds PxK, w) -> outputs 6xN and their derivatives along the K parameter
        seeds, 6K x N (row 6j + i: output i along seed j)."""
        n, m = len(STATES), len(PARAMETERS)
        s0, refs = ca.MX.sym("s0", n), ca.MX.sym("refs", 2, samples)
        theta, seeds = ca.MX.sym("theta", m), ca.MX.sym("seeds", m, directions)
        weights = ca.MX.sym("w", self.representation.size)
        _, outputs = rolled(self.sensitivity_step(directions), ca.vertcat(s0, ca.MX.zeros(n * directions)), refs, theta,
                            ca.vec(seeds), weights)
        return ca.Function("sensitivity_rollout", [s0, refs, theta, seeds, weights],
                           [outputs[:len(OUTPUTS), :], outputs[len(OUTPUTS):, :]],
                           ["s0", "refs", "theta", "seeds", "w"], ["y", "y_dot"])

    def reference_columns(self, reference: Reference, samples: int, first: int = 0) -> np.ndarray:
        """Reference at each sample interval's start and end, for `samples` samples from sample `first`."""
        t = np.arange(first, first + samples + 1) / self.rate_hz
        values = reference(t)
        return np.vstack([values[:-1], values[1:]])

    def initial_state(self, rail_position_m: float, angle_rad: float, velocity_rad_s: float = 0.0,
                      current_a: float = 0.0) -> np.ndarray:
        """Start of a throw: controller integrator empty, rails at rest, hooks latched where they close."""
        p = self.params.plant
        rod_m = float(rod_kinematics(p.drive, angle_rad, 0.0)[0])
        hooks = latched_hooks(p.lock, p.drive, p.rail.left_stock_m, p.rail.right_stock_m, rail_position_m, rod_m)
        return np.array([angle_rad, velocity_rad_s, 0.0, current_a, rail_position_m, 0.0, *hooks])

    def simulate(self, s0: np.ndarray, reference: Reference, samples: int,
                 values: dict[str, float] | None = None, weights: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Outputs at the `samples` sample times after s0 (numbers in, numbers out)."""
        y, s_end = self.rollout(samples)(s0, self.reference_columns(reference, samples), self.vector(values),
                                         self.weights if weights is None else weights)
        out = dict(zip(OUTPUTS, np.asarray(y)))
        out["final_state"] = np.asarray(s_end).ravel()
        return out
