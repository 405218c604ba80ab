"""Reduced rail representations (paper, sections "Acausal modeling" and "Hybrid rail switch model").

Each replaces the finite-element rails by one component with the same port:
force F at the adjuster-rail connection, position x and velocity v there.

- `poly`: generalised mass-spring-damper with polynomial spring and damper
  (Proposition 1: non-negative coefficients make it dissipative).
- `nn`: spring c(x)^2 (x - xfix) and damper d(x, v)^2 v, with c and d one-hidden-layer
  tanh networks, linear mass (Proposition 2: stiffness depending on position only
  keeps the spring conservative, so the component is dissipative).
- `causal`: F = g(x, v, a): a one-hidden-layer tanh network plus the fixed inertia of
  the toe (CAUSAL_MASS_KG * a), which keeps the map invertible in a; the acceleration
  is found by a Newton step from a = 0 with its slope floored at half that mass (the
  learned dependence on a is weak, so one step is accurate).

Parameters live in physical units in plain dicts of numpy arrays; `flatten` and
`unflatten` map them to the vector the optimisers and CasADi functions see.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from models.smooth import softplus

# Typical magnitudes used to scale network inputs and outputs to order one.
POSITION_SCALE_M = 0.1
VELOCITY_SCALE_M_S = 0.1
ACCELERATION_SCALE_M_S2 = 1.0
FORCE_SCALE_N = 1000.0
GAIN_SCALE = 100.0  # c and d networks output sqrt-stiffness / sqrt-damping over this
CAUSAL_MASS_KG = 150.0  # adjuster, stretcher bars and toe: the least inertia at the drive point


def _mlp(inputs, w0, b0, w1, b1):
    """One hidden tanh layer, linear output."""
    return ca.mtimes(w1, ca.tanh(ca.mtimes(w0, inputs) + b0)) + b1


def _floored_inertia(slope):
    """dF/da of the causal map, kept above half the toe's inertia (smoothly), so a is always solvable."""
    return softplus(slope - CAUSAL_MASS_KG / 2, CAUSAL_MASS_KG / 10) + CAUSAL_MASS_KG / 2


@dataclass(frozen=True)
class Representation:
    """Shapes of a representation's parameters and its constitutive law."""

    name: str
    shapes: dict[str, tuple[int, ...]]
    equations: tuple[str, ...]
    acausal: bool

    @property
    def size(self) -> int:
        return int(sum(np.prod(s) for s in self.shapes.values()))

    def flatten(self, params: dict) -> np.ndarray:
        return np.concatenate([np.asarray(params[k], dtype=float).ravel(order="F") for k in self.shapes])

    def unflatten(self, vector) -> dict:
        """Split a (numeric or symbolic) vector into named parameters, column-major."""
        out, start = {}, 0
        for key, shape in self.shapes.items():
            n = int(np.prod(shape))
            piece = vector[start:start + n]
            if isinstance(vector, np.ndarray):
                out[key] = piece.reshape(shape, order="F")
            else:
                out[key] = ca.reshape(piece, *(shape if len(shape) == 2 else (shape[0], 1))) if shape else piece
            start += n
        return out

    # -- constitutive law ---------------------------------------------------------------------
    def force(self, x, v, a, w):
        """Force at the port that produces acceleration a at state (x, v)."""
        p = self.unflatten(w)
        if self.name == "poly":
            return p["m"] * a + self.spring(x, p) + p["d0"] * v + p["d1"] * v**3 + p["d2"] * v**5
        if self.name == "nn":
            return p["m"] * a + self.spring(x, p) + self.damping(x, v, p) * v
        u = ca.vertcat((x - 1.10) / POSITION_SCALE_M, v / VELOCITY_SCALE_M_S, a / ACCELERATION_SCALE_M_S2)
        return CAUSAL_MASS_KG * a + FORCE_SCALE_N * _mlp(u, p["w0"], p["b0"], p["w1"], p["b1"])

    def spring(self, x, p):
        delta = x - p["xfix"]
        if self.name == "poly":
            return p["c0"] * delta + p["c1"] * delta**3 + p["c2"] * delta**5
        return self.stiffness_nn(x, p) * delta

    def stiffness_nn(self, x, p):
        """c(x)^2 of the NN spring."""
        c = GAIN_SCALE * _mlp((x - p["xfix"]) / POSITION_SCALE_M, p["cw0"], p["cb0"], p["cw1"], p["cb1"])
        return c**2

    def damping(self, x, v, p):
        """d(x, v)^2 of the NN damper."""
        d = GAIN_SCALE * _mlp(ca.vertcat((x - p["xfix"]) / POSITION_SCALE_M, v / VELOCITY_SCALE_M_S),
                              p["dw0"], p["db0"], p["dw1"], p["db1"])
        return d**2

    def acceleration(self, x, v, force, w, newton_steps: int = 1):
        """Acceleration under port force `force`: explicit for acausal forms, Newton for the causal map."""
        if self.acausal:
            p = self.unflatten(w)
            return (force - (self.force(x, v, 0.0, w))) / p["m"]
        a_sym = ca.SX.sym("a")
        residual = self.force(x, v, a_sym, w) - force
        slope = _floored_inertia(ca.jacobian(residual, a_sym))
        a = ca.SX(0.0)
        for _ in range(newton_steps):
            r, s = ca.substitute([residual, slope], [a_sym], [a])
            a = a - r / s
        return a

    def linearisation(self, x, v, w):
        """Mass, stiffness and damping of a dissipative linear stand-in at (x, v), all non-negative.

        Secant coefficients of the acausal forms (c(x)^2, d(x, v)^2) and the clipped
        slopes of the causal map: used only as the W matrix of the integrator.
        """
        p = self.unflatten(w)
        if self.name == "poly":
            delta = x - p["xfix"]
            return (p["m"], p["c0"] + 3 * p["c1"] * delta**2 + 5 * p["c2"] * delta**4,
                    p["d0"] + 3 * p["d1"] * v**2 + 5 * p["d2"] * v**4)
        if self.name == "nn":
            return p["m"], self.stiffness_nn(x, p), self.damping(x, v, p)
        a_sym, x_sym, v_sym = ca.SX.sym("a"), ca.SX.sym("x"), ca.SX.sym("v")
        g = self.force(x_sym, v_sym, a_sym, w)
        slopes = ca.substitute([ca.jacobian(g, a_sym), ca.jacobian(g, x_sym), ca.jacobian(g, v_sym)],
                               [a_sym, x_sym, v_sym], [ca.SX(0.0), x, v])
        return _floored_inertia(slopes[0]), ca.fmax(slopes[1], 0.0), ca.fmax(slopes[2], 0.0)

    def energy(self, x, v, w, quadrature_points: int = 64):
        """Stored energy: kinetic plus the spring's potential (acausal forms only)."""
        p = self.unflatten(w)
        kinetic = 0.5 * p["m"] * v**2
        delta = x - p["xfix"]
        if self.name == "poly":
            return kinetic + p["c0"] * delta**2 / 2 + p["c1"] * delta**4 / 4 + p["c2"] * delta**6 / 6
        s = np.linspace(0.0, 1.0, quadrature_points + 1)
        weights = np.full(s.size, 1.0 / quadrature_points)
        weights[[0, -1]] *= 0.5
        potential = 0
        for sk, wk in zip(s, weights):  # trapezoid rule for the integral of the spring force
            potential += wk * self.spring(p["xfix"] + sk * delta, p) * delta
        return kinetic + potential


NN_HIDDEN = 15
CAUSAL_HIDDEN = 50

REPRESENTATIONS: dict[str, Representation] = {
    "poly": Representation(
        "poly", {k: () for k in ("m", "c0", "c1", "c2", "d0", "d1", "d2", "xfix")},
        ("m*a + c0*(x-xfix) + c1*(x-xfix)^3 + c2*(x-xfix)^5 + d0*v + d1*v^3 + d2*v^5 = F",), True),
    "nn": Representation(
        "nn", {"m": (), "xfix": (),
               "cw0": (NN_HIDDEN, 1), "cb0": (NN_HIDDEN, 1), "cw1": (1, NN_HIDDEN), "cb1": (),
               "dw0": (NN_HIDDEN, 2), "db0": (NN_HIDDEN, 1), "dw1": (1, NN_HIDDEN), "db1": ()},
        ("m*a + c(x)^2*(x-xfix) + d(x,v)^2*v = F",
         f"c(x) = {GAIN_SCALE:g} * (Wc1 tanh(Wc0 (x-xfix)/{POSITION_SCALE_M:g} + bc0) + bc1), {NN_HIDDEN} tanh units",
         f"d(x,v) = {GAIN_SCALE:g} * (Wd1 tanh(Wd0 [(x-xfix)/{POSITION_SCALE_M:g}, v/{VELOCITY_SCALE_M_S:g}] + bd0) + bd1), "
         f"{NN_HIDDEN} tanh units"), True),
    "causal": Representation(
        "causal", {"w0": (CAUSAL_HIDDEN, 3), "b0": (CAUSAL_HIDDEN, 1), "w1": (1, CAUSAL_HIDDEN), "b1": ()},
        (f"F = {CAUSAL_MASS_KG:g}*a + {FORCE_SCALE_N:g} * (W1 tanh(W0 [(x-1.1)/{POSITION_SCALE_M:g}, "
         f"v/{VELOCITY_SCALE_M_S:g}, a/{ACCELERATION_SCALE_M_S2:g}] + b0) + b1), {CAUSAL_HIDDEN} tanh units",
         "a solved from F by Newton's method"), False),
}
