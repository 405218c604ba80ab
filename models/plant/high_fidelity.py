"""High-fidelity rail switch: the stand-in for the paper's Modelica model.

Assembles motor, speed controller, crank drive, adjuster and finite-element
rails with the fault components into one stiff ODE, written once in CasADi
SX and integrated with SUNDIALS CVODES (BDF, sparse direct Newton solver on
the exact Jacobian from automatic differentiation).

A switch's own build and environment (schemas/plant.py: winding resistance,
supply, friction in the point machine and on the chairs, the heel's stiffness)
are inputs of the same equations, like the faults, so one compiled plant
serves every switch of a fleet and a cold night costs nothing to simulate.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import lru_cache
from threading import Lock

import casadi as ca
import numpy as np

from railswitch.models.plant.adjuster import AdjusterParams, adjuster_energy, adjuster_force
from railswitch.models.numerics.buffers import InPlace
from railswitch.models.plant.drive import DriveParams, adjuster_on_rod, binding_torque, rod_kinematics
from railswitch.models.plant.lock import LockParams, latched_hooks, lock_terms
from railswitch.models.plant.faults import FAULT_ORDER, ObstacleParams, bearing_weights, fault_vector, obstacle_profile, unpack
from railswitch.models.plant.motor import ControllerParams, MotorParams, controller, motor_derivatives
from railswitch.models.plant.rail_beam import RailBeam, RailParams
from railswitch.models.plant.reference import Reference
from railswitch.schemas.plant import PLANT_PARAMETERS

PLANT_VARIABLES: tuple[str, ...] = tuple(PLANT_PARAMETERS)  # a switch's own parameters, inputs of the plant

# CVODES's BDF up to order 4, not 5. The rails' bending modes are lightly damped: their eigenvalues lie close to the
# imaginary axis, where BDF of order 5 is not stable (its stability wedge is 51.8 degrees wide against order 4's 73.4),
# so at order 5 CVODES keeps failing its error test and cutting the step. Up to order 4, over two throws of each of the
# paper's five scenarios, CVODES takes fewer steps (right-to-left throws markedly fewer, left-to-right as many) and
# less time (a whole simulated throw too, in paired runs), and a throw's error against a run at 1000 times tighter
# tolerances stays of the same size (RMS current and velocity over a throw of those scenarios), both far inside what
# the recordings' check allows for the solver (tests/integration/test_recordings.py). Order 3 loses accuracy.
BDF_MAX_ORDER = 4
# Where a throw's time goes (a nominal left-to-right throw, perf): thousands of short steps. Most of it goes to the
# equations, evaluated about once a step, and to the sparse factorisations and solves; less to the equations'
# Jacobian, dearer but taken only every few steps, and to CVODES's vector operations; CasADi times every evaluation
# with the process clock, a system call here, a small share. The steps are where the blades leave and meet the stock
# rails and the lock engages (early and late in a throw). Tried and left out, over ten scenarios (the paper's faults,
# population switches), each pair of throws run alternately: CasADi's sparse QR for csparse (faster on the nominal
# pair only because rounding moved its steps; over the ten, no faster), tanh written with exp (a little faster, but
# it moved the current).
# CasADi stops CVODES wherever the control changes from one sample to the next (it takes the control as piecewise
# constant): a step cut short, and more often a fresh Jacobian and factorisation. The reference reaches the plant as the
# line of each piece of its profile (Reference.linear_pieces), the same two numbers over a piece to the last bit; as
# chords through the samples, which differ in their last bits, every sample of the ramps (20 each) was a stop. Over
# population switches (faults as benchmarks.diagnosis draws them; two throws each, the two ways alternating in one
# process): a few fewer steps, markedly fewer Jacobians, less time. A pair of throws' steps move a good deal either
# way with any rounding, so one pair says little: the nominal pair of benchmarks.plant went from a slow draw to a
# fast one. The error against a run at 1e-10 tolerances is the same (ten scenarios: RMS current and velocity over a
# throw).

SIGNALS = ("current_a", "angle_rad", "velocity_rad_s", "rail_position_m", "rail_velocity_m_s",
           "rail_acceleration_m_s2", "drive_force_n", "rod_position_m")


@dataclass(frozen=True)
class PlantParams:
    motor: MotorParams = field(default_factory=MotorParams)
    controller: ControllerParams = field(default_factory=ControllerParams)
    drive: DriveParams = field(default_factory=DriveParams)
    adjuster: AdjusterParams = field(default_factory=AdjusterParams)
    lock: LockParams = field(default_factory=LockParams)
    rail: RailParams = field(default_factory=RailParams)
    obstacle: ObstacleParams = field(default_factory=ObstacleParams)


@dataclass(frozen=True)
class Trajectory:
    """Plant signals at the sample times (seconds from the start of the run)."""

    t_s: np.ndarray
    signals: dict[str, np.ndarray]
    states: np.ndarray  # one column per sample

    def __getitem__(self, name: str) -> np.ndarray:
        return self.signals[name]


def nominal_values(params: PlantParams) -> dict[str, float]:
    """The plant variables as `params` has them (group.field)."""
    return {name: float(getattr(getattr(params, name.split(".")[0]), name.split(".")[1])) for name in PLANT_VARIABLES}


class Plant:
    """State layout, symbolic equations and integrators of the high-fidelity model."""

    def __init__(self, params: PlantParams = PlantParams(), *, reltol: float = 1e-6, abstol: float = 1e-7,
                 compiler: Callable[..., list[ca.Function]] | None = None):
        """`compiler` (services/adapters/compiled.py MachineCode) turns the equations into machine code, their
        Jacobian with them (`compiler([f], with_jacobian=True)`): the same numbers, CVODES spends less per step."""
        self.params = params
        self.compiler = compiler
        self.beam = RailBeam(params.rail)
        self.nodes = params.rail.nodes
        self.n_states = 2 * self.nodes + 6
        self.index = {"current_a": 2 * self.nodes, "angle_rad": 2 * self.nodes + 1,
                      "velocity_rad_s": 2 * self.nodes + 2, "integral_v": 2 * self.nodes + 3,
                      "hook_left": 2 * self.nodes + 4, "hook_right": 2 * self.nodes + 5}
        self.tolerances = {"reltol": reltol, "abstol": abstol}
        self.nominal = nominal_values(params)
        self._running = Lock()  # one run at a time on the evaluators' buffers (_evaluators)
        self._build()

    # -- equations ---------------------------------------------------------------------------
    def _build(self) -> None:
        p, n = self.params, self.nodes
        x = ca.SX.sym("x", self.n_states)
        theta = ca.SX.sym("fault", len(FAULT_ORDER))
        phi = ca.SX.sym("plant", len(PLANT_VARIABLES))
        control = ca.SX.sym("control", 3)  # reference = control[0] + control[1]*t, control[2] = powered
        t = ca.SX.sym("t")
        u, v = x[:n], x[n:2 * n]
        current, angle, omega, integral = x[2 * n], x[2 * n + 1], x[2 * n + 2], x[2 * n + 3]
        hooks = x[2 * n + 4:2 * n + 6]
        faults = unpack(theta)
        own = dict(zip(PLANT_VARIABLES, ca.vertsplit(phi)))
        binding = binding_torque(p.drive, angle, own["drive.binding_torque_nm"], own["drive.binding_position"])
        motor = replace(p.motor, resistance_ohm=own["motor.resistance_ohm"], supply_v=own["motor.supply_v"],
                        coulomb_friction_nm=own["motor.coulomb_friction_nm"] + faults["drive_friction_nm"] + binding,
                        torque_constant_nm_a=own["motor.torque_constant_nm_a"],
                        emf_constant_v_s=own["motor.torque_constant_nm_a"])
        heel = own["rail.heel_flex_factor"]

        rail_m = p.rail.neutral_m + u[n - 1]
        rod_m, rod_velocity, lever_m = rod_kinematics(p.drive, angle, omega)
        adjuster_m, adjuster_velocity = adjuster_on_rod(p.drive, rail_m, v[n - 1])
        rod_force = adjuster_force(p.adjuster, rod_m, rod_velocity, adjuster_m, adjuster_velocity,
                                   faults["left_bolt_offset"], faults["right_bolt_offset"])
        drive_force = p.drive.linkage_ratio * rod_force  # on the blades, by virtual work through the lever

        lock = lock_terms(p.lock, p.drive, p.adjuster, p.rail.left_stock_m, p.rail.right_stock_m, rail_m, rod_m, hooks,
                          faults["left_bolt_offset"], faults["right_bolt_offset"])
        forces = self.beam.internal_forces(u, v, heel, own["rail.chair_friction_coefficient"],
                                           own["rail.chair_viscous_n_s_m"])
        forces -= faults["bearing_friction"] * ca.DM(bearing_weights(self.beam.masses_kg, self.beam.shape)) * v
        obstacle = faults["obstacle_friction"] * obstacle_profile(p.obstacle, rail_m, faults["obstacle_position"])
        forces[n - 1] += drive_force + lock.force_n - obstacle * v[n - 1]
        acceleration = forces / ca.DM(self.beam.masses_kg)

        omega_ref = control[0] + control[1] * t
        voltage, d_integral = controller(p.controller, motor, omega_ref, omega, integral, control[2])
        d_current, d_omega = motor_derivatives(motor, voltage, current, omega, rod_force * lever_m)

        ode = ca.vertcat(v, acceleration, d_current, omega, d_omega, d_integral, lock.d_hooks)
        self._dae = {"x": x, "p": ca.vertcat(theta, phi), "u": control, "t": t, "ode": ode}
        none = ca.SX(0, 1)
        dae = ca.Function("railswitch_plant_dae", [t, x, ca.SX.sym("z", 0), self._dae["p"], control],
                          [ode, none, none, none], ca.dyn_in(), ca.dyn_out())
        self._dae_function = self.compiler([dae], with_jacobian=True)[0] if self.compiler else dae
        machine_force = drive_force + lock.force_n  # everything the point machine applies at the drive point
        outputs = ca.vertcat(current, angle, omega, rail_m, v[n - 1], acceleration[n - 1], machine_force, rod_m)
        self._outputs = ca.Function("outputs", [x, theta, phi], [outputs])
        rail_energy = self.beam.energy(u, v, heel) + lock.energy_j
        drive_energy = (adjuster_energy(p.adjuster, rod_m, adjuster_m, faults["left_bolt_offset"], faults["right_bolt_offset"])
                        + 0.5 * p.motor.rotor_inertia_kg_m2 * omega**2 + 0.5 * p.motor.inductance_h * current**2)
        self.energy = ca.Function("energy", [x, theta, phi], [rail_energy, rail_energy + drive_energy],
                                  ["x", "fault", "plant"], ["rails", "total"])

    def ode_function(self) -> ca.Function:
        """The right-hand side f(t, x, [fault; plant variables], control) and its sparse Jacobian in x."""
        d = self._dae
        return ca.Function("plant_ode", [d["t"], d["x"], d["p"], d["u"]], [d["ode"], ca.jacobian(d["ode"], d["x"])],
                           ["t", "x", "p", "control"], ["ode", "jac_x"])

    def variables(self, values: dict[str, float] | None = None) -> np.ndarray:
        """The plant variables in PLANT_VARIABLES order: this plant's nominal ones, overridden by `values`."""
        own = {**self.nominal, **(values or {})}
        unknown = set(own) - set(PLANT_VARIABLES)
        if unknown:
            raise ValueError(f"unknown plant parameters {sorted(unknown)}; accepted: {', '.join(PLANT_VARIABLES)}")
        return np.array([own[name] for name in PLANT_VARIABLES], dtype=float)

    @lru_cache(maxsize=16)
    def _integrator(self, dt_s: float, steps: int) -> ca.Function:
        """CVODES over `steps` output intervals of `dt_s`; built once per grid, reused."""
        opts = {**self.tolerances, "linear_solver": "csparse", "max_num_steps": 200_000, "max_order": BDF_MAX_ORDER,
                "disable_internal_warnings": True}
        grid = [dt_s * (k + 1) for k in range(steps)]
        return ca.integrator("plant", "cvodes", self._dae_function, 0.0, grid, opts)

    @lru_cache(maxsize=16)
    def _evaluators(self, dt_s: float, steps: int) -> tuple[InPlace, InPlace]:
        """The integrator over that grid and the outputs at its samples, on numpy buffers of their own
        (models/numerics/buffers.py): the states to and from DMs took a large share of a throw's time."""
        outputs = self._outputs.map("outputs_at_samples", "serial", steps, [1, 2], [])  # one fault and plant vector
        return InPlace(self._integrator(dt_s, steps)), InPlace(outputs)

    # -- simulation --------------------------------------------------------------------------
    def rest_state(self, rail_position_m: float, motor_angle_rad: float = 0.0,
                   plant: dict[str, float] | None = None) -> np.ndarray:
        """Rails at rest in their static shape with the drive point at `rail_position_m`."""
        p = self.params
        own = self.variables(plant)
        x = np.zeros(self.n_states)
        x[: self.nodes] = self.beam.rest_shape(rail_position_m, own[PLANT_VARIABLES.index("rail.heel_flex_factor")])
        x[self.index["angle_rad"]] = motor_angle_rad
        rod_m = float(np.asarray(self._outputs(x, fault_vector(), own)).ravel()[SIGNALS.index("rod_position_m")])
        x[[self.index["hook_left"], self.index["hook_right"]]] = latched_hooks(
            p.lock, p.drive, p.rail.left_stock_m, p.rail.right_stock_m, rail_position_m, rod_m)
        return x

    def run(self, state: np.ndarray, duration_s: float, rate_hz: float, faults: dict[str, float] | None = None,
            reference: Reference | None = None, plant: dict[str, float] | None = None) -> Trajectory:
        """Integrate from `state` for `duration_s`, sampling at `rate_hz`.

        With a reference the controller is powered and tracks it (time 0 is the
        start of this run, the controller's integrator starts from `state`);
        without one the motor is unpowered (armature short-circuited). `plant`
        overrides this plant's nominal variables (a switch's own build and weather).
        """
        steps = int(round(duration_s * rate_hz))
        dt = 1.0 / rate_hz
        t = dt * np.arange(1, steps + 1)
        control = np.zeros((3, steps))
        if reference is not None:
            control[0], control[1] = reference.linear_pieces(dt * np.arange(steps), t)
            control[2] = 1.0
        theta, own = fault_vector(faults), self.variables(plant)
        integrator, outputs = self._evaluators(dt, steps)
        none = np.zeros(0)  # the integrator's algebraic states and adjoint seeds: it has none
        with self._running:
            states = integrator(state, none, np.concatenate([theta, own]), control, none, none, none)[0]
            values = outputs(states, theta, own)[0]
        return Trajectory(t, dict(zip(SIGNALS, values)), states)

    def signals_at(self, state: np.ndarray, faults: dict[str, float] | None = None,
                   plant: dict[str, float] | None = None) -> dict[str, float]:
        """Output signals for one state."""
        values = np.asarray(self._outputs(state, fault_vector(faults), self.variables(plant))).ravel()
        return dict(zip(SIGNALS, values.tolist()))

    def start_throw(self, state: np.ndarray) -> np.ndarray:
        """A throw starts with the controller's integrator emptied."""
        state = state.copy()
        state[self.index["integral_v"]] = 0.0
        return state

    def describe(self) -> dict:
        """Model statistics in the spirit of the paper's Table 1."""
        p = self.params
        scalars = sum(len(vars(part)) for part in (p.motor, p.controller, p.drive, p.adjuster, p.lock, p.rail, p.obstacle))
        per_node = 4 * self.nodes  # mass, chair normal load, bearing share, static shape
        contact = 2 * len(self.beam.contact_nodes)  # stock-rail gaps on each side
        return {
            "states": self.n_states,
            "parameters": scalars + per_node + contact + int(self.beam.stiffness().nnz) + len(FAULT_ORDER),
            "rail_nodes": self.nodes,
            "rail_states": 2 * self.nodes,
            "fault_parameters": list(FAULT_ORDER),
            "switch_parameters": {name: {"unit": PLANT_PARAMETERS[name].unit, "nominal": self.nominal[name],
                                         "low": PLANT_PARAMETERS[name].low, "high": PLANT_PARAMETERS[name].high,
                                         "meaning": PLANT_PARAMETERS[name].meaning} for name in PLANT_VARIABLES},
            "jacobian_nonzeros": int(self.ode_function().sparsity_out("jac_x").nnz()),
            "rail_tip_stiffness_n_m": round(float(self.beam.tip_stiffness_n_m), 1),
            "solver": "cvodes (BDF, sparse direct Newton, AD Jacobian)",
            "machine_code": self.compiler is not None and bool(getattr(self.compiler, "machine_code", True)),
        }
