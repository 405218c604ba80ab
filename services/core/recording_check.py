"""Whether recorded throws are the current plant's under their scenario: judged at the accuracy the plant's
solver promises, not bit for bit.

Another processor or library build rounds differently, which moves CVODES's adaptive steps and, around contacts,
a sample of the current by a few 1e-3 A. What stays put is the RMS difference over a throw: it is of the order of
the solver's own global error (tests/integration/test_recordings.py measures it by changing the tolerance).
"""
from __future__ import annotations

import numpy as np

from railswitch.models.plant.high_fidelity import Plant
from railswitch.models.plant.simulation import SwitchSimulation, nominal_peaks
from railswitch.services.core.throw_cutter import CutThrow

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


def rms_differences(recorded_throws: list[CutThrow], plant: Plant, faults: dict) -> list[dict[str, float]]:
    """Per throw, the RMS difference of each signal between the recording and `plant` under `faults`."""
    sim = SwitchSimulation(plant, faults=faults)
    out = []
    for recorded in recorded_throws:
        fresh = sim.throw().samples.signals
        # recorded throws hold the start sample too
        out.append({name: float(np.sqrt(np.mean((getattr(recorded.signals, name)[1:] - getattr(fresh, name)) ** 2)))
                    for name in SIGNALS})
    return out
