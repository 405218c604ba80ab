"""The example recordings match the paper's scenarios and the current plant."""
from pathlib import Path

import numpy as np
import pytest

from models.switch import SwitchSimulation
from services.mcap_io import RecordingReader
from services.throw_cutter import cut_throws

RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"
SCENARIOS = {
    "nominal.mcap": {},
    "left_bolt.mcap": {"left_bolt_offset": 0.05},
    "right_bolt.mcap": {"right_bolt_offset": 0.20},
    "missing_bearing.mcap": {"bearing_friction": 5000.0},
    "obstacle.mcap": {"obstacle_friction": 1e5, "obstacle_position": 1.1},
}


@pytest.mark.parametrize("name,faults", SCENARIOS.items())
def test_example_recording_is_the_current_plant_under_its_scenario(plant, name, faults):
    path = RECORDINGS / name
    assert path.stat().st_size < 5_000_000
    reader = RecordingReader(path)
    throws = list(cut_throws(m.message for m in reader))
    assert reader.damage is None and not reader.skipped
    assert [t.start.direction for t in throws] == ["left_to_right", "right_to_left"]
    assert all(t.complete and t.missing_samples == 0 for t in throws)
    truth = throws[0].truth.params()
    for parameter, value in faults.items():
        assert truth[parameter] == value
    sim = SwitchSimulation(plant, faults=faults)
    for recorded in throws:
        fresh = sim.throw().samples
        # recorded throws hold the start sample too; regenerate with recordings/make.sh if this fails
        np.testing.assert_allclose(recorded.current_a[1:], fresh.current_a, atol=1e-4)
        np.testing.assert_allclose(recorded.velocity_rad_s[1:], fresh.velocity_rad_s, atol=1e-3)
