"""DC motor and its speed controller: the servo-motor half of the point machine.

Written against CasADi's symbolic API so the same equations serve the
high-fidelity plant and the reduced hybrid models.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca


@dataclass(frozen=True)
class MotorParams:
    """Permanent-magnet DC motor fed from a 110 V DC supply."""

    supply_v: float = 110.0
    resistance_ohm: float = 9.5
    inductance_h: float = 0.05
    torque_constant_nm_a: float = 0.2
    emf_constant_v_s: float = 0.2
    rotor_inertia_kg_m2: float = 0.003  # rotor plus gearbox, seen at the motor
    viscous_friction_nm_s: float = 2.0e-4
    coulomb_friction_nm: float = 0.12
    friction_speed_rad_s: float = 0.5  # regularisation width of the Coulomb friction


@dataclass(frozen=True)
class ControllerParams:
    """PI speed controller with back-calculation anti-windup and voltage saturation."""

    kp_v_s_rad: float = 3.6
    ki_v_rad: float = 32.0
    antiwindup_1_s: float = 20.0


def saturate(value, limit: float):
    """Hard clip to +-limit (a supply cannot deliver more than its voltage)."""
    return ca.fmin(ca.fmax(value, -limit), limit)


def controller(params: ControllerParams, motor: MotorParams, omega_ref, omega, integral_v, enabled,
               clip=saturate):
    """Armature voltage and integrator derivative of the PI speed loop.

    `enabled` is 1 while the point machine is powered and 0 otherwise; with 0
    the armature is short-circuited (0 V) and the integrator is frozen.
    """
    error = omega_ref - omega
    raw_v = params.kp_v_s_rad * error + integral_v
    voltage = clip(raw_v, motor.supply_v)
    d_integral = params.ki_v_rad * error + params.antiwindup_1_s * (voltage - raw_v)
    return enabled * voltage, enabled * d_integral


def motor_derivatives(params: MotorParams, voltage, current_a, omega, load_torque_nm):
    """Armature-current and rotor-speed derivatives (textbook DC motor equations)."""
    d_current = (voltage - params.resistance_ohm * current_a - params.emf_constant_v_s * omega) / params.inductance_h
    friction = params.viscous_friction_nm_s * omega + params.coulomb_friction_nm * ca.tanh(omega / params.friction_speed_rad_s)
    d_omega = (params.torque_constant_nm_a * current_a - friction - load_torque_nm) / params.rotor_inertia_kg_m2
    return d_current, d_omega
