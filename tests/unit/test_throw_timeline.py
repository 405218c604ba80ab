"""Where a throw's samples fall on the estimator's model samples (models/diagnosis/estimation.py _Timeline)."""
import numpy as np
import pytest

from railswitch.models.diagnosis.estimation import CHUNK_SAMPLES, GRID_RATE_HZ, MODEL_RATE_HZ, Measurement, _Timeline
from railswitch.models.reduced.rail_models import REPRESENTATIONS
from railswitch.models.reduced.hybrid import ReducedSwitch
from railswitch.models.plant.reference import throw_reference
from railswitch.models.plant.signals import MotorSignals


@pytest.fixture(scope="module")
def reduced():
    poly = REPRESENTATIONS["poly"]
    return {rate: ReducedSwitch(poly, poly.initial_weights(0), rate_hz=rate) for rate in (MODEL_RATE_HZ, GRID_RATE_HZ)}


def _measurement(seconds: float, rate_hz: float) -> Measurement:
    t_s = np.arange(1, round(seconds * rate_hz) + 1) / rate_hz
    blank = np.zeros(len(t_s))
    return Measurement("left_to_right", throw_reference("left_to_right"), t_s, MotorSignals(blank, blank, blank),
                       0.0, 1.0)


@pytest.mark.parametrize("seconds, rate_hz, chunks", [
    (7.0, 50.0, 7),  # the last sample on the 700th model sample: seven 1 s chunks, not eight
    (7.0, 200.0, 7),
    (6.995, 200.0, 7),  # between the 699th and 700th model samples: the 700th is needed
    (7.01, 100.0, 8),
    (2.5, 20.0, 3),
])
def test_a_throw_rolls_out_the_model_samples_its_samples_need_and_no_chunk_more(reduced, seconds, rate_hz, chunks):
    timeline = _Timeline.of(reduced[MODEL_RATE_HZ], _measurement(seconds, rate_hz), CHUNK_SAMPLES)
    assert len(timeline.refs) == chunks
    last = timeline.index[-1] + (timeline.fraction[-1] > 0)  # the model sample the last sample needs
    assert last <= chunks * CHUNK_SAMPLES < last + CHUNK_SAMPLES


def test_the_grid_timeline_interpolates_what_the_model_timeline_does(reduced):
    """The same throw on the grid's coarser samples: a model output linear in time reads the same at every
    sample on both."""
    m = _measurement(7.0, 30.0)  # off both grids
    fine = _Timeline.of(reduced[MODEL_RATE_HZ], m, CHUNK_SAMPLES)
    coarse = _Timeline.of(reduced[GRID_RATE_HZ], m, CHUNK_SAMPLES // 2)
    assert not fine.on_grid and not coarse.on_grid
    ramp = [np.arange(1 + len(t.refs) * size) / rate
            for t, size, rate in ((fine, CHUNK_SAMPLES, MODEL_RATE_HZ), (coarse, CHUNK_SAMPLES // 2, GRID_RATE_HZ))]
    np.testing.assert_allclose(fine.at_samples(ramp[0]), m.t_s, atol=1e-12)
    np.testing.assert_allclose(coarse.at_samples(ramp[1]), m.t_s, atol=1e-12)
