"""A switch's health over throws: level, trend, throws to the limit, states with hysteresis (issue 15)."""
import numpy as np
import pytest

from railswitch.models.health import DEFAULT_LIMITS, HealthTracker


def feed(tracker, values, name="bearing_friction", std=250.0, seed=0):
    rng = np.random.default_rng(seed)
    return [tracker.update(k, {name: (v + rng.normal(0.0, std), std)}) for k, v in enumerate(values)]


def test_a_linearly_growing_bearing_friction_has_its_slope_in_the_interval_and_a_shrinking_time_to_limit():
    rate = 25.0  # N·s/m per throw: the 5000 N·s/m limit in 200 throws
    healths = feed(HealthTracker(), [rate * k for k in range(150)])
    bearing = [h.parameters["bearing_friction"] for h in healths]
    last = bearing[-1]
    assert abs(last.slope_per_100 - 100 * rate) <= 2 * last.slope_std_per_100
    times = np.array([b.throws_to_limit for b in bearing[60:]], dtype=float)
    assert np.all(np.isfinite(times))
    per_throw = np.polyfit(np.arange(len(times)), times, 1)[0]
    assert -1.5 < per_throw < -0.5  # one throw fewer to go with every throw
    assert last.throws_to_limit_low <= (5000 - rate * 149) / rate <= last.throws_to_limit_high


def test_a_steady_fault_has_a_flat_trend_and_its_state_never_flaps():
    healths = feed(HealthTracker(), [3000.0] * 200, seed=3)
    last = healths[-1].parameters["bearing_friction"]
    assert abs(last.slope_per_100) <= 2 * last.slope_std_per_100
    states = [h.parameters["bearing_friction"].state for h in healths[20:]]
    assert states == [states[0]] * len(states)  # watch (past half the limit) and stays there


def test_one_odd_throw_does_not_raise_an_alarm():
    tracker = HealthTracker()
    values = [100.0] * 60
    values[40] = 9000.0  # one wild estimate
    healths = feed(tracker, values, std=100.0)
    assert all(h.parameters["bearing_friction"].state == "ok" for h in healths)


def test_a_bolt_not_seen_by_a_throw_keeps_its_level():
    tracker = HealthTracker()
    tracker.update(0, {"left_bolt_offset": (0.05, 0.001)})
    before = tracker.update(1, {"left_bolt_offset": (0.05, 0.001)}).parameters["left_bolt_offset"]
    after = tracker.update(2, {"bearing_friction": (10.0, 100.0)}).parameters["left_bolt_offset"]  # a throw that cannot see it
    assert after.level == before.level


def test_a_reset_switch_starts_afresh_and_limits_are_configurable():
    tracker = HealthTracker(limits={"bearing_friction": 2000.0})
    assert tracker.limits["bearing_friction"] == 2000.0 and tracker.limits["left_bolt_offset"] == DEFAULT_LIMITS["left_bolt_offset"]
    feed(tracker, [2500.0] * 10)
    assert tracker.states["bearing_friction"] == "alarm"
    tracker.reset()
    assert tracker.states["bearing_friction"] == "ok" and tracker.filters["bearing_friction"].updates == 0


def test_a_step_restarts_the_level_and_keeps_the_trend():
    """Two throws in a row far off on the same side are a step (a bolt's nut slipping a few millimetres): the level
    starts again there, and the trend the parameter was on goes on."""
    tracker = HealthTracker()
    for k in range(100):
        tracker.update(k, {"left_bolt_offset": (0.0002 * k, 0.0005)})
    before = tracker.filters["left_bolt_offset"].x[1]
    for k in (100, 101):
        health = tracker.update(k, {"left_bolt_offset": (0.0002 * k + 0.01, 0.0005)})
    bolt = health.parameters["left_bolt_offset"]
    assert bolt.level == pytest.approx(0.0302, abs=0.001)
    assert bolt.slope_per_100 == pytest.approx(100 * before, rel=0.2)
