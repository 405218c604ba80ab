"""Tongue rails as a lumped finite-element beam (paper, section "Rail switch model").

The two tongue rails, tied by stretcher bars, move as one Euler-Bernoulli beam
clamped at the heel and pushed at the toe (the drive point). It is discretised
as a chain of lumped masses joined by rotational bending springs and dampers
(the paper's "chain of alternating bodies and joints"); every node sits on a
slide chair with roller friction, and the toe region closes against
the stock rail at each end of travel. Node coordinate `u` is the lateral
displacement from the unstressed shape; the travel coordinate of the drive
point is `neutral_m + u[-1]`.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np
import scipy.sparse as sp

from railswitch.models.plant.adjuster import unilateral_contact

GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class RailParams:
    """Two 60 kg/m rails (UIC60: E = 210 GPa, lateral I = 5.12e-6 m^4 each)."""

    nodes: int = 128
    length_m: float = 10.0
    mass_per_length_kg_m: float = 2 * 60.2
    bending_stiffness_n_m2: float = 2 * 210e9 * 5.12e-6
    # Flexible heel: the blades are machined thin near the heel so that little elastic
    # force opposes throwing them (and holding them at either end).
    heel_flex_length_m: float = 2.0
    heel_flex_factor: float = 0.08
    structural_damping_s: float = 1.0e-3  # stiffness-proportional (Rayleigh) damping
    drive_mass_kg: float = 30.0  # adjuster, stretcher bar and locking parts at the toe
    # Slide chairs with rollers: a little Coulomb friction, mostly viscous rolling losses.
    chair_friction_coefficient: float = 0.02
    chair_friction_speed_m_s: float = 0.001
    chair_viscous_n_s_m: float = 300.0
    neutral_m: float = 1.10  # unstressed position of the drive point
    left_stock_m: float = 1.00
    right_stock_m: float = 1.20
    contact_region_fraction: float = 0.35  # toe share of the beam that meets the stock rail
    stock_stiffness_n_m: float = 1.0e6  # per contacting node
    stock_damping_s_m: float = 5.0


class RailBeam:
    """Mass, stiffness and contact geometry of the discretised beam (numbers only)."""

    def __init__(self, params: RailParams = RailParams()):
        self.params = params
        n = params.nodes
        self.spacing_m = params.length_m / n
        self.arc_m = self.spacing_m * np.arange(1, n + 1)
        self.masses_kg = np.full(n, params.mass_per_length_kg_m * self.spacing_m)
        self.masses_kg[-1] = 0.5 * params.mass_per_length_kg_m * self.spacing_m + params.drive_mass_kg
        self.contact_nodes = np.flatnonzero(self.arc_m >= (1.0 - params.contact_region_fraction) * params.length_m)

    @cached_property
    def _heel_joints(self) -> np.ndarray:
        """1 at the joints of the machined heel, 0 elsewhere (joint j sits at node j, joint 0 at the clamped heel)."""
        return (self.spacing_m * np.arange(self.params.nodes) < self.params.heel_flex_length_m).astype(float)

    def _stiffness_from_joints(self, joint_ei: np.ndarray) -> sp.csc_matrix:
        """K = ds * D^T diag(EI) D, D the curvature at every joint (heel clamped, toe free)."""
        n, ds = self.params.nodes, self.spacing_m
        rows, cols, vals = [], [], []
        for joint in range(n):  # joint j sits at node j; node 0 is the clamped heel
            for node, weight in ((joint - 1, 1.0), (joint, -2.0), (joint + 1, 1.0)):
                if 1 <= node <= n:
                    rows.append(joint)
                    cols.append(node - 1)
                    vals.append(weight / ds**2)
        curvature = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
        stiffness = sp.csc_matrix(ds * (curvature.T @ sp.diags(joint_ei) @ curvature))
        stiffness.sort_indices()
        return stiffness

    @cached_property
    def stiffness_parts(self) -> tuple[sp.csc_matrix, sp.csc_matrix]:
        """K = K_rail + heel_flex_factor * K_heel: the full-section joints, and the heel's at factor 1."""
        ei = self.params.bending_stiffness_n_m2
        return (self._stiffness_from_joints((1.0 - self._heel_joints) * ei),
                self._stiffness_from_joints(self._heel_joints * ei))

    def stiffness(self, heel_flex_factor: float | None = None) -> sp.csc_matrix:
        """The stiffness matrix for a heel factor (default: the params')."""
        rail, heel = self.stiffness_parts
        factor = self.params.heel_flex_factor if heel_flex_factor is None else heel_flex_factor
        return sp.csc_matrix(rail + factor * heel)

    @cached_property
    def _stiffness_dm_parts(self) -> tuple[ca.DM, ca.DM]:
        def dm(k: sp.csc_matrix) -> ca.DM:
            k = sp.csc_matrix(k)
            k.sort_indices()
            return ca.DM(ca.Sparsity(k.shape[0], k.shape[1], k.indptr.tolist(), k.indices.tolist()), k.data)
        return tuple(dm(k) for k in self.stiffness_parts)

    def stiffness_times(self, u, heel_flex_factor):
        """K u as a CasADi expression; the heel factor may be symbolic."""
        rail, heel = self._stiffness_dm_parts
        return ca.mtimes(rail, u) + heel_flex_factor * ca.mtimes(heel, u)

    def _unit_load_deflection(self, heel_flex_factor: float | None = None) -> np.ndarray:
        """Static deflection of every node under 1 N at the drive point: K u = ds D^T diag(EI) D u = f solved as the
        two triangular systems it is (_stiffness_from_joints), D^T m = f / ds for the joints' moments (statics, from
        the toe) and D u = m / EI for the nodes (the curvature integrated twice, from the heel).

        Scalar recurrences, the same numbers on every processor: a sparse LU of K goes through the BLAS kernel
        OpenBLAS picks for the processor, and its last digits (4e-9 of the tip stiffness here) moved every plant
        run, training's data among them, by its integrator's tolerance."""
        n, ds = self.params.nodes, self.spacing_m
        factor = self.params.heel_flex_factor if heel_flex_factor is None else heel_flex_factor
        ei = [self.params.bending_stiffness_n_m2 * (factor if heel else 1.0) for heel in self._heel_joints]
        moment = [0.0] * (n + 2)  # D^T is upper triangular: rows from the toe, D's entries (1, -2, 1) / ds^2
        for joint in range(n - 1, -1, -1):
            load = 1.0 / ds if joint == n - 1 else 0.0
            moment[joint] = ds * ds * load + 2.0 * moment[joint + 1] - moment[joint + 2]
        u = [0.0] * (n + 2)  # u[k + 2] is node k + 1; the two before it are the clamped heel's
        for joint in range(n):
            u[joint + 2] = ds * ds * (moment[joint] / ei[joint]) + 2.0 * u[joint + 1] - u[joint]
        return np.array(u[2:])

    @cached_property
    def shape(self) -> np.ndarray:
        """Static deflection under a load at the drive point, 1 at the drive point (the params' heel).
        It fixes the geometry: where the stock rails are and how bearing friction is spread."""
        deflection = self._unit_load_deflection()
        return deflection / deflection[-1]

    @property
    def tip_stiffness_n_m(self) -> float:
        """Static stiffness seen at the drive point (3EI/L^3 for a uniform continuous beam)."""
        return 1.0 / self._unit_load_deflection()[-1]

    def rest_shape(self, drive_position_m: float, heel_flex_factor: float | None = None) -> np.ndarray:
        """Node displacements of the static shape with the drive point at `drive_position_m`."""
        deflection = self._unit_load_deflection(heel_flex_factor)
        return (drive_position_m - self.params.neutral_m) * deflection / deflection[-1]

    def _stock_penetrations(self, u):
        """Penetration into the left and right stock rails of every toe node."""
        p = self.params
        idx = [int(i) for i in self.contact_nodes]
        shape = ca.DM(self.shape[self.contact_nodes])
        left = (p.left_stock_m - p.neutral_m) * shape - u[idx]
        right = u[idx] - (p.right_stock_m - p.neutral_m) * shape
        return idx, left, right

    def internal_forces(self, u, v, heel_flex_factor=None, chair_friction_coefficient=None, chair_viscous_n_s_m=None):
        """Bending, structural damping, slide-chair friction and stock-rail contact forces on every node.

        The heel factor and the chairs' friction default to the params' and may be symbolic (a switch's own)."""
        p = self.params
        heel = p.heel_flex_factor if heel_flex_factor is None else heel_flex_factor
        mu = p.chair_friction_coefficient if chair_friction_coefficient is None else chair_friction_coefficient
        viscous = p.chair_viscous_n_s_m if chair_viscous_n_s_m is None else chair_viscous_n_s_m
        forces = -self.stiffness_times(u + p.structural_damping_s * v, heel)
        normal_n = ca.DM(self.masses_kg * GRAVITY_M_S2)
        forces -= mu * normal_n * ca.tanh(v / p.chair_friction_speed_m_s)
        forces -= viscous * v
        idx, left, right = self._stock_penetrations(u)
        rate = v[idx]
        contact = unilateral_contact(left, -rate, p.stock_stiffness_n_m, p.stock_damping_s_m) \
            - unilateral_contact(right, rate, p.stock_stiffness_n_m, p.stock_damping_s_m)
        forces[idx] += contact
        return forces

    def energy(self, u, v, heel_flex_factor=None):
        """Kinetic + bending + stock-contact elastic energy (J)."""
        heel = self.params.heel_flex_factor if heel_flex_factor is None else heel_flex_factor
        kinetic = 0.5 * ca.sum1(ca.DM(self.masses_kg) * v**2)
        bending = 0.5 * ca.dot(u, self.stiffness_times(u, heel))
        _, left, right = self._stock_penetrations(u)
        contact = 0.5 * self.params.stock_stiffness_n_m * ca.sum1(ca.fmax(left, 0) ** 2 + ca.fmax(right, 0) ** 2)
        return kinetic + bending + contact
