"""A throw's features (issue 40), computed from the samples alone, the same from any source."""
import json

import numpy as np
import pytest

from railswitch.models.health.features import FEATURES, RECENT_THROWS, FeatureTrends, throw_features
from railswitch.models.plant.reference import Reference
from railswitch.models.plant.signals import MotorSignals

REFERENCE = Reference(np.array([0.0, 0.4, 6.0, 6.4, 7.0]), np.array([0.0, 130.9, 130.9, 0.0, 0.0]))
T = np.arange(0.0, 7.0001, 0.02)


def throw(stroke_a: float = 1.5, surge_a: float = 6.0, lock_a: float = 1.0, velocity: bool = True):
    current = np.where(T < 0.45, surge_a, stroke_a)
    current = np.where((T > 5.85) & (T <= 6.0), lock_a, current)  # the crank enters its lock zone at 5.853 s
    current = np.where(T > 6.0, -4.0 * (T < 6.4), current)
    signals = MotorSignals(-current, None, REFERENCE(T - 0.02) * (-1) if velocity else None)  # a right-to-left throw
    return throw_features(T, signals, REFERENCE, 7.0)


def test_the_surge_is_left_out_of_the_peak_and_currents_are_magnitudes():
    features = throw()
    assert set(features) == set(FEATURES)
    assert features["peak_current_a"] == 1.5 and abs(features["mean_current_a"] - 1.5) < 0.05
    assert features["lock_current_a"] == 1.0  # the stroke's end, where the crank runs into its dead centre
    assert 6.3 < features["throw_time_s"] < 6.45  # the motor stopped
    assert throw(velocity=False)["throw_time_s"] == 7.0  # a current-only unit: the end event
    assert throw(stroke_a=3.0)["energy_j"] > throw()["energy_j"] > 0


def test_a_commissioned_band_flags_a_feature_outside_it_and_follows_its_slope():
    trends = FeatureTrends(needed=3)
    for k in range(3):
        trends.learn("left_to_right", {"peak_current_a": 2.0 + 0.01 * k, "lock_current_a": None})
    assert trends.band("right_to_left", "peak_current_a") is None  # not learnt that way
    mean, low, high = trends.band("left_to_right", "peak_current_a")
    assert low < 2.0 < high and high - mean >= 0.1 * mean  # at least a tenth of its level
    inside = trends.update(10, "left_to_right", {"peak_current_a": 2.05})
    assert [(f["name"], f["state"]) for f in inside] == [("peak_current_a", "ok")]
    for k in range(11, 20):
        last = trends.update(k, "left_to_right", {"peak_current_a": 2.05 + 0.1 * (k - 10)})
    assert last[0]["state"] == "outside" and abs(last[0]["slope_per_100"] - 10.0) < 0.5
    again = FeatureTrends(needed=3)
    again.load(json.loads(json.dumps(trends.to_dict())))
    assert again.band("left_to_right", "peak_current_a") == (mean, low, high)
    latest = trends.latest("left_to_right", "peak_current_a")
    assert again.latest("left_to_right", "peak_current_a") == pytest.approx(latest)  # kept to six digits
    assert again.latest("left_to_right", "lock_current_a") is None is trends.latest("right_to_left", "peak_current_a")
    after, reloaded = (t.update(20, "left_to_right", {"peak_current_a": 3.2}) for t in (trends, again))
    assert reloaded[0]["slope_per_100"] == pytest.approx(after[0]["slope_per_100"], rel=1e-9)
    for k in range(21, 21 + RECENT_THROWS):  # the slope is over the latest RECENT_THROWS alone: a level one is 0
        last = trends.update(k, "left_to_right", {"peak_current_a": 2.0})
    assert last[0]["slope_per_100"] == pytest.approx(0.0, abs=1e-9)


def test_the_stroke_profile_places_a_load_by_the_rod_s_share_of_its_stroke_either_way():
    from railswitch.models.plant.drive import DriveParams
    from railswitch.models.health.features import PROFILE_BINS, stroke_profile
    drive = DriveParams()
    angle = np.concatenate([[0.0], np.cumsum(0.5 * (REFERENCE(T)[1:] + REFERENCE(T)[:-1]) * np.diff(T))])
    share = 0.5 * (1.0 - np.cos(np.minimum(angle / drive.gear_ratio, np.pi)))  # of a left-to-right throw
    for direction, at in (("left_to_right", share), ("right_to_left", 1.0 - share)):
        current = 1.5 + 2.0 * (np.abs(at - 0.3) < 0.02)  # a load where the rod is at 30 % of its stroke
        reference = REFERENCE if direction == "left_to_right" else Reference(REFERENCE.t_s, -REFERENCE.velocity_rad_s)
        profile = stroke_profile(T, MotorSignals(current, None, None), reference, drive)
        assert len(profile) == PROFILE_BINS
        assert abs((int(np.nanargmax(profile)) + 0.5) / PROFILE_BINS - 0.3) <= 1.0 / PROFILE_BINS, direction
    trends = FeatureTrends(needed=2)
    for _ in range(2):
        trends.learn("left_to_right", {}, np.full(PROFILE_BINS, 1.5))
    trends.update(20, "left_to_right", {}, profile)
    assert abs(np.nanmax(trends.excess("left_to_right")) - 2.0) < 0.5
    restored = FeatureTrends(needed=2)
    restored.load(trends.to_dict())  # the state keeps the profiles
    assert np.allclose(restored.excess("left_to_right"), trends.excess("left_to_right"), equal_nan=True)
