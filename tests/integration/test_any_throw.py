"""One compiled estimator for throws of any length and rate, and units that log the current alone (issue 17)."""
from dataclasses import replace

import pytest

from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.services.core.switch_messages import SimulatedThrows

NOISE = 0.01
BOLT = 0.08


def commissioned_then_bolt(diagnoser, plant, switch_id, *, current_only=False, **machine):
    """A switch commissioned on its healthy throws, then two throws with a loose left bolt: every diagnosis."""
    sim = SwitchSimulation(plant, noise_rel=NOISE, seed=11, **machine)
    source = SimulatedThrows(switch_id, sim)

    def diagnose():
        throw = source.next()
        if current_only:
            throw = replace(throw, signals=throw.signals.only(("current_a",)))
        return diagnoser.diagnose(throw).diagnosis

    out = [diagnose() for _ in range(2 * COMMISSIONING_THROWS)]
    sim.set_faults({"left_bolt_offset": BOLT})
    return out + [diagnose() for _ in range(2)]


@pytest.mark.parametrize("machine", [
    {"rate_hz": 10.0}, {"rate_hz": 200.0}, {"rate_hz": 50.0, "end_s": 6.6}, {"rate_hz": 50.0, "end_s": 9.0},
], ids=["10 Hz", "200 Hz", "ends before its reference", "ends after it"])
def test_throws_of_other_rates_and_lengths_are_diagnosed_without_compiling_again(diagnoser, plant, machine):
    diagnoses = commissioned_then_bolt(diagnoser, plant, f"machine{len(diagnoser.switches)}", **machine)
    assert [d.decision for d in diagnoses[:-2]] == ["nominal"] * (len(diagnoses) - 2)
    assert diagnoses[-1].decision == "left_bolt"
    assert diagnoses[-1].estimate.params["left_bolt_offset"] == pytest.approx(BOLT, rel=0.1)
    assert diagnoser.compiles == 1


OTHER_TYPES = [{"rate_hz": 25.0, "stroke_s": 4.4}, {"rate_hz": 50.0, "stroke_s": 8.4},
               {"rate_hz": 50.0, "stroke_s": 2.4, "end_s": 3.0}, {"rate_hz": 20.0, "stroke_s": 12.4, "end_s": 15.0}]
OTHER_IDS = ["5 s at 25 Hz", "9 s", "3 s", "15 s"]


@pytest.mark.parametrize("machine", OTHER_TYPES, ids=OTHER_IDS)
def test_point_machines_of_other_stroke_times_are_diagnosed_and_their_faults_found(diagnoser, plant, machine):
    """Throws of 3 to 15 s from machine types whose reference profiles stroke faster or slower than the model's
    (whose rails were trained on its own 6.4 s stroke): every throw fitted, the loose bolt found within 20 % by the
    throw that drives it."""
    diagnoses = commissioned_then_bolt(diagnoser, plant, f"machine{len(diagnoser.switches)}", **machine)
    assert "unknown" not in [d.decision for d in diagnoses]
    assert diagnoses[-1].decision == "left_bolt"
    bolt = next(h for h in diagnoses[-2].hypotheses if h.mode == "left_bolt")
    assert bolt.params["left_bolt_offset"] == pytest.approx(BOLT, rel=0.2)
    assert diagnoser.compiles == 1


def test_healthy_throws_of_a_slower_machine_type_stay_nominal(diagnoser, plant):
    """A machine stroking 30 % slower than the model's reads a steady -3 mm on both bolts (model error): within a
    bolt's setting tolerance, so its throws are healthy, it commissions, and the later bolt is found."""
    diagnoses = commissioned_then_bolt(diagnoser, plant, f"machine{len(diagnoser.switches)}", **OTHER_TYPES[1])
    assert [d.decision for d in diagnoses[:-2]] == ["nominal"] * (len(diagnoses) - 2)
    assert diagnoses[-1].decision == "left_bolt"
    assert diagnoses[-1].estimate.params["left_bolt_offset"] == pytest.approx(BOLT, rel=0.1)


def test_a_throw_cut_short_while_moving_is_unknown(diagnoser, plant):
    sim = SwitchSimulation(plant, noise_rel=NOISE, seed=3, end_s=5.0)
    diagnosis = diagnoser.diagnose(SimulatedThrows("short", sim).next()).diagnosis
    assert diagnosis.decision == "unknown" and "still asked to turn" in diagnosis.reason


def test_a_current_only_unit_is_diagnosed_from_the_current_and_says_so_with_wider_intervals(diagnoser, plant):
    full = commissioned_then_bolt(diagnoser, plant, "full")
    current = commissioned_then_bolt(diagnoser, plant, "current", current_only=True)
    assert full[-1].signals == ["current_a", "angle_rad", "velocity_rad_s"]
    assert current[-1].signals == ["current_a"]
    assert current[-1].decision == "left_bolt"
    assert current[-1].estimate.params["left_bolt_offset"] == pytest.approx(BOLT, rel=0.15)
    full_bolt = next(h for h in full[-2].hypotheses if h.mode == "left_bolt")  # the throw that drives the bolt
    current_bolt = next(h for h in current[-2].hypotheses if h.mode == "left_bolt")
    assert current_bolt.std["left_bolt_offset"] > full_bolt.std["left_bolt_offset"]
