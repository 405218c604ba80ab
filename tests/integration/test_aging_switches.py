"""Switches as they age: several faults at once, repairs, standing conditions (issue 38).

Each switch is drawn from the population (unlike the model), thrown through the plant with 1 % noise and diagnosed
from its first throw; magnitudes lie between any grid points the diagnosis uses.
"""
import re

import pytest

from railswitch.models.plant.population import draw_switch
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.services.core.switch_messages import SimulatedThrows

COMMISSIONED = 2 * COMMISSIONING_THROWS
NOISE = 0.01


class Life:
    """One switch of the population thrown and diagnosed throw by throw."""

    def __init__(self, diagnoser, plant, switch_id: str, seed: int, own: dict[str, float] | None = None):
        drawn = draw_switch(seed).plant
        for name, factor in (own or {}).items():
            drawn[name] *= factor
        self.diagnoser, self.switch_id = diagnoser, switch_id
        self.sim = SwitchSimulation(plant, own=drawn, noise_rel=NOISE, seed=seed)
        self.source = SimulatedThrows(switch_id, self.sim)
        diagnoser.switches.pop(switch_id, None)

    def throws(self, count: int, faults: dict[str, float] | None = None) -> list:
        if faults is not None:
            self.sim.set_faults(faults)
        return [self.diagnoser.diagnose(self.source.next()).diagnosis for _ in range(count)]


@pytest.mark.parametrize("seed, first, second, onset", [
    # the old diagnosis named only the bolt once it came (the joint fit put the bearing at a fifth of its truth)
    (4242, ("missing_bearing", "bearing_friction", 3130.0), ("left_bolt", "left_bolt_offset", 0.0437), 2),
    # both bolts loose, every throw starts short of the stock rail, where the reduced model reads its own bolt loosely:
    # a 47 mm right bolt beside a 38 mm left one read 1.5 mm on such a throw and was repaired at once, and the left
    # bolt crept towards 60 mm
    (4248, ("left_bolt", "left_bolt_offset", 0.0415), ("right_bolt", "right_bolt_offset", 0.0493), 4),
], ids=["bearing then left bolt", "left bolt then right bolt"])
def test_a_second_fault_on_a_first_stays_two_faults_across_ten_more_throws(diagnoser, plant, seed, first, second,
                                                                            onset):
    life = Life(diagnoser, plant, "stacked", seed=seed)
    life.throws(COMMISSIONED + 2)
    alone = life.throws(6, {first[1]: first[2]})
    assert alone[-1].faults == [first[0]]
    both = life.throws(onset, {first[1]: first[2], second[1]: second[2]})
    later = life.throws(10)
    assert all(d.faults == sorted([first[0], second[0]]) for d in [both[-1], *later])
    assert later[-1].decision == second[0]  # the newest
    sizes = {e.mode: e for e in later[-1].estimates}
    # each fault's size within its reported 2 std (the std holds the model's error, so it is a promise)
    for mode, name, truth in (first, second):
        assert abs(sizes[mode].params[name] - truth) <= 2 * sizes[mode].std[name], (mode, sizes[mode])


@pytest.mark.parametrize("fault", [{"right_bolt_offset": 0.0362}, {"bearing_friction": 4410.0},
                                   {"drive_friction_nm": 0.094}], ids=["right bolt", "bearing", "drive friction"])
def test_a_repair_empties_faults_within_three_throws_and_its_level_returns(diagnoser, plant, fault):
    life = Life(diagnoser, plant, "repaired", seed=4243)
    life.throws(COMMISSIONED + 1)
    faulty = life.throws(6, fault)
    mode = faulty[-1].faults[0]
    assert faulty[-1].faults == [mode]
    after = life.throws(6, {})
    first_empty = next(k for k, d in enumerate(after) if not d.faults)
    assert first_empty < 3 and all(not d.faults for d in after[first_empty:])
    assert "repaired: " + mode in after[first_empty].reason


def test_an_accepted_standing_condition_followed_by_a_bolt_names_the_bolt(diagnoser, plant, caplog):
    """Rollers that lose 1.7 times the population's read as a missing bearing from the first throw: the switch never
    commissions as healthy, says so once, and once accepted it is commissioned at once and a left bolt is named."""
    life = Life(diagnoser, plant, "standing", seed=4244, own={"rail.chair_viscous_n_s_m": 1.7})
    early = life.throws(12)
    assert all(d.faults == ["missing_bearing"] for d in early[1:])
    assert all(d.commissioning.state == "provisional" for d in early)
    said = [d for d in early if d.commissioning.standing]
    words = re.fullmatch(r"cannot be commissioned as healthy: rolling losses ([0-9.]+)x, reads as missing_bearing",
                         said[0].commissioning.standing)
    # the switch's own rolling losses are the population's spread (5 %) times 1.7; a bearing's estimate is good to a few
    # per cent (ErrorModel), one decimal shown
    assert words and abs(float(words.group(1)) - 1.7) <= 0.15
    assert sum("cannot be commissioned as healthy" in r.message for r in caplog.records) == 1  # said once
    accepted = diagnoser.commission(life.switch_id, accept=True)
    assert set(accepted) == {"missing_bearing"}
    calm = life.throws(4)
    assert all(d.faults == [] and d.commissioning.state == "commissioned" for d in calm)
    assert calm[-1].commissioning.accepted["missing_bearing"]["bearing_friction"] == pytest.approx(
        accepted["missing_bearing"]["bearing_friction"])
    bolt = life.throws(4, {"left_bolt_offset": 0.0388})
    assert bolt[-1].faults == ["left_bolt"]
    more = life.throws(4, {"left_bolt_offset": 0.0388, "bearing_friction": 3300.0})  # more of the same is seen
    assert more[-1].faults == ["left_bolt", "missing_bearing"]


def test_a_standing_condition_not_accepted_still_names_a_later_bolt(diagnoser, plant):
    life = Life(diagnoser, plant, "standing2", seed=4245, own={"rail.chair_viscous_n_s_m": 1.45})
    life.throws(10)
    later = life.throws(6, {"right_bolt_offset": 0.051})
    assert later[-1].faults == ["missing_bearing", "right_bolt"]


def current_only(throw):
    """A throw as a unit that logs the motor current alone sends it."""
    from dataclasses import replace

    from railswitch.models.plant.signals import MotorSignals

    return replace(throw, signals=MotorSignals(current_a=throw.signals.current_a))


def test_current_only_throws_that_fit_a_bearing_about_as_well_do_not_commission_a_new_switch(diagnoser, plant):
    """Current alone, a 4200 N·s/m bearing on a new switch fits the healthy switch only with chairs twice as dry and
    rolling losses far up: the priors prefer healthy, the samples do not tell. Those throws teach no baseline."""
    life = Life(diagnoser, plant, "current", seed=4242)
    life.sim.set_faults({"bearing_friction": 4200.0})
    diagnoses = [diagnoser.diagnose(current_only(life.source.next())).diagnosis for _ in range(6)]
    assert all(d.commissioning.state == "provisional" and sum(d.commissioning.throws.values()) == 0
               for d in diagnoses)
    assert all("not counted: the throw fits missing_bearing" in d.reason for d in diagnoses)
    assert all(d.signals == ["current_a"] for d in diagnoses)


def test_an_accept_command_on_the_bus_takes_the_switch_as_it_is_and_a_restarted_diagnoser_keeps_it(plant, tmp_path):
    """`railswitch commission SW --accept` as the live diagnoser receives it: the standing condition is accepted, the
    acceptance is in the switch's stored state, and a diagnoser restarted from it goes on from the accepted baseline."""
    from railswitch.schemas import CommissionCommand, encode, key_expr
    from railswitch.services.adapters.baseline_store import BaselineStore
    from railswitch.services.adapters.zenoh_bus import Received
    from railswitch.services.wiring import Diagnoser
    from railswitch.services.core.live_diagnoser import LiveDiagnoser

    def diagnoser_with_store():
        store = BaselineStore("poly", tmp_path)
        return Diagnoser("poly", on_state=store.save, stored_state=store.load), store

    first, store = diagnoser_with_store()
    life = Life(first, plant, "installed", seed=4246, own={"rail.chair_viscous_n_s_m": 1.6})
    assert life.throws(10)[-1].faults == ["missing_bearing"]
    live = LiveDiagnoser(first, publishers=None, known=store.known)
    live.handle(Received(key_expr("installed", "commission"),
                         encode(CommissionCommand(switch_id="installed", accept=True)), 0.0))
    assert live.commissions == 1 and first.switches["installed"].baseline.complete
    again, _ = diagnoser_with_store()
    resumed = again.switch("installed")
    assert resumed.baseline.complete and set(resumed.baseline.accepted) == {"missing_bearing"}
    life.diagnoser = again
    after = life.throws(4)
    assert all(d.faults == [] and "missing_bearing" in d.commissioning.accepted for d in after)


def test_a_commissioned_switch_accepts_its_worn_gearbox_and_more_wear_is_a_fault_of_the_rest(diagnoser, plant):
    """Accepted on a commissioned switch, drive friction shifts the point machine's own friction: the switch reads
    healthy at once, and further wear reads as drive friction of what it adds beyond the accepted."""
    life = Life(diagnoser, plant, "gearbox", seed=4247)
    life.throws(COMMISSIONED + 1)
    worn = life.throws(4, {"drive_friction_nm": 0.052})
    assert worn[-1].faults == ["drive_friction"]
    accepted = diagnoser.commission(life.switch_id, accept=True)["drive_friction"]["drive_friction_nm"]
    assert abs(accepted - 0.052) < 0.01
    assert all(d.faults == [] and d.commissioning.state == "commissioned" for d in life.throws(4))
    wearing = life.throws(4, {"drive_friction_nm": 0.113})
    assert wearing[-1].faults == ["drive_friction"]
    more = wearing[-1].estimates[0]
    assert abs(more.params["drive_friction_nm"] - (0.113 - accepted)) <= 2 * more.std["drive_friction_nm"]
