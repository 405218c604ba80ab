"""Reduced rail representations (paper, sections "Acausal modeling" and "Hybrid rail switch model").

Each replaces the finite-element rails by one component with the same port:
force F at the adjuster-rail connection, position x and velocity v there.

- `poly`: generalised mass-spring-damper with polynomial spring and damper
  (Proposition 1: non-negative coefficients make it dissipative).
- `nn`: spring c(x)^2 (x - xfix) and damper d(x, v)^2 v, with c and d one-hidden-layer
  networks, linear mass (Proposition 2: stiffness depending on position only keeps the
  spring conservative, so the component is dissipative).
- `causal`: F = g(x, v, a): a one-hidden-layer network plus the fixed inertia of the toe
  (CAUSAL_MASS_KG * a), which keeps the map invertible in a; the acceleration is found
  by a Newton step from a = 0 with its slope floored at half that mass (the learned
  dependence on a is weak, so one step is accurate).

The hidden units are algebraic sigmoids, z / sqrt(1 + z^2): smooth, odd and bounded
like tanh, but a square root and a division instead of a transcendental function,
which makes the causal switch model's compiled step a fifth faster (the network is
most of its work).

Parameters live in physical units in plain dicts of numpy arrays; `flatten` and
`unflatten` map them to the vector the CasADi functions see. Training works on an
unconstrained vector z of order one (`weights_from_z`), where the bounds of each
form (non-negative coefficients, a floor on the mass) are built in.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from railswitch.models.numerics.smooth import softplus
from railswitch.schemas.faults import RAIL_MODELS

# Typical magnitudes used to scale network inputs and outputs to order one.
POSITION_SCALE_M = 0.1
VELOCITY_SCALE_M_S = 0.1
ACCELERATION_SCALE_M_S2 = 1.0
FORCE_SCALE_N = 1000.0
GAIN_SCALE = 100.0  # c and d networks output sqrt-stiffness / sqrt-damping over this
CAUSAL_MASS_KG = 150.0  # adjuster, stretcher bars and toe: the least inertia at the drive point
# The blades' effective mass at the drive point is at least that of the adjuster, stretcher bars and toe.
MIN_MASS_KG = 150.0
MID_TRAVEL_M = 1.10


def sigmoid(z):
    """The hidden units' activation z / sqrt(1 + z^2) and its derivative (1 + z^2)^(-3/2)."""
    inverse_norm = 1.0 / ca.sqrt(1.0 + z * z)
    return z * inverse_norm, inverse_norm**3


def _mlp(inputs, w0, b0, w1, b1):
    """One hidden layer, linear output."""
    return ca.mtimes(w1, sigmoid(ca.mtimes(w0, inputs) + b0)[0]) + b1


def _is_symbolic(z) -> bool:
    return isinstance(z, (ca.SX, ca.MX))


# A kernel's arrays of hidden units are padded with units of zero weight to a multiple of this: the C compiler's
# vector loop over them then needs no scalar tail, which at -O2 it will not write (GCC 12's cost model).
KERNEL_LANES = 8


@dataclass(frozen=True)
class KernelCode:
    """A representation's features at fixed weights as C function bodies (CasADi's Function.jit): inputs `x` and
    `v` (one number each), outputs `q` (the features) and, in `jacobian`, `J` (their Jacobian in (x, v), column-major).

    Written out unit by unit as CasADi writes the networks (SX), each hidden unit's square root and division is
    its own instruction, one at a time; as a loop over arrays of units, the compiler makes them vector instructions
    (the causal rail's 50 units: 232 ns a point unit by unit, 49 ns as a loop, 512-bit registers)."""

    features: str
    jacobian: str
    size: int  # number of features


def lanes(units: int) -> int:
    """`units` rounded up to a multiple of KERNEL_LANES: the length of a kernel's arrays and loops."""
    return -(-units // KERNEL_LANES) * KERNEL_LANES


def c_array(name: str, values) -> str:
    """A static C array of doubles, padded with zeros to a multiple of KERNEL_LANES."""
    values = np.asarray(values, dtype=float).ravel()
    padded = np.zeros(lanes(values.size))
    padded[:values.size] = values
    return f"static const casadi_real {name}[{padded.size}] = {{{', '.join(repr(float(x)) for x in padded)}}};"


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
        raise NotImplementedError

    def features(self, x, v, w):
        """The learned quantities at (x, v) that `acceleration` and `linearisation` are made of (a column of a
        few, whatever the size of the networks behind them), or None where there is nothing to learn from but
        the weights themselves (poly). Derivatives with respect to anything but the weights pass through
        them by their Jacobian with respect to (x, v) alone (ReducedSwitch.sensitivity_step)."""
        return None

    def features_jacobian(self, x, v, w):
        """`features` at (x, v) and their Jacobian with respect to (x, v) (None where there are none): CasADi's
        derivative of them, unless a representation writes it out."""
        q = self.features(x, v, w)
        return None if q is None else (q, ca.jacobian(q, ca.vertcat(x, v)))

    def kernel_code(self, weights: np.ndarray) -> KernelCode | None:
        """`features` and `features_jacobian` at `weights` as C loops over the hidden units (KernelCode), or None
        where the representation has none."""
        return None

    def acceleration(self, x, v, force, w, features=None):
        """Acceleration under port force `force`; `features`: self.features(x, v, w), where already made."""
        raise NotImplementedError

    def linearisation(self, x, v, w, features=None):
        """Mass, stiffness and damping of a dissipative linear stand-in at (x, v), all non-negative:
        used only as the W matrix of the integrator. `features` as for `acceleration`."""
        raise NotImplementedError

    # -- training parametrisation -------------------------------------------------------------
    def weights_from_z(self, z):
        """Physical weights from the unconstrained training vector (numeric or symbolic)."""
        return z

    def z_from_weights(self, w: np.ndarray) -> np.ndarray:
        return np.asarray(w, dtype=float).copy()

    def initial_weights(self, seed: int) -> np.ndarray:
        """A physically plausible, seeded start for training."""
        raise NotImplementedError


def _mass_z(mass_kg: float) -> float:
    return float(np.sqrt(max(mass_kg - MIN_MASS_KG, 0.0) / 100.0))


class AcausalRepresentation(Representation):
    """m*a + spring(x) + damping(x, v)*v = F with m, spring and damping that keep it dissipative."""

    acausal = True

    def spring(self, x, p):
        raise NotImplementedError

    def damper(self, x, v, p):
        """The damping force."""
        raise NotImplementedError

    def force(self, x, v, a, w):
        p = self.unflatten(w)
        return p["m"] * a + self.spring(x, p) + self.damper(x, v, p)

    def acceleration(self, x, v, force, w, features=None):
        p = self.unflatten(w)
        return (force - self.spring(x, p) - self.damper(x, v, p)) / p["m"]

    def energy(self, x, v, w, quadrature_points: int = 64):
        """Stored energy: kinetic plus the spring's potential (trapezoid rule of the spring force)."""
        p = self.unflatten(w)
        delta = x - p["xfix"]
        s = np.linspace(0.0, 1.0, quadrature_points + 1)
        weights = np.full(s.size, 1.0 / quadrature_points)
        weights[[0, -1]] *= 0.5
        potential = 0
        for sk, wk in zip(s, weights):
            potential += wk * self.spring(p["xfix"] + sk * delta, p) * delta
        return 0.5 * p["m"] * v**2 + potential


class PolyRail(AcausalRepresentation):
    """m*a + c0*(x-xfix) + c1*(x-xfix)^3 + c2*(x-xfix)^5 + d0*v + d1*v^3 + d2*v^5 = F, coefficients >= 0."""

    name = "poly"
    shapes = {k: () for k in ("m", "c0", "c1", "c2", "d0", "d1", "d2", "xfix")}
    equations = ("m*a + c0*(x-xfix) + c1*(x-xfix)^3 + c2*(x-xfix)^5 + d0*v + d1*v^3 + d2*v^5 = F",)
    # Training scales: non-negative coefficients as scale * z^2.
    scales = {"m": 100.0, "c0": 1e3, "c1": 1e5, "c2": 1e7, "d0": 1e3, "d1": 1e4, "d2": 1e5}

    def spring(self, x, p):
        delta = x - p["xfix"]
        return p["c0"] * delta + p["c1"] * delta**3 + p["c2"] * delta**5

    def damper(self, x, v, p):
        return p["d0"] * v + p["d1"] * v**3 + p["d2"] * v**5

    def energy(self, x, v, w, quadrature_points: int = 64):
        p = self.unflatten(w)
        delta = x - p["xfix"]
        return 0.5 * p["m"] * v**2 + p["c0"] * delta**2 / 2 + p["c1"] * delta**4 / 4 + p["c2"] * delta**6 / 6

    def linearisation(self, x, v, w, features=None):
        """Tangent stiffness and damping: non-negative with non-negative coefficients."""
        p = self.unflatten(w)
        delta = x - p["xfix"]
        return (p["m"], p["c0"] + 3 * p["c1"] * delta**2 + 5 * p["c2"] * delta**4,
                p["d0"] + 3 * p["d1"] * v**2 + 5 * p["d2"] * v**4)

    def weights_from_z(self, z):
        parts = [MIN_MASS_KG + self.scales["m"] * z[0] ** 2]
        parts += [self.scales[k] * z[i] ** 2 for i, k in enumerate(self.scales) if k != "m"]
        parts += [MID_TRAVEL_M + 0.1 * z[7]]
        return ca.vertcat(*parts) if _is_symbolic(z) else np.array(parts, dtype=float)

    def z_from_weights(self, w):
        w = np.asarray(w, dtype=float)
        return np.array([_mass_z(w[0])] + [np.sqrt(w[i] / self.scales[k]) for i, k in enumerate(self.scales) if k != "m"]
                        + [(w[7] - MID_TRAVEL_M) / 0.1])

    def initial_weights(self, seed: int) -> np.ndarray:
        """200 kg, 1 kN/m spring, 10 kN s/m damper at mid-travel (deterministic: no draw)."""
        return self.flatten(dict(m=200.0, c0=1e3, c1=1e3, c2=1e3, d0=1e4, d1=1e3, d2=1e3, xfix=MID_TRAVEL_M))


NN_HIDDEN = 15
CAUSAL_HIDDEN = 50


class NNRail(AcausalRepresentation):
    """m*a + c(x)^2*(x-xfix) + d(x,v)^2*v = F, c and d one-hidden-layer networks."""

    name = "nn"
    shapes = {"m": (), "xfix": (),
              "cw0": (NN_HIDDEN, 1), "cb0": (NN_HIDDEN, 1), "cw1": (1, NN_HIDDEN), "cb1": (),
              "dw0": (NN_HIDDEN, 2), "db0": (NN_HIDDEN, 1), "dw1": (1, NN_HIDDEN), "db1": ()}
    equations = (
        "m*a + c(x)^2*(x-xfix) + d(x,v)^2*v = F",
        f"c(x) = {GAIN_SCALE:g} * (Wc1 s(Wc0 (x-xfix)/{POSITION_SCALE_M:g} + bc0) + bc1), {NN_HIDDEN} units",
        f"d(x,v) = {GAIN_SCALE:g} * (Wd1 s(Wd0 [(x-xfix)/{POSITION_SCALE_M:g}, v/{VELOCITY_SCALE_M_S:g}] + bd0) + bd1), "
        f"{NN_HIDDEN} units",
        "s(z) = z / sqrt(1 + z^2)")

    def c(self, x, p):
        """The spring network, c(x)."""
        return GAIN_SCALE * _mlp((x - p["xfix"]) / POSITION_SCALE_M, p["cw0"], p["cb0"], p["cw1"], p["cb1"])

    def d(self, x, v, p):
        """The damper network, d(x, v)."""
        return GAIN_SCALE * _mlp(ca.vertcat((x - p["xfix"]) / POSITION_SCALE_M, v / VELOCITY_SCALE_M_S),
                                 p["dw0"], p["db0"], p["dw1"], p["db1"])

    def spring(self, x, p):
        return self.c(x, p) ** 2 * (x - p["xfix"])

    def damper(self, x, v, p):
        return self.d(x, v, p) ** 2 * v

    def features(self, x, v, w):
        """c(x) and d(x, v)."""
        p = self.unflatten(w)
        return ca.vertcat(self.c(x, p), self.d(x, v, p))

    def kernel_code(self, weights: np.ndarray) -> KernelCode:
        """c(x) and d(x, v), and their Jacobian, as loops over each network's hidden units (CausalRail.kernel_code)."""
        p = self.unflatten(np.asarray(weights, dtype=float))
        cw0, dw0 = p["cw0"].ravel() / POSITION_SCALE_M, p["dw0"] / np.array([POSITION_SCALE_M, VELOCITY_SCALE_M_S])
        cw1, dw1 = GAIN_SCALE * p["cw1"].ravel(), GAIN_SCALE * p["dw1"].ravel()
        units = lanes(NN_HIDDEN)
        arrays = "\n".join([c_array("kcx", cw0), c_array("kcb", p["cb0"]), c_array("kcg", cw1), c_array("kcs", cw1 * cw0),
                            c_array("kdx", dw0[:, 0]), c_array("kdv", dw0[:, 1]), c_array("kdb", p["db0"]),
                            c_array("kdg", dw1), c_array("kdsx", dw1 * dw0[:, 0]), c_array("kdsv", dw1 * dw0[:, 1])])

        def body(slopes: bool) -> str:
            return arrays + f"""
casadi_real e = x[0] - {float(p["xfix"])!r}, c = 0, d = 0, cx = 0, dx = 0, dv = 0;
int i;
for (i = 0; i < {units}; ++i) {{
  casadi_real z = kcx[i] * e + kcb[i], r = 1.0 / sqrt(1.0 + z * z);
  c += kcg[i] * (z * r);{" cx += kcs[i] * (r * r * r);" if slopes else ""}
}}
for (i = 0; i < {units}; ++i) {{
  casadi_real z = kdx[i] * e + kdv[i] * v[0] + kdb[i], r = 1.0 / sqrt(1.0 + z * z);
  d += kdg[i] * (z * r);{" dx += kdsx[i] * (r * r * r); dv += kdsv[i] * (r * r * r);" if slopes else ""}
}}
q[0] = c + {GAIN_SCALE * float(p["cb1"])!r}; q[1] = d + {GAIN_SCALE * float(p["db1"])!r};
""" + ("J[0] = cx; J[1] = dx; J[2] = 0; J[3] = dv;\n" if slopes else "")

        return KernelCode(body(False), body(True), 2)

    def acceleration(self, x, v, force, w, features=None):
        p = self.unflatten(w)
        c, d = ca.vertsplit(self.features(x, v, w) if features is None else features)
        return (force - c**2 * (x - p["xfix"]) - d**2 * v) / p["m"]

    def linearisation(self, x, v, w, features=None):
        """Secant stiffness and damping, c(x)^2 and d(x, v)^2."""
        p = self.unflatten(w)
        c, d = ca.vertsplit(self.features(x, v, w) if features is None else features)
        return p["m"], c**2, d**2

    def weights_from_z(self, z):
        mass, xfix = MIN_MASS_KG + 100.0 * z[0] ** 2, MID_TRAVEL_M + 0.1 * z[1]
        return ca.vertcat(mass, xfix, z[2:]) if _is_symbolic(z) else np.concatenate([[mass, xfix], z[2:]])

    def z_from_weights(self, w):
        w = np.asarray(w, dtype=float)
        return np.concatenate([[_mass_z(w[0]), (w[1] - MID_TRAVEL_M) / 0.1], w[2:]])

    def initial_weights(self, seed: int) -> np.ndarray:
        """200 kg, 1 kN/m spring and 10 kN s/m damper at mid-travel, with small seeded network weights."""
        rng = np.random.default_rng(seed)
        params = {k: rng.normal(0.0, 1.0, shape) for k, shape in self.shapes.items()}
        params.update(m=200.0, xfix=MID_TRAVEL_M, cb1=np.sqrt(1e3) / GAIN_SCALE, db1=np.sqrt(1e4) / GAIN_SCALE)
        params.update(cw1=0.01 * params["cw1"], dw1=0.01 * params["dw1"])
        return self.flatten(params)


class CausalRail(Representation):
    """F = CAUSAL_MASS_KG*a + g(x, v, a), g a one-hidden-layer network; a solved from F by Newton."""

    name = "causal"
    acausal = False
    shapes = {"w0": (CAUSAL_HIDDEN, 3), "b0": (CAUSAL_HIDDEN, 1), "w1": (1, CAUSAL_HIDDEN), "b1": ()}
    equations = (f"F = {CAUSAL_MASS_KG:g}*a + {FORCE_SCALE_N:g} * (W1 s(W0 [(x-{MID_TRAVEL_M:g})/{POSITION_SCALE_M:g}, "
                 f"v/{VELOCITY_SCALE_M_S:g}, a/{ACCELERATION_SCALE_M_S2:g}] + b0) + b1), {CAUSAL_HIDDEN} units",
                 "s(z) = z / sqrt(1 + z^2)", "a solved from F by Newton's method")
    input_scales = (POSITION_SCALE_M, VELOCITY_SCALE_M_S, ACCELERATION_SCALE_M_S2)

    def network(self, x, v, a, w):
        """g(x, v, a) and its slopes dg/dx, dg/dv, dg/da, written out so that one pass of the hidden
        layer serves the force and every slope (half the operations of differentiating it again)."""
        p = self.unflatten(w)
        hidden, slope = sigmoid(self._pre_activation(x, v, a, p))
        g = FORCE_SCALE_N * (ca.mtimes(p["w1"], hidden) + p["b1"])
        weighted = FORCE_SCALE_N * p["w1"].T * slope  # dg / d(each unit's pre-activation)
        slopes = ca.mtimes(weighted.T, p["w0"])
        return g, *(slopes[0, k] / scale for k, scale in enumerate(self.input_scales))

    def _pre_activation(self, x, v, a, p):
        u = ca.vertcat((x - MID_TRAVEL_M) / POSITION_SCALE_M, v / VELOCITY_SCALE_M_S, a / ACCELERATION_SCALE_M_S2)
        return ca.mtimes(p["w0"], u) + p["b0"]

    def force(self, x, v, a, w):
        return CAUSAL_MASS_KG * a + self.network(x, v, a, w)[0]

    def features(self, x, v, w):
        """g and its slopes dg/dx, dg/dv, dg/da at a = 0."""
        return ca.vertcat(*self.network(x, v, 0.0, w))

    def features_jacobian(self, x, v, w):
        """The features and their Jacobian with respect to (x, v), written out: dg/dx and dg/dv are two of the
        features, and the slopes' own slopes are sums over the hidden units of the weights times the units'
        curvature s''(z) = -3 z (1 + z^2)^(-5/2), in one pass with the features. CasADi's derivative of `features`
        took half as many operations again and six times the divisions (3578 operations, 604 of them divisions,
        against 2327 and 104 once merged with the features); the diagnosis's Jacobian chunks take 0.76 to 0.96 of
        their time with it (4 to 9 directions, timed alternately in one process)."""
        q = self.features(x, v, w)
        p = self.unflatten(w)
        z = self._pre_activation(x, v, 0.0, p)  # as `network` makes it: the same nodes once common ones are merged
        inverse_norm = 1.0 / ca.sqrt(1.0 + z * z)
        curvature = -3.0 * z * sigmoid(z)[1] * (inverse_norm * inverse_norm)
        # d(slope j)/d(input k) = sum_i F w1_i w0_ij w0_ik s''(z_i) / (scale_j scale_k): weights alone first
        gains, inputs = self._slope_weights(p)
        curvatures = ca.vertcat(*[ca.horzcat(*[ca.dot(gains[j] * inputs[k], curvature) for k in range(2)])
                                  for j in range(3)])
        return q, ca.vertcat(ca.horzcat(q[1], q[2]), curvatures)

    def _slope_weights(self, p: dict) -> tuple[list, list]:
        """Per unit, columns: F w1 w0_j / scale_j, what unit i's s'(z) adds to dg/d(input j) (j: x, v, a), and
        w0_k / scale_k, its pre-activation's slope in x and v (k)."""
        gains = [FORCE_SCALE_N * p["w1"].T * p["w0"][:, j] / scale for j, scale in enumerate(self.input_scales)]
        return gains, [p["w0"][:, k] / scale for k, scale in enumerate(self.input_scales[:2])]

    def kernel_code(self, weights: np.ndarray) -> KernelCode:
        """`features` and `features_jacobian` as loops over the hidden units: the same sums, the constant products
        of weights made here (the pre-activation's input scales folded into the first layer's weights)."""
        p = self.unflatten(ca.DM(np.asarray(weights, dtype=float)))
        gains, inputs = ([np.asarray(column).ravel() for column in columns] for columns in self._slope_weights(p))
        w1 = np.asarray(p["w1"]).ravel()
        units = lanes(w1.size)
        arrays = [c_array("kx", inputs[0]), c_array("kv", inputs[1]), c_array("kb", p["b0"]), c_array("kg", FORCE_SCALE_N * w1),
                  *[c_array(f"ks{j}", gains[j]) for j in range(3)]]
        head = "\n".join(arrays) + f"""
casadi_real dx = x[0] - {MID_TRAVEL_M!r}, g = 0, s0 = 0, s1 = 0, s2 = 0;
int i;"""
        unit = """
  casadi_real z = kx[i] * dx + kv[i] * v[0] + kb[i];
  casadi_real r = 1.0 / sqrt(1.0 + z * z), slope = r * r * r;
  g += kg[i] * (z * r); s0 += ks0[i] * slope; s1 += ks1[i] * slope; s2 += ks2[i] * slope;"""
        tail = f"""
q[0] = g + {FORCE_SCALE_N * float(p["b1"])!r}; q[1] = s0; q[2] = s1; q[3] = s2;
"""
        features = head + f"\nfor (i = 0; i < {units}; ++i) {{{unit}\n}}" + tail
        curvature = [c_array(f"kh{j}{k}", gains[j] * inputs[k]) for j in range(3) for k in range(2)]
        jacobian = ("\n".join(curvature) + head + "\ncasadi_real h00 = 0, h01 = 0, h10 = 0, h11 = 0, h20 = 0, h21 = 0;"
                    + f"\nfor (i = 0; i < {units}; ++i) {{{unit}"
                    + """
  casadi_real c = -3.0 * z * slope * (r * r);
  h00 += kh00[i] * c; h01 += kh01[i] * c; h10 += kh10[i] * c; h11 += kh11[i] * c; h20 += kh20[i] * c; h21 += kh21[i] * c;
}""" + tail + """J[0] = s0; J[1] = h00; J[2] = h10; J[3] = h20; J[4] = s1; J[5] = h01; J[6] = h11; J[7] = h21;
""")
        return KernelCode(features, jacobian, 4)

    @staticmethod
    def floored_inertia(slope):
        """dF/da, kept above half the toe's inertia (smoothly), so a is always solvable."""
        return softplus(slope - CAUSAL_MASS_KG / 2, CAUSAL_MASS_KG / 10) + CAUSAL_MASS_KG / 2

    def acceleration(self, x, v, force, w, features=None):
        """One Newton step from a = 0 (the learned dependence on a is weak)."""
        g, _, _, dg_da = ca.vertsplit(self.features(x, v, w) if features is None else features)
        return -(g - force) / self.floored_inertia(CAUSAL_MASS_KG + dg_da)

    def linearisation(self, x, v, w, features=None):
        """The map's slopes at a = 0, stiffness and damping clipped at zero."""
        _, dg_dx, dg_dv, dg_da = ca.vertsplit(self.features(x, v, w) if features is None else features)
        return self.floored_inertia(CAUSAL_MASS_KG + dg_da), ca.fmax(dg_dx, 0.0), ca.fmax(dg_dv, 0.0)

    def initial_weights(self, seed: int) -> np.ndarray:
        """Small seeded weights; acceleration enters through the toe's inertia until the data says otherwise."""
        rng = np.random.default_rng(seed)
        params = {k: rng.normal(0.0, 1.0 / np.sqrt(shape[-1] if len(shape) == 2 else 1), shape)
                  for k, shape in self.shapes.items()}
        params["w1"] = 0.1 * params["w1"]
        params["w0"][:, 2] = 0.0
        params["b1"] = np.zeros(())
        return self.flatten(params)

    def acceleration_input_weights(self) -> np.ndarray:
        """Flat indices of the first-layer weights that multiply the acceleration input."""
        probe = self.unflatten(np.zeros(self.size))
        probe["w0"][:, 2] = 1.0
        return np.flatnonzero(self.flatten(probe))


REPRESENTATIONS: dict[str, Representation] = {r.name: r for r in (PolyRail(), NNRail(), CausalRail())}
assert tuple(REPRESENTATIONS) == RAIL_MODELS, "one representation per rail model of the contract"
