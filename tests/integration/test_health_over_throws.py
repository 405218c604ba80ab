"""A switch's health from its own diagnoses (issue 15): a fault that grows throw by throw shows whole in its trend."""
import numpy as np

from railswitch.models.switch import SwitchSimulation
from railswitch.models.switch_diagnosis import COMMISSIONING_THROWS
from railswitch.services.core.switch_messages import SimulatedThrows


def test_bearings_drying_out_throw_by_throw_show_whole_in_the_health_level(diagnoser, plant):
    """Bearing friction rising 40 N·s/m a throw after commissioning: every throw alike enough to the last that the
    drifting chairs could take it (and the decisions stay nominal for a while), the health level still follows the
    truth rather than the small part the bearing hypothesis keeps."""
    sim = SwitchSimulation(plant, noise_rel=0.01, seed=5)
    source = SimulatedThrows("drying", sim)
    commissioning, growing, rate = 2 * COMMISSIONING_THROWS, 60, 40.0
    for _ in range(commissioning):
        diagnoser.diagnose(source.next())
    levels, truths = [], []
    for k in range(1, growing + 1):
        sim.set_faults({"bearing_friction": rate * k})
        health = diagnoser.diagnose(source.next()).health
        levels.append(next(p.level for p in health.parameters if p.name == "bearing_friction"))
        truths.append(rate * k)
    assert abs(levels[-1] - truths[-1]) < 0.2 * truths[-1], (levels[-1], truths[-1])
    slope = 100 * np.polyfit(np.arange(20), levels[-20:], 1)[0]
    assert abs(slope - 100 * rate) < 0.3 * 100 * rate, slope
