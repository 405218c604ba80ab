"""The example recordings match the paper's scenarios and the current plant.

"Match" is judged at the accuracy the plant's solver promises, not bit for bit: the
recordings were made on one machine, and another processor or library build rounds
differently, which moves CVODES's adaptive steps and, around contacts, a sample of the
current by a few 1e-3 A. What stays put is the RMS difference over a throw: it is of
the order of the solver's own global error, measured below by changing its tolerance.
"""
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

from railswitch.models.plant.motor import MotorParams
from railswitch.models.plant.high_fidelity import Plant, PlantParams
from railswitch.services.adapters.compiled import MachineCode
from railswitch.services.adapters.recordings import RecordingReader
from railswitch.services.core.recording_check import SIGNALS, rms_bound, rms_differences
from railswitch.services.core.throw_cutter import cut_throws

RECORDINGS = Path(__file__).resolve().parents[2] / "recordings"
needs_compiler = pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None,
                                    reason="no C compiler: the plant runs through CasADi's virtual machine")
SCENARIOS = {
    "nominal.mcap": {},
    "left_bolt.mcap": {"left_bolt_offset": 0.05},
    "right_bolt.mcap": {"right_bolt_offset": 0.20},
    "missing_bearing.mcap": {"bearing_friction": 5000.0},
    "obstacle.mcap": {"obstacle_friction": 1e5, "obstacle_position": 1.1},
}
def recorded(name: str):
    path = RECORDINGS / name
    assert path.stat().st_size < 5_000_000
    reader = RecordingReader(path)
    throws = list(cut_throws(m.message for m in reader))
    assert reader.damage is None and not reader.skipped
    return throws


@pytest.mark.parametrize("name,faults", SCENARIOS.items())
def test_example_recording_is_the_current_plant_under_its_scenario(plant, name, faults):
    throws = recorded(name)
    assert [t.start.direction for t in throws] == ["left_to_right", "right_to_left"]
    assert all(t.complete and t.missing_samples == 0 for t in throws)
    truth = throws[0].truth.params()
    for parameter, value in faults.items():
        assert truth[parameter] == value
    bound = rms_bound(plant)
    for difference in rms_differences(throws, plant, faults):
        # regenerate with recordings/make.sh when the plant changed on purpose
        assert all(difference[s] < bound[s] for s in SIGNALS), (difference, bound)


def test_the_recording_check_tolerates_the_solver_at_twice_its_tolerance(plant):
    """The bound is not tighter than the solver's accuracy: a run at doubled tolerances passes."""
    looser = Plant(reltol=2 * plant.tolerances["reltol"], abstol=2 * plant.tolerances["abstol"])
    bound = rms_bound(plant)
    for name in ("left_bolt.mcap", "obstacle.mcap"):  # the scenarios with the most contact
        for difference in rms_differences(recorded(name), looser, SCENARIOS[name]):
            assert all(difference[s] < bound[s] for s in SIGNALS), (name, difference, bound)


@pytest.mark.parametrize("change", [{"resistance_ohm": 1.01}, {"coulomb_friction_nm": 1.01}])
def test_the_recording_check_sees_a_one_percent_change_of_the_motor(plant, change):
    """The bound is not looser than physics: a plant whose motor differs by 1 % fails it."""
    motor = MotorParams()
    changed = Plant(PlantParams(motor=replace(motor, **{k: f * getattr(motor, k) for k, f in change.items()})))
    bound = rms_bound(plant)
    for difference in rms_differences(recorded("nominal.mcap"), changed, {}):
        assert difference["current_a"] > bound["current_a"], (difference, bound)


@needs_compiler
def test_the_machine_code_plant_is_the_plant(plant, tmp_path):
    """The plant with its equations and Jacobian compiled (what the simulator and the benchmarks run) passes
    the same check on every example recording, and its library holds the Jacobian CVODES uses."""
    compiler = MachineCode(tmp_path)
    compiled = Plant(compiler=compiler)
    assert compiler.machine_code and compiled.describe()["machine_code"]
    assert compiled._dae_function.class_name() == compiled._dae_function.jacobian().class_name() == "External"
    bound = rms_bound(plant)
    for name, faults in SCENARIOS.items():
        for difference in rms_differences(recorded(name), compiled, faults):
            assert all(difference[s] < bound[s] for s in SIGNALS), (name, difference, bound)
