"""A switch's life in pictures (services/core/health_series.py, railswitch report): one figure per switch,
throws as whole numbers."""
from types import SimpleNamespace

from railswitch.schemas import Diagnosis, FeatureHealth, Hypothesis, ParameterHealth, SwitchHealth
from railswitch.services.core.pictures import estimates_figure, features_figure, health_figure, life_pictures
from railswitch.services.core.fleet_diagnoser import DiagnosedThrow
from railswitch.services.core.health_series import health_series


def bearing(switch_id: str, throw: int, level: float, to_limit: float | None = None) -> SwitchHealth:
    parameter = ParameterHealth(name="bearing_friction", level=level, level_std=100.0, slope_per_100=50.0,
                                slope_std_per_100=10.0, limit=5000.0, throws_to_limit=to_limit,
                                throws_to_limit_low=None if to_limit is None else to_limit / 2,
                                throws_to_limit_high=None if to_limit is None else to_limit * 2)
    return SwitchHealth(switch_id=switch_id, throw_index=throw, t_ns=10**18 + throw * 10**9, model="poly",
                        state="ok", worst="bearing_friction", throws_to_limit=to_limit, parameters=[parameter])


def interleaved() -> list[SwitchHealth]:
    """Two switches' health messages as a fleet recording holds them: interleaved, one throw repeated."""
    return [bearing("sw2", 0, 10.0), bearing("sw1", 0, 100.0), bearing("sw1", 1, 150.0), bearing("sw2", 1, 20.0),
            bearing("sw1", 2, 200.0, to_limit=96.0), bearing("sw1", 1, 160.0)]  # throw 1 again, later


def test_each_switch_gets_its_own_series_over_whole_throw_numbers_a_repeated_throw_once():
    series = health_series(interleaved())
    assert list(series) == ["sw1", "sw2"]
    sw1 = series["sw1"].parameters["bearing_friction"]
    assert sw1.throws.dtype.kind == "i" and sw1.throws.tolist() == [0, 1, 2]
    assert sw1.level.tolist() == [100.0, 160.0, 200.0]  # the later message of throw 1 wins
    assert (sw1.crossing.throw, sw1.crossing.low, sw1.crossing.high) == (98.0, 50.0, 194.0)  # from throw 2 on
    assert series["sw2"].parameters["bearing_friction"].crossing is None


def test_a_crossing_far_beyond_the_history_is_named_in_the_legend_instead_of_stretching_the_axis():
    figure = health_figure(health_series(interleaved())["sw1"])  # throws 0-2, the limit predicted at throw 98
    ax = figure.axes[0]
    assert ax.get_xlim()[1] <= 2 + 10 + 0.5  # ten throws ahead at least, not 98
    labels = ax.get_legend_handles_labels()[1]
    assert "limit at throw 98 (50–194), beyond the picture" in labels


def test_a_two_switch_history_gives_one_health_picture_per_switch(tmp_path):
    written = life_pictures(tmp_path, interleaved(), {})
    assert [path.name for path in written] == ["sw1_health.png", "sw2_health.png"]
    assert all(path.stat().st_size > 10_000 for path in written)


def diagnosed(switch_id: str, throw: int, bearing_friction: float) -> DiagnosedThrow:
    """A throw's diagnosis with the bearing hypothesis estimated (the throw's signals are not drawn here)."""
    hypothesis = Hypothesis(mode="missing_bearing", params={"bearing_friction": bearing_friction},
                            std={"bearing_friction": 300.0}, mse=1e-4)
    return DiagnosedThrow(throw=SimpleNamespace(truth=None), verdict=None, diagnosis=Diagnosis(
        switch_id=switch_id, throw_index=throw, direction="left_to_right" if throw % 2 == 0 else "right_to_left",
        t_start_ns=throw, t_end_ns=throw + 1, model="poly", decision="nominal", hypotheses=[hypothesis],
        latency_ms=1.0))


def test_estimates_of_two_throws_are_drawn_at_whole_throw_numbers():
    figure = estimates_figure("sw1", [diagnosed("sw1", 0, 100.0), diagnosed("sw1", 1, 300.0)])
    for ax in figure.axes:
        ticks = [t for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1]]
        assert ticks and all(t == round(t) for t in ticks)


def test_a_fleet_recordings_estimates_get_one_picture_per_switch(tmp_path):
    fits = {(s, k): diagnosed(s, k, 100.0 * k) for s in ("sw1", "sw2") for k in range(3)}
    written = life_pictures(tmp_path, [], fits)
    assert [path.name for path in written] == ["sw1_estimates.png", "sw2_estimates.png"]


def test_parameters_are_drawn_in_the_contracts_order_whichever_a_switch_reported_first():
    bolt = ParameterHealth(name="left_bolt_offset", level=0.01, level_std=0.002, limit=0.06)
    later = bearing("sw1", 1, 120.0).model_copy(update={"parameters": [*bearing("sw1", 1, 120.0).parameters, bolt]})
    series = health_series([bearing("sw1", 0, 100.0), later])["sw1"]  # the bolt first seen at throw 1
    assert list(series.parameters) == ["left_bolt_offset", "bearing_friction"]
    assert series.parameters["left_bolt_offset"].throws.tolist() == [1]
    labels = [ax.get_ylabel().split("\n")[0] for ax in health_figure(series).axes]
    assert labels == ["left_bolt_offset", "bearing_friction"]


def with_features(switch_id: str, throw: int, peak_a: float) -> SwitchHealth:
    """A commissioned switch's health with its features' trend in the throw's direction."""
    direction = "left_to_right" if throw % 2 == 0 else "right_to_left"
    feature = FeatureHealth(name="peak_current_a", direction=direction, value=peak_a, mean=2.9, low=2.6, high=3.2,
                            state="ok" if 2.6 <= peak_a <= 3.2 else "outside")
    return bearing(switch_id, throw, 10.0).model_copy(update={"features": [feature]})


def test_a_switch_whose_health_holds_features_gets_a_features_picture_with_its_band(tmp_path):
    healths = [with_features("sw1", k, 2.9 + 0.05 * k) for k in range(10)] + [bearing("sw2", 0, 10.0)]
    written = life_pictures(tmp_path, healths, {})
    assert [path.name for path in written] == ["sw1_health.png", "sw2_health.png", "sw1_features.png"]
    figure = features_figure("sw1", healths[:10])
    peak = figure.axes[1]
    assert peak.get_ylabel() == "peak current [A]"
    marked = sorted(int(x) for line in peak.get_lines() if line.get_marker() == "x" for x in line.get_xdata())
    assert marked == [7, 8, 9]  # the throws outside the band (3.2 A), each direction's own
