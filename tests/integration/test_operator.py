"""What a maintenance team works with (issue 40): anomalies no fault names, alarms latched until acknowledged, and
maintenance that teaches nothing. Switches are drawn from the population (unlike the model) and thrown through the
plant with 1 % noise; the diagnoser is the real one, its state kept in real files."""
import copy
import re

import pytest

from railswitch.models.health.alarms import AlarmBook
from railswitch.models.plant.population import draw_switch
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.services.adapters.baseline_store import BaselineStore
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.switch_messages import SimulatedThrows

COMMISSIONED = 2 * COMMISSIONING_THROWS


class Switch:
    def __init__(self, diagnoser: Diagnoser, plant, switch_id: str, seed: int):
        self.own = draw_switch(seed).plant
        self.diagnoser, self.switch_id = diagnoser, switch_id
        self.sim = SwitchSimulation(plant, own=self.own, noise_rel=0.01, seed=seed)
        self.source = SimulatedThrows(switch_id, self.sim)
        diagnoser.forget(switch_id)

    def throws(self, count: int) -> list:
        return [self.diagnoser.diagnose(self.source.next()) for _ in range(count)]


@pytest.mark.parametrize("factor", [1.37, 1.62])
def test_a_winding_resistance_step_reads_anomaly_naming_the_resistance_and_alarms_once(diagnoser, plant, factor):
    switch = Switch(diagnoser, plant, "winding", seed=811)
    assert all(not t.diagnosis.anomalies for t in switch.throws(COMMISSIONED + 1))
    switch.sim.set_own({**switch.own, "motor.resistance_ohm": switch.own["motor.resistance_ohm"] * factor})
    after = switch.throws(4)
    for item in after:
        d = item.diagnosis
        assert "anomaly" in d.faults and d.tag == "anomaly", (d.faults, d.reason)
        assert [a.quantity for a in d.anomalies] == ["motor.resistance_ohm"]
        assert "winding resistance" in d.anomalies[0].reason and "motor.resistance_ohm" in d.anomalies[0].suspects
    changes = [(a.alarm, a.change) for item in after for a in item.alarms if a.cause == "anomaly"]
    assert changes == [("anomaly:motor.resistance_ohm", "raised")]  # the repeats raise nothing


def test_a_maintenance_throw_with_a_bolt_fault_raises_no_alarm_and_leaves_the_baseline_as_it_was(diagnoser, plant):
    switch = Switch(diagnoser, plant, "maintained", seed=812)
    switch.throws(COMMISSIONED + 2)
    before = copy.deepcopy(diagnoser.switches["maintained"].state())
    assert diagnoser.set_maintenance("maintained", True, 0, note="adjusting the left bolt")
    assert not diagnoser.set_maintenance("maintained", True, 0)  # already in maintenance: nothing changes
    switch.sim.set_faults({"left_bolt_offset": 0.047})
    during = switch.throws(4)
    assert all(t.diagnosis.tag == "maintenance" and not t.alarms for t in during)
    assert any("left_bolt" in t.diagnosis.faults for t in during)  # diagnosed all the same
    assert diagnoser.switches["maintained"].state() == before  # no baseline, trend, feature or fault learnt
    switch.sim.set_faults({})
    assert diagnoser.set_maintenance("maintained", False, 0)
    after = switch.throws(4)
    assert all(t.diagnosis.faults == [] and t.diagnosis.tag == "normal" and not t.alarms for t in after)


def test_maintenance_ending_with_recommissioning_learns_the_baseline_again(diagnoser, plant):
    switch = Switch(diagnoser, plant, "recommissioned", seed=813)
    switch.throws(COMMISSIONED + 1)
    diagnoser.set_maintenance("recommissioned", True, 0)
    switch.throws(2)
    diagnoser.set_maintenance("recommissioned", False, 0, recommission=True)
    assert switch.throws(1)[0].diagnosis.commissioning.state == "provisional"


def test_a_latched_alarm_survives_a_diagnoser_restart_and_clears_only_on_acknowledgement(plant, tmp_path):
    store = BaselineStore("poly", tmp_path)
    first = Diagnoser("poly", on_state=store.save, stored_state=store.load)
    switch = Switch(first, plant, "latched", seed=814)
    switch.throws(COMMISSIONED + 1)
    switch.sim.set_faults({"right_bolt_offset": 0.052})
    raised = [(a.change, a.active) for t in switch.throws(4) for a in t.alarms if a.alarm == "right_bolt"]
    assert raised[0] == ("raised", True) and {change for change, _ in raised} <= {"raised", "escalated"}
    switch.sim.set_faults({})  # repaired: the alarm's cause is gone, the alarm stays until acknowledged
    cleared = [a for t in switch.throws(4) for a in t.alarms if a.alarm == "right_bolt"]
    assert [(a.change, a.active, a.acknowledged) for a in cleared] == [("cleared", False, False)]

    restarted = Diagnoser("poly", on_state=store.save, stored_state=store.load)  # a new process, the same files
    switch.diagnoser = restarted
    assert all(a.alarm != "right_bolt" for t in switch.throws(2) for a in t.alarms)
    assert "right_bolt" in [a.alarm for a in restarted.books["latched"].latched()]  # still latched
    assert restarted.acknowledge("latched", 5, alarm="left_bolt") == []  # not one of its alarms: nothing changes
    acknowledged = restarted.acknowledge("latched", 5, alarm="right_bolt", note="bolt reset")
    assert [(a.alarm, a.change, a.note) for a in acknowledged] == [("right_bolt", "acknowledged", "bolt reset")]
    assert acknowledged[0].sequence > cleared[0].sequence
    assert "right_bolt" not in restarted.books["latched"].alarms  # acknowledged and cleared: closed
    assert "right_bolt" not in AlarmBook.from_dict(store.load("latched")["alarms"]).alarms  # kept closed on disk


def test_weakening_magnets_read_as_an_anomaly_that_names_them_not_as_a_silent_bearing(diagnoser, plant):
    """A torque constant 14 % down once read missing_bearing on every throw: a team sent to grease chairs."""
    switch = Switch(diagnoser, plant, "magnets", seed=815)
    switch.throws(COMMISSIONED + 1)
    switch.sim.set_own({**switch.own, "motor.torque_constant_nm_a": switch.own["motor.torque_constant_nm_a"] * 0.86})
    after = [t.diagnosis for t in switch.throws(5)]
    assert all("anomaly" in d.faults for d in after), [d.named() for d in after]
    last = after[-1].anomalies[0]
    assert "motor.torque_constant_nm_a" in last.suspects and "magnets" in last.reason
    if set(after[-1].faults) & {"missing_bearing", "drive_friction"}:  # read as friction too: the magnets first
        assert last.suspects[0] == "motor.torque_constant_nm_a", last.reason


@pytest.mark.parametrize("torque, position", [(0.46, 0.33), (0.37, 0.71)])
def test_a_gearbox_binding_at_one_point_reads_anomaly_naming_it_whatever_fault_the_fit_finds(diagnoser, plant,
                                                                                             torque, position):
    """The reduced models read a binding gearbox as an obstacle, a bearing or drive friction; the stroke's current
    profile places its load at one motor angle both ways, where a blade obstacle's lies the free play apart."""
    switch = Switch(diagnoser, plant, "binding", seed=823)
    switch.throws(COMMISSIONED + 1)
    switch.sim.set_own({**switch.own, "drive.binding_torque_nm": torque, "drive.binding_position": position})
    after = [t.diagnosis for t in switch.throws(4)]
    for d in after[1:]:  # from the first throw of the other direction on
        binding = [a for a in d.anomalies if "drive.binding_torque_nm" in a.suspects]
        assert binding and "anomaly" in d.faults, (d.named(), [a.reason for a in d.anomalies])
        at = re.search(r"at (\d+) % of the stroke", binding[0].reason)
        assert at and abs(int(at.group(1)) - 100 * position) <= 5, binding[0].reason


def test_a_blade_obstacle_is_not_read_as_a_binding_gearbox(diagnoser, plant):
    switch = Switch(diagnoser, plant, "obstacle", seed=824)
    switch.throws(COMMISSIONED + 1)
    switch.sim.set_faults({"obstacle_friction": 60_000.0, "obstacle_position": 1.09})
    after = [t.diagnosis for t in switch.throws(4)]
    assert "obstacle" in after[-1].faults, after[-1].named()
    assert not [a for d in after for a in d.anomalies if "drive.binding_torque_nm" in a.suspects]
