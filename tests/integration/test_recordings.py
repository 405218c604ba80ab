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

import numpy as np
import pytest

from railswitch.models.motor import MotorParams
from railswitch.models.plant import Plant, PlantParams
from railswitch.models.switch import SwitchSimulation, nominal_peaks
from railswitch.services.adapters.compiled import MachineCode
from railswitch.services.adapters.recordings import RecordingReader
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
SIGNALS = ("current_a", "velocity_rad_s")
# RMS over a throw of the difference between two solutions that both meet the plant's relative
# tolerance, as a multiple of that tolerance times the signal's nominal peak (6.3 A, 139 rad/s).
# Doubling the solver's tolerances moves the current's RMS by up to 1.3e-4 of its peak (8e-4 A,
# the left bolt's second throw, where the blade starts from a gap); a 1 % change of the motor's
# resistance or Coulomb friction moves it by 7e-4 to 1e-3 of the peak. The bound sits between.
SOLVER_RMS_FACTOR = 200.0


def rms_bound(plant: Plant) -> dict[str, float]:
    """Largest RMS difference, per signal, that two correct runs of this plant may show."""
    peaks = nominal_peaks(plant)
    return {name: SOLVER_RMS_FACTOR * plant.tolerances["reltol"] * peaks[name] for name in SIGNALS}


def rms_differences(recorded_throws, plant: Plant, faults: dict) -> list[dict[str, float]]:
    """Per throw, the RMS difference of each signal between the recording and `plant` under `faults`."""
    sim = SwitchSimulation(plant, faults=faults)
    out = []
    for recorded in recorded_throws:
        fresh = sim.throw().samples.signals
        # recorded throws hold the start sample too
        out.append({name: float(np.sqrt(np.mean((getattr(recorded.signals, name)[1:] - getattr(fresh, name)) ** 2)))
                    for name in SIGNALS})
    return out


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
