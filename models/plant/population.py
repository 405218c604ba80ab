"""The population of switches: how a real switch's build and weather differ from the nominal plant.

`draw_switch(seed)` gives one switch (plant variables, schemas/plant.py); `credible_range(name)` says
what the population lets a parameter be, for a diagnosis that must not call a healthy switch faulty.
Where each spread comes from:

- Winding resistance: copper's temperature coefficient, +0.393 % per kelvin from 20 °C (IEC 60228),
  at the winding's temperature, which follows the ambient one (-25 … +45 °C, uniform: a year of weather
  over a national network) plus the few kelvin a point machine's short duty warms it (uniform 0 … 10 K);
  times a unit-to-unit tolerance of the winding, normal with 3 % standard deviation (motor makers quote
  a tolerance of a few per cent on terminal resistance).
- Supply at the point machine: 110 V, uniform ±10 % (a typical tolerance of a signalling supply, with
  the voltage drop of a long cable in the lower half).
- Torque constant: unit-to-unit, normal with 2 % standard deviation (magnet strength).
- Coulomb friction of motor and gearbox: 0.12 N·m times a log-normal unit-to-unit factor (25 %: grease
  fill and gear meshing differ from unit to unit), times a wear factor uniform in 1 … 1.25 (age since
  overhaul). Its growth after commissioning is the fault `drive_friction`, not the population.
- Slide-chair Coulomb coefficient: 0.02 (rollers) times a log-normal lubrication factor (30 %: freshly
  greased to dry chairs, twice as dry as nominal some two standard deviations out), times 1 … 1.3 below
  0 °C (frost on the chairs; ice that blocks a switch is a fault, and what point heaters are for).
- Rolling losses per chair: 300 N·s/m times a log-normal factor (5 %): what one chair's rollers lose
  differs more, but a switch's losses are the sum over its chairs, whose independent differences average
  out; what is left is common to the switch (roller type, temperature of the grease).
- Heel stiffness: 0.08 of the full section, normal with 5 % standard deviation (machining tolerance of
  the heel's thinned section).

These are engineering assumptions where no figure is cited; they are the population the fleet
benchmark draws and the diagnosis is judged against. `credible_range` spans all but one switch in
ten thousand on each side (the 0.01 % and 99.99 % quantiles of 20 000 draws): the diagnosis takes it
as hard limits, where its priors already say how unlikely a value is, so it must not rule out the
healthy switches of a national fleet (with the 0.5 % and 99.5 % quantiles, one switch in a few dozen
had some part outside them, never commissioned and stayed a provisional fault).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from railswitch.schemas.plant import PLANT_PARAMETERS

COPPER_PER_K = 0.00393
REFERENCE_C = 20.0
NOMINAL = {name: p.nominal for name, p in PLANT_PARAMETERS.items()}
CREDIBLE_TAIL = 1e-4  # the share of the population beyond each end of a credible range


@dataclass(frozen=True)
class DrawnSwitch:
    """One switch of the population: its plant variables and the weather and wear behind them."""

    seed: int
    plant: dict[str, float]
    ambient_c: float
    winding_c: float
    lubrication: float  # chair friction factor of the lubrication state (1: as designed)


def draw_switch(seed: int) -> DrawnSwitch:
    """A switch drawn from the population, the same for the same seed."""
    rng = np.random.default_rng([seed, 0x5717C4])
    ambient = rng.uniform(-25.0, 45.0)
    winding = ambient + rng.uniform(0.0, 10.0)
    resistance = NOMINAL["motor.resistance_ohm"] * rng.normal(1.0, 0.03) * (1 + COPPER_PER_K * (winding - REFERENCE_C))
    lubrication = float(np.exp(rng.normal(0.0, 0.3)))
    frost = rng.uniform(1.0, 1.3) if ambient < 0.0 else 1.0
    plant = {
        "motor.resistance_ohm": resistance,
        "motor.supply_v": NOMINAL["motor.supply_v"] * rng.uniform(0.9, 1.1),
        "motor.torque_constant_nm_a": NOMINAL["motor.torque_constant_nm_a"] * rng.normal(1.0, 0.02),
        "motor.coulomb_friction_nm": NOMINAL["motor.coulomb_friction_nm"] * np.exp(rng.normal(0.0, 0.25))
                                     * rng.uniform(1.0, 1.25),
        "rail.chair_friction_coefficient": NOMINAL["rail.chair_friction_coefficient"] * lubrication * frost,
        "rail.chair_viscous_n_s_m": NOMINAL["rail.chair_viscous_n_s_m"] * np.exp(rng.normal(0.0, 0.05)),
        "rail.heel_flex_factor": NOMINAL["rail.heel_flex_factor"] * rng.normal(1.0, 0.05),
        # a sound gearbox binds nowhere (drawn last, so the draws above stay those of every earlier release)
        "drive.binding_torque_nm": NOMINAL["drive.binding_torque_nm"],
        "drive.binding_position": NOMINAL["drive.binding_position"],
    }
    # each within its schema's limits (min and max of floats: np.clip on a scalar was half of a draw's time, and
    # the population's statistics draw 20 000 switches when a diagnoser starts)
    plant = {name: min(max(float(value), PLANT_PARAMETERS[name].low), PLANT_PARAMETERS[name].high)
             for name, value in plant.items()}
    return DrawnSwitch(seed, plant, float(ambient), float(winding), lubrication)


@lru_cache(maxsize=1)
def _draws() -> dict[str, np.ndarray]:
    draws = [draw_switch(seed).plant for seed in range(20_000)]
    return {name: np.array([d[name] for d in draws]) for name in PLANT_PARAMETERS}


def credible_range(name: str) -> tuple[float, float]:
    """What the population lets a plant variable be: its CREDIBLE_TAIL and 1 - CREDIBLE_TAIL quantiles."""
    values = _draws()[name]
    return float(np.quantile(values, CREDIBLE_TAIL)), float(np.quantile(values, 1.0 - CREDIBLE_TAIL))


def spread(name: str, log: bool = False) -> tuple[float, float]:
    """Mean and standard deviation of a plant variable (or of its logarithm) over the population."""
    values = np.log(_draws()[name]) if log else _draws()[name]
    return float(values.mean()), float(values.std())


def resistance_at(temperature_c: float, resistance_20c_ohm: float = NOMINAL["motor.resistance_ohm"]) -> float:
    """Winding resistance at a temperature (copper)."""
    return resistance_20c_ohm * (1 + COPPER_PER_K * (temperature_c - REFERENCE_C))
