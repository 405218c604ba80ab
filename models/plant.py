"""High-fidelity rail switch: the stand-in for the paper's Modelica model.

Assembles motor, speed controller, crank drive, adjuster and finite-element
rails with the fault components into one stiff ODE, written once in CasADi
SX and integrated with SUNDIALS CVODES (BDF, sparse direct Newton solver on
the exact Jacobian from automatic differentiation).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import casadi as ca
import numpy as np

from railswitch.models.adjuster import AdjusterParams, adjuster_energy, adjuster_force
from railswitch.models.drive import DriveParams, adjuster_on_rod, rod_kinematics
from railswitch.models.lock import LockParams, latched_hooks, lock_terms
from railswitch.models.faults import FAULT_ORDER, ObstacleParams, bearing_weights, fault_vector, obstacle_profile, unpack
from railswitch.models.motor import ControllerParams, MotorParams, controller, motor_derivatives
from railswitch.models.rail_beam import RailBeam, RailParams
from railswitch.models.reference import Reference

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


class Plant:
    """State layout, symbolic equations and integrators of the high-fidelity model."""

    def __init__(self, params: PlantParams = PlantParams(), *, reltol: float = 1e-6, abstol: float = 1e-7):
        self.params = params
        self.beam = RailBeam(params.rail)
        self.nodes = params.rail.nodes
        self.n_states = 2 * self.nodes + 6
        self.index = {"current_a": 2 * self.nodes, "angle_rad": 2 * self.nodes + 1,
                      "velocity_rad_s": 2 * self.nodes + 2, "integral_v": 2 * self.nodes + 3,
                      "hook_left": 2 * self.nodes + 4, "hook_right": 2 * self.nodes + 5}
        self.tolerances = {"reltol": reltol, "abstol": abstol}
        self._build()

    # -- equations ---------------------------------------------------------------------------
    def _build(self) -> None:
        p, n = self.params, self.nodes
        x = ca.SX.sym("x", self.n_states)
        theta = ca.SX.sym("fault", len(FAULT_ORDER))
        control = ca.SX.sym("control", 3)  # reference = control[0] + control[1]*t, control[2] = powered
        t = ca.SX.sym("t")
        u, v = x[:n], x[n:2 * n]
        current, angle, omega, integral = x[2 * n], x[2 * n + 1], x[2 * n + 2], x[2 * n + 3]
        hooks = x[2 * n + 4:2 * n + 6]
        faults = unpack(theta)

        rail_m = p.rail.neutral_m + u[n - 1]
        rod_m, rod_velocity, lever_m = rod_kinematics(p.drive, angle, omega)
        adjuster_m, adjuster_velocity = adjuster_on_rod(p.drive, rail_m, v[n - 1])
        rod_force = adjuster_force(p.adjuster, rod_m, rod_velocity, adjuster_m, adjuster_velocity,
                                   faults["left_bolt_offset"], faults["right_bolt_offset"])
        drive_force = p.drive.linkage_ratio * rod_force  # on the blades, by virtual work through the lever

        lock = lock_terms(p.lock, p.drive, p.adjuster, p.rail.left_stock_m, p.rail.right_stock_m, rail_m, rod_m, hooks,
                          faults["left_bolt_offset"], faults["right_bolt_offset"])
        forces = self.beam.internal_forces(u, v)
        forces -= faults["bearing_friction"] * ca.DM(bearing_weights(self.beam.masses_kg, self.beam.shape)) * v
        obstacle = faults["obstacle_friction"] * obstacle_profile(p.obstacle, rail_m, faults["obstacle_position"])
        forces[n - 1] += drive_force + lock.force_n - obstacle * v[n - 1]
        acceleration = forces / ca.DM(self.beam.masses_kg)

        omega_ref = control[0] + control[1] * t
        voltage, d_integral = controller(p.controller, p.motor, omega_ref, omega, integral, control[2])
        d_current, d_omega = motor_derivatives(p.motor, voltage, current, omega, rod_force * lever_m)

        ode = ca.vertcat(v, acceleration, d_current, omega, d_omega, d_integral, lock.d_hooks)
        self._dae = {"x": x, "p": theta, "u": control, "t": t, "ode": ode}
        machine_force = drive_force + lock.force_n  # everything the point machine applies at the drive point
        outputs = ca.vertcat(current, angle, omega, rail_m, v[n - 1], acceleration[n - 1], machine_force, rod_m)
        self._outputs = ca.Function("outputs", [x, theta], [outputs])
        rail_energy = self.beam.energy(u, v) + lock.energy_j
        drive_energy = (adjuster_energy(p.adjuster, rod_m, adjuster_m, faults["left_bolt_offset"], faults["right_bolt_offset"])
                        + 0.5 * p.motor.rotor_inertia_kg_m2 * omega**2 + 0.5 * p.motor.inductance_h * current**2)
        self.energy = ca.Function("energy", [x, theta], [rail_energy, rail_energy + drive_energy],
                                  ["x", "fault"], ["rails", "total"])

    def ode_function(self) -> ca.Function:
        """The right-hand side f(t, x, fault, control) and its sparse Jacobian in x."""
        d = self._dae
        return ca.Function("plant_ode", [d["t"], d["x"], d["p"], d["u"]], [d["ode"], ca.jacobian(d["ode"], d["x"])],
                           ["t", "x", "fault", "control"], ["ode", "jac_x"])

    @lru_cache(maxsize=16)
    def _integrator(self, dt_s: float, steps: int) -> ca.Function:
        """CVODES over `steps` output intervals of `dt_s`; built once per grid, reused."""
        opts = {**self.tolerances, "linear_solver": "csparse", "max_num_steps": 200_000,
                "disable_internal_warnings": True}
        grid = [dt_s * (k + 1) for k in range(steps)]
        return ca.integrator("plant", "cvodes", self._dae, 0.0, grid, opts)

    # -- simulation --------------------------------------------------------------------------
    def rest_state(self, rail_position_m: float, motor_angle_rad: float = 0.0) -> np.ndarray:
        """Rails at rest in their static shape with the drive point at `rail_position_m`."""
        p = self.params
        x = np.zeros(self.n_states)
        x[: self.nodes] = self.beam.rest_shape(rail_position_m)
        x[self.index["angle_rad"]] = motor_angle_rad
        rod_m = float(np.asarray(self._outputs(x, fault_vector())).ravel()[SIGNALS.index("rod_position_m")])
        x[[self.index["hook_left"], self.index["hook_right"]]] = latched_hooks(
            p.lock, p.drive, p.rail.left_stock_m, p.rail.right_stock_m, rail_position_m, rod_m)
        return x

    def run(self, state: np.ndarray, duration_s: float, rate_hz: float, faults: dict[str, float] | None = None,
            reference: Reference | None = None) -> Trajectory:
        """Integrate from `state` for `duration_s`, sampling at `rate_hz`.

        With a reference the controller is powered and tracks it (time 0 is the
        start of this run, the controller's integrator starts from `state`);
        without one the motor is unpowered (armature short-circuited).
        """
        steps = int(round(duration_s * rate_hz))
        dt = 1.0 / rate_hz
        t = dt * np.arange(1, steps + 1)
        control = np.zeros((3, steps))
        if reference is not None:
            start, end = reference(t - dt), reference(t)
            control[1] = (end - start) / dt
            control[0] = start - control[1] * (t - dt)
            control[2] = 1.0
        theta = fault_vector(faults)
        states = np.asarray(self._integrator(dt, steps)(x0=state, p=theta, u=control)["xf"])
        return self._trajectory(t, states, theta)

    def _trajectory(self, t: np.ndarray, states: np.ndarray, theta: np.ndarray) -> Trajectory:
        values = np.asarray(self._outputs.map(states.shape[1])(states, theta))
        return Trajectory(t, dict(zip(SIGNALS, values)), states)

    def signals_at(self, state: np.ndarray, faults: dict[str, float] | None = None) -> dict[str, float]:
        """Output signals for one state."""
        values = np.asarray(self._outputs(state, fault_vector(faults))).ravel()
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
            "parameters": scalars + per_node + contact + int(self.beam.stiffness.nnz) + len(FAULT_ORDER),
            "rail_nodes": self.nodes,
            "rail_states": 2 * self.nodes,
            "fault_parameters": list(FAULT_ORDER),
            "jacobian_nonzeros": int(self.ode_function().sparsity_out("jac_x").nnz()),
            "rail_tip_stiffness_n_m": round(float(self.beam.tip_stiffness_n_m), 1),
            "solver": "cvodes (BDF, sparse direct Newton, AD Jacobian)",
        }
