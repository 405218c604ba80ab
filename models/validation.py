"""Validation of the reduced switch models against the plant, and the search for inputs that break them.

- `validate`: the reduced switch driven by the references of plant runs it never saw
  in training, from the plant's start; mean squared errors of rail position, velocity
  and drive force per series (the paper's box plots).
- `divergence`: the reduced switch alone under stress pushes (wider than training)
  and throws with every fault at the ends of its range; a rollout diverges when it
  is not finite or leaves the physical travel by more than DIVERGED_BEYOND_M.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from railswitch.models.plant import Plant, Trajectory
from railswitch.models.reduced import ReducedSwitch
from railswitch.models.reference import DIRECTIONS, THROW_DURATION_S, Reference, throw_reference
from railswitch.models.training import random_push_run, stress_reference
from railswitch.schemas.faults import FAULT_PARAMETERS

DIVERGED_BEYOND_M = 0.03  # past a stock rail by more than this is no motion the switch can make
STRESS_SECONDS = 30.0
STRESS_FIRST_SEED = 100_000  # stress seeds never overlap training (1-3) or validation (1001-1025) seeds
# The hardest validation series: 1003 and 1023 diverged with poly before the hooks relaxed exactly.
QUICK_VALIDATION_SEEDS = (1003, 1011, 1023)


@dataclass(frozen=True)
class PlantSeries:
    """One plant run of random pushes: its reference, the plant's signals at the start and its trajectory."""

    seed: int
    reference: Reference
    start: dict[str, float]
    plant: Trajectory


def plant_series(plant: Plant, seeds, duration_s: float = 100.0) -> list[PlantSeries]:
    return [PlantSeries(seed, *random_push_run(plant, seed, duration_s)) for seed in seeds]


def validate(reduced: ReducedSwitch, series: list[PlantSeries]) -> dict[str, list[float]]:
    """Per series, the MSE of rail position, velocity and drive force against the plant."""
    mse: dict[str, list[float]] = {"position": [], "velocity": [], "force": []}
    for item in series:
        s0 = reduced.initial_state(item.start["rail_position_m"], item.start["angle_rad"])
        out = reduced.simulate(s0, item.reference, len(item.plant.t_s))
        for key, signal in (("position", "rail_position_m"), ("velocity", "rail_velocity_m_s"),
                            ("force", "drive_force_n")):
            error = out[signal] - item.plant[signal]
            mse[key].append(float(np.mean(error**2)) if np.all(np.isfinite(error)) else float("inf"))
    return mse


def excursion_m(rail_position_m: np.ndarray, reduced: ReducedSwitch) -> float:
    """How far the rail went past either stock rail (inf when not finite)."""
    if not np.all(np.isfinite(rail_position_m)):
        return float("inf")
    rail = reduced.params.plant.rail
    return float(max(0.0, np.max(rail.left_stock_m - rail_position_m), np.max(rail_position_m - rail.right_stock_m)))


def fault_extremes() -> list[dict[str, float]]:
    """Every fault parameter alone at each end of its range (obstacles at both ends and mid-travel),
    and all at once at their worst."""
    cases = []
    for name in ("left_bolt_offset", "right_bolt_offset", "bearing_friction"):
        p = FAULT_PARAMETERS[name]
        cases += [{name: p.low}, {name: p.high}]
    obstacle = FAULT_PARAMETERS["obstacle_position"]
    cases += [{"obstacle_friction": FAULT_PARAMETERS["obstacle_friction"].high, "obstacle_position": x}
              for x in (obstacle.low, obstacle.nominal, obstacle.high)]
    cases.append({name: p.high for name, p in FAULT_PARAMETERS.items() if name != "obstacle_position"}
                 | {"obstacle_position": obstacle.nominal})
    return cases


@dataclass(frozen=True)
class Divergence:
    """What a stress run found for one reduced switch (one representation, rate and substep count)."""

    series: int
    diverged_series: list[int]  # stress seeds
    max_excursion_m: float
    fault_throws: int
    diverged_fault_throws: list[str]


def divergence(reduced: ReducedSwitch, stress_series: int, first_seed: int = STRESS_FIRST_SEED) -> Divergence:
    """Roll the reduced switch over `stress_series` stress pushes and every fault extreme in both directions."""
    rate = reduced.rate_hz
    diverged, worst = [], 0.0
    for seed in range(first_seed, first_seed + stress_series):
        reference = stress_reference(np.random.default_rng(seed), STRESS_SECONDS, reduced.params.plant.drive.gear_ratio)
        out = reduced.simulate(reduced.initial_state(1.0, 0.0), reference, int(round(STRESS_SECONDS * rate)))
        excursion = excursion_m(out["rail_position_m"], reduced)
        worst = max(worst, excursion)
        if excursion > DIVERGED_BEYOND_M:
            diverged.append(seed)
    closed_right = reduced.initial_state(1.2, throw_reference("left_to_right").angle_rad())
    starts = {DIRECTIONS[0]: reduced.initial_state(1.0, 0.0), DIRECTIONS[1]: closed_right}
    bad_throws, cases = [], fault_extremes()
    for faults in cases:
        for direction, s0 in starts.items():
            out = reduced.simulate(s0, throw_reference(direction), int(round(THROW_DURATION_S * rate)), faults)
            excursion = excursion_m(out["rail_position_m"], reduced)
            worst = max(worst, excursion)
            if excursion > DIVERGED_BEYOND_M:
                bad_throws.append(f"{direction} {faults}")
    return Divergence(stress_series, diverged, worst, 2 * len(cases), bad_throws)


def quick_validation(reduced: ReducedSwitch, plant: Plant) -> dict:
    """Position RMSE on the hardest validation series: stored beside trained weights, so a change to the
    model code that changes what the weights do is caught (tests/test_reduced.py) and revalidated."""
    mse = validate(reduced, plant_series(plant, QUICK_VALIDATION_SEEDS))["position"]
    return {"seeds": list(QUICK_VALIDATION_SEEDS), "position_rmse_m": [float(np.sqrt(e)) for e in mse]}
