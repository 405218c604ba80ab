"""Per-switch build and environment parameters of the simulated plant: the names a user may set
(`--plant NAME=VALUE`, scenario files, the truth channel), their units, nominal values and ranges.

Names are `group.field` of the plant's parameter groups (motor, drive, rail). The nominal values are the
plant's own defaults; a test holds the two to account.
"""
from dataclasses import dataclass

from railswitch.schemas.ranges import Ranged


@dataclass(frozen=True)
class PlantParameter(Ranged):
    """One settable plant parameter: its SI unit, nominal value and range, and what it means."""

    meaning: str


PLANT_PARAMETERS: dict[str, PlantParameter] = {
    p.name: p
    for p in (
        PlantParameter("motor.resistance_ohm", "Ω", 9.5, 6.0, 24.0,
                       "winding resistance at the winding's temperature (copper: +0.393 % per kelvin), with its cable;"
                       " up to twice the hottest healthy winding's: a cable or winding fault"),
        PlantParameter("motor.supply_v", "V", 110.0, 40.0, 140.0,
                       "supply voltage at the point machine (down to a sag that saturates the drive)"),
        PlantParameter("motor.coulomb_friction_nm", "N·m", 0.12, 0.04, 0.40,
                       "Coulomb friction of motor and gearbox, at the motor shaft"),
        PlantParameter("motor.torque_constant_nm_a", "N·m/A", 0.2, 0.12, 0.24,
                       "torque constant (and back-EMF constant, in SI units the same); down to weakened magnets"),
        PlantParameter("drive.binding_torque_nm", "N·m", 0.0, 0.0, 1.0,
                       "extra friction of a gearbox that binds at one point of the stroke, at the motor shaft, at its"
                       " height (a bell a tenth of the stroke wide at half height); 0 on a sound gearbox"),
        PlantParameter("drive.binding_position", "1", 0.5, 0.05, 0.95,
                       "where the gearbox binds, as the share of the rod's stroke from its left dead centre"),
        PlantParameter("rail.chair_friction_coefficient", "1", 0.02, 0.002, 0.15,
                       "slide-chair Coulomb friction coefficient: lubrication, dryness, ice"),
        PlantParameter("rail.chair_viscous_n_s_m", "N·s/m", 300.0, 100.0, 900.0, "rolling losses of each slide chair"),
        PlantParameter("rail.heel_flex_factor", "1", 0.08, 0.04, 0.16,
                       "bending stiffness of the machined heel relative to the full rail section"),
    )
}


def check_plant_value(name: str, value: float | str) -> float:
    """Return value as a float if name is a plant parameter and the value finite and in range; else ValueError."""
    if name not in PLANT_PARAMETERS:
        raise ValueError(f"unknown plant parameter {name!r}; accepted: {', '.join(PLANT_PARAMETERS)}")
    return PLANT_PARAMETERS[name].check(value)


def check_plant_values(values: dict[str, float]) -> dict[str, float]:
    return {name: check_plant_value(name, value) for name, value in values.items()}
