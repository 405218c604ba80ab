"""Training data from the plant and the fits of the reduced rail representations.

Data (paper, section "Hybrid rail switch model"): the plant's motor follows random
references that push the blades back and forth; we record force, position,
velocity and acceleration at the adjuster-rail connection every 0.02 s.

Fits use CasADi's automatic differentiation and a bounded Levenberg-Marquardt:
- acausal forms: multiple shooting, each 1 s segment simulated (RK4) from its
  measured start under the measured force, positions and velocities compared;
- causal map: regression of F on (x, v, a), then fine-tuned inside the full
  reduced switch model against the plant's nominal throws.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from models.plant import Plant
from models.rail_models import Representation
from models.reduced import ReducedParams, stock_rail_force
from models.reference import Reference

RATE_HZ = 50.0
SEGMENT_SAMPLES = 50
POSITION_RESIDUAL_M = 0.002
VELOCITY_RESIDUAL_M_S = 0.01


@dataclass(frozen=True)
class RailData:
    """Signals at the adjuster-rail connection, one row per sample."""

    force_n: np.ndarray
    position_m: np.ndarray
    velocity_m_s: np.ndarray
    acceleration_m_s2: np.ndarray


def random_reference(rng: np.random.Generator, duration_s: float, gear_ratio: float = 250.0) -> Reference:
    """Random back-and-forth pushes: moves to random crank angles in [0, pi] at random speeds, with pauses."""
    t, v = [0.0], [0.0]
    crank = 0.0
    while t[-1] < duration_s:
        target = rng.uniform(0.0, np.pi)
        speed = rng.uniform(40.0, 140.0) * np.sign(target - crank)
        ramp = 0.3
        run = max(abs(target - crank) * gear_ratio / abs(speed) - ramp, 0.05)
        t += [t[-1] + ramp, t[-1] + ramp + run, t[-1] + 2 * ramp + run, t[-1] + 2 * ramp + run + rng.uniform(0.2, 1.5)]
        v += [speed, speed, 0.0, 0.0]
        crank += speed * (run + ramp) / gear_ratio
    return Reference(np.array(t), np.array(v))


def rail_experiment(plant: Plant, seed: int, duration_s: float = 100.0) -> RailData:
    """One series of random pushes through the nominal plant (deterministic for a seed)."""
    reference = random_reference(np.random.default_rng(seed), duration_s, plant.params.drive.gear_ratio)
    state = plant.run(plant.rest_state(1.0), 1.0, RATE_HZ).states[:, -1]
    trajectory = plant.run(plant.start_throw(state), duration_s, RATE_HZ, reference=reference)
    return RailData(trajectory["drive_force_n"], trajectory["rail_position_m"], trajectory["rail_velocity_m_s"],
                    trajectory["rail_acceleration_m_s2"])


# -- a bounded Levenberg-Marquardt on CasADi residuals --------------------------------------------
@dataclass
class FitResult:
    z: np.ndarray
    cost: float
    iterations: int
    history: list[float]


def levenberg_marquardt(residual_jacobian: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], z0: np.ndarray,
                        iterations: int = 50, progress: Callable[[int, float], None] | None = None,
                        tolerance: float = 1e-6) -> FitResult:
    """Minimise 0.5*|r(z)|^2 with Marquardt's scaling; z unconstrained (bounds live in the parametrisation)."""
    z = np.asarray(z0, dtype=float).copy()
    r, jac = residual_jacobian(z)
    cost = 0.5 * float(r @ r)
    if not np.isfinite(cost):
        raise ValueError("the starting point gives a non-finite residual; start closer")
    damping = 1e-3
    history = [cost]
    for k in range(iterations):
        gradient = jac.T @ r
        hessian = jac.T @ jac
        scale = np.maximum(np.diag(hessian), 1e-12)
        improved = False
        for _ in range(12):
            step = np.linalg.solve(hessian + damping * np.diag(scale), -gradient)
            r_new, jac_new = residual_jacobian(z + step)
            cost_new = 0.5 * float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new < cost:
                improved = True
                relative = (cost - cost_new) / max(cost, 1e-30)
                z, r, jac, cost = z + step, r_new, jac_new, cost_new
                damping = max(damping / 3.0, 1e-9)
                break
            damping *= 8.0
        history.append(cost)
        if progress is not None:
            progress(k + 1, cost)
        if not improved or relative < tolerance:
            break
    return FitResult(z, cost, len(history) - 1, history)


# -- parametrisations: z (unconstrained, order one) <-> physical weights ---------------------------
POLY_SCALES = {"m": 100.0, "c0": 1e3, "c1": 1e5, "c2": 1e7, "d0": 1e3, "d1": 1e4, "d2": 1e5}


def weights_from_z(representation: Representation, z):
    """Physical weights; non-negative poly coefficients and masses as scale * z^2."""
    if representation.name == "poly":
        parts = [POLY_SCALES[k] * z[i] ** 2 for i, k in enumerate(POLY_SCALES)] + [1.10 + 0.1 * z[7]]
        return ca.vertcat(*parts) if isinstance(z, (ca.SX, ca.MX)) else np.array(parts, dtype=float)
    if representation.name == "nn":
        mass, xfix = 100.0 * z[0] ** 2, 1.10 + 0.1 * z[1]
        rest = z[2:]
        return ca.vertcat(mass, xfix, rest) if isinstance(z, (ca.SX, ca.MX)) else np.concatenate([[mass, xfix], rest])
    return z


def z_from_weights(representation: Representation, w: np.ndarray) -> np.ndarray:
    w = np.asarray(w, dtype=float)
    if representation.name == "poly":
        return np.array([np.sqrt(w[i] / POLY_SCALES[k]) for i, k in enumerate(POLY_SCALES)] + [(w[7] - 1.10) / 0.1])
    if representation.name == "nn":
        return np.concatenate([[np.sqrt(w[0] / 100.0), (w[1] - 1.10) / 0.1], w[2:]])
    return w.copy()


# -- acausal: multiple shooting on rail data --------------------------------------------------------
def rail_step_function(representation: Representation, reduced: ReducedParams, substeps: int = 2) -> ca.Function:
    """(x, v, F at sample start, F at sample end, w) -> (x, v) one sample later, RK4."""
    s = ca.SX.sym("s", 2)
    force = ca.SX.sym("F", 2)
    w = ca.SX.sym("w", representation.size)
    tau = ca.SX.sym("tau")

    def ode(state, fraction):
        x, v = state[0], state[1]
        port = force[0] + (force[1] - force[0]) * fraction + stock_rail_force(reduced, x, v)
        return ca.vertcat(v, representation.acceleration(x, v, port, w))

    h = 1.0 / (RATE_HZ * substeps)
    state = s
    for k in range(substeps):
        t0 = k / substeps
        k1 = ode(state, t0)
        k2 = ode(state + h / 2 * k1, t0 + 0.5 / substeps)
        k3 = ode(state + h / 2 * k2, t0 + 0.5 / substeps)
        k4 = ode(state + h * k3, t0 + 1.0 / substeps)
        state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("rail_step", [s, force, w], [state]).expand()


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


def acausal_residuals(representation: Representation, reduced: ReducedParams, data: list[RailData]) -> Callable:
    """z -> (residuals, Jacobian) of the scaled shooting errors over all segments."""
    starts, forces, measured = shooting_segments(data)
    segments = starts.shape[1]
    step = rail_step_function(representation, reduced)
    roll = step.mapaccum("segment", SEGMENT_SAMPLES)
    z = ca.MX.sym("z", _z_size(representation))
    w = weights_from_z(representation, z)
    s0 = ca.MX.sym("s0", 2)
    f = ca.MX.sym("f", 2, SEGMENT_SAMPLES)
    states = roll(s0, f, ca.repmat(w, 1, SEGMENT_SAMPLES))
    one = ca.Function("one_segment", [s0, f, z], [states])
    all_segments = one.map(segments, "serial")
    S0 = ca.MX(ca.DM(starts))
    F = ca.MX(ca.DM(forces.transpose(0, 2, 1).reshape(2, -1)))  # 2 x (N * segments), segment-major
    predicted = all_segments(S0, F, ca.repmat(z, 1, segments))
    target = measured.transpose(0, 2, 1).reshape(2, -1)
    scale = ca.DM([[1.0 / POSITION_RESIDUAL_M], [1.0 / VELOCITY_RESIDUAL_M_S]])
    residual = ca.vec((predicted - ca.DM(target)) * ca.repmat(scale, 1, predicted.shape[1]))
    fn = ca.Function("acausal_residual", [z], [residual, ca.jacobian(residual, z)])

    def evaluate(zv: np.ndarray):
        r, j = fn(zv)
        return np.asarray(r).ravel(), np.asarray(j)
    return evaluate


def _z_size(representation: Representation) -> int:
    return representation.size
