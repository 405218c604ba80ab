"""Switches that differ: the plant's own parameters, the population, scenario files that set and change them."""
import pytest

from railswitch.models.plant.high_fidelity import PlantParams, nominal_values
from railswitch.models.plant.population import credible_range, draw_switch
from railswitch.schemas.plant import PLANT_PARAMETERS, check_plant_value
from railswitch.schemas.scenario import Scenario, SwitchPlan


def test_the_contract_table_holds_the_plant_own_nominal_values():
    assert nominal_values(PlantParams()) == {name: p.nominal for name, p in PLANT_PARAMETERS.items()}


def test_a_drawn_switch_is_the_same_for_the_same_seed_and_inside_every_range():
    assert draw_switch(17) == draw_switch(17)
    assert draw_switch(17).plant != draw_switch(18).plant
    for seed in range(200):
        for name, value in draw_switch(seed).plant.items():
            assert PLANT_PARAMETERS[name].low <= value <= PLANT_PARAMETERS[name].high


def test_the_population_is_wider_than_the_examples_a_healthy_switch_must_survive():
    assert credible_range("motor.supply_v")[0] < 100.0 < 120.0 < credible_range("motor.supply_v")[1]
    assert credible_range("rail.chair_friction_coefficient")[1] > 0.04  # chairs twice as dry
    assert credible_range("motor.coulomb_friction_nm")[1] > 0.18  # a gearbox with 50 % more friction


@pytest.mark.parametrize("name, value, words", [
    ("motor.supply_v", "300", "outside the accepted range 40 … 140 V"),
    ("motor.bogus", "1", "unknown plant parameter 'motor.bogus'"),
    ("rail.heel_flex_factor", "nan", "not a finite number"),
])
def test_a_bad_plant_value_is_one_line_naming_it_and_the_range(name, value, words):
    with pytest.raises(ValueError, match=words):
        check_plant_value(name, value)


def test_a_scenario_schedules_a_cold_night_and_chairs_drying_out():
    plan = SwitchPlan.model_validate({
        "id": "sw1", "throws": 6, "vary": 17, "plant": {"motor.supply_v": 99.0},
        "changes": [{"throw": 1, "set": {"motor.resistance_ohm": 8.6}},
                    {"throw": 2, "until": 4, "add": {"rail.chair_friction_coefficient": 0.01}}]})
    schedule = plan.schedule(base={"rail.chair_friction_coefficient": 0.02})
    assert schedule[0] == {"motor.supply_v": 99.0}
    assert schedule[1]["motor.resistance_ohm"] == 8.6
    assert schedule[4]["rail.chair_friction_coefficient"] == pytest.approx(0.05)


@pytest.mark.parametrize("switch, words", [
    ({"id": "a", "throws": 2, "plant": {"motor.bogus": 1.0}}, "unknown plant parameter"),
    ({"id": "a", "throws": 2, "vary": -3}, "greater than or equal to 0"),
    ({"id": "a", "throws": 2, "changes": [{"throw": 0, "set": {"motor.supply_v": 500.0}}]}, "outside the accepted range"),
])
def test_a_bad_scenario_switch_names_the_problem(switch, words):
    with pytest.raises(ValueError, match=words):
        Scenario.model_validate({"switches": [switch]})
