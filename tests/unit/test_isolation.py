"""Fault detection by F test on the effective number of residuals."""
from types import SimpleNamespace

import numpy as np
import pytest

from railswitch.models.diagnosis.estimation import Estimate
from railswitch.models.numerics.statistics import effective_samples
from railswitch.models.diagnosis.isolation import judge
from railswitch.models.diagnosis.switch_diagnoser import BOLT_TOLERANCE, Baseline, ErrorModel, SwitchDiagnoser


def test_effective_sample_count_is_the_count_for_white_noise_and_small_for_smooth_error():
    rng = np.random.default_rng(0)
    white = rng.normal(size=(1000, 3))
    smooth = np.sin(np.linspace(0, 6, 1000))[:, None] * np.ones((1, 3))
    assert effective_samples(white) > 2000
    assert effective_samples(smooth) < 100


def _estimate(mode: str, objective: float, values: dict[str, float] | None = None, mse: float | None = None,
              prior_weight: float = 0.0, samples: float = 500.0) -> Estimate:
    return Estimate(mode, {}, {}, values or {}, objective if mse is None else mse, objective, 1, np.zeros((0, 3)),
                    samples, prior_weight)


def _three_throws(nominal: tuple[float, float], bearing: tuple[float, float], prior_weight: float = 0.0) -> list[float]:
    """The bearing's evidence ratio after each of three throws alike: (objective, data MSE) of each fit."""
    earlier, ratios = {}, []
    for _ in range(3):
        estimates = {"nominal": _estimate("nominal", nominal[0], mse=nominal[1], prior_weight=prior_weight),
                     "missing_bearing": _estimate("missing_bearing", bearing[0], mse=bearing[1],
                                                  prior_weight=prior_weight)}
        _, found = judge("left_to_right", estimates, earlier=earlier)
        earlier = {m: [e, *earlier.get(m, [])] for m, e in found.items()}
        ratios.append(found["missing_bearing"].ratio)
    return ratios


def test_a_detected_bolt_within_the_setting_tolerance_is_an_adjustment_not_a_fault():
    estimates = {"nominal": _estimate("nominal", 1.0), "left_bolt": _estimate("left_bolt", 0.5)}
    assert judge("left_to_right", estimates)[0] == "left_bolt"
    mode, found = judge("left_to_right", estimates, negligible=["left_bolt"])
    assert mode == "nominal" and found["left_bolt"].detected  # its evidence is kept all the same


def test_the_switch_diagnoser_calls_bolts_within_tolerance_negligible_and_larger_ones_not():
    switch = SwitchDiagnoser.__new__(SwitchDiagnoser)
    switch.errors = ErrorModel(bias={"left_bolt_offset": 0.001})
    switch.baseline, switch.faults = Baseline(), {}
    switch.drive = SimpleNamespace(linkage_ratio=2.0)
    small = _estimate("left_bolt", 0.5, {"left_bolt_offset": -BOLT_TOLERANCE + 0.0015})  # -3.5 mm less the bias
    large = _estimate("right_bolt", 0.5, {"right_bolt_offset": BOLT_TOLERANCE + 0.001})
    assert switch.negligible({"left_bolt": small, "right_bolt": large}, "left_to_right", 1.0) == ["left_bolt"]
    assert switch.negligible({"left_bolt": _estimate("left_bolt", 0.5, {"left_bolt_offset": 0.0065})},
                             "left_to_right", 1.0) == []


def test_evidence_from_the_samples_adds_up_over_throws_but_a_prior_saved_counts_once():
    # Each throw shows the bearing at about half the one-throw threshold (F = 6.5 against 13.1 at 500 samples).
    # From its samples: three such throws together are a detection (the chi-square of their sum).
    from_samples = _three_throws(nominal=(1.013, 1.013), bearing=(1.0, 1.0))
    assert from_samples[0] < 0.6 and from_samples[-1] > 1.0
    # From the prior the nominal fit pays and the bearing's does not (a switch whose chairs are drier than the
    # population's: the same knowledge in every throw), the same gain never adds up.
    from_prior = _three_throws(nominal=(1.013, 1.0), bearing=(1.0, 1.0), prior_weight=0.013 / 6.5)  # saves 6.5
    assert from_prior[0] == pytest.approx(from_samples[0], rel=0.01) and max(from_prior) < 0.6


def test_a_prior_saved_counts_as_its_standard_scores_whatever_the_residual_variance():
    # The nominal fit holds a nuisance three population standard deviations out (charge 9) on a throw whose
    # residual variance is a third of the priors' weight: the mode that frees it is not a fault on that alone
    # (9 < 13.1, the one-throw threshold), and a nuisance five out (25) is.
    for scores, detected in ((9.0, False), (25.0, True)):
        weight = 3e-3
        estimates = {"nominal": _estimate("nominal", 1.0 + weight * scores, mse=1.0, prior_weight=weight),
                     "drive_friction": _estimate("drive_friction", 1.0, mse=1.0, prior_weight=weight)}
        assert (judge("left_to_right", estimates)[0] == "drive_friction") == detected


def test_the_model_error_part_that_differs_between_throws_averages_out_and_the_common_part_stays():
    """Calibrated on one throw (3 mm) and on four combined (2 mm): the common part is what four throws leave
    of it beyond a quarter of the varying part's variance."""
    errors = ErrorModel(absolute={"left_bolt_offset": 0.002}, one_absolute={"left_bolt_offset": 0.003},
                        throws={"left_bolt_offset": 4.0})
    assert errors.std("left_bolt_offset", 0.05, throws=1) == pytest.approx(0.003)
    assert errors.std("left_bolt_offset", 0.05, throws=4) == pytest.approx(0.002)
    varying = (0.003**2 - 0.002**2) * 4 / 3
    assert errors.std("left_bolt_offset", 0.05, throws=10_000) == pytest.approx(np.sqrt(0.003**2 - varying), rel=1e-3)
    assert errors.common("left_bolt_offset", 0.05) == pytest.approx(np.sqrt(0.003**2 - varying), rel=1e-6)
    # a calibration from before the split: the one envelope at any number of throws
    assert ErrorModel(absolute={"left_bolt_offset": 0.002}).std("left_bolt_offset", 0.05, throws=1) == 0.002
    # one throw no worse than several: nothing averages out
    same = ErrorModel(absolute={"x": 0.002}, one_absolute={"x": 0.0015}, throws={"x": 4.0})
    assert same.std("x", 0.0, throws=1) == same.std("x", 0.0, throws=9) == 0.002


def test_the_units_torque_constant_is_common_to_every_throw_and_scales_with_the_value():
    """A force read through the current is off by the unit's torque constant in every throw alike: its relative
    spread adds to the common part at any number of throws, in proportion to the value."""
    measured = dict(absolute={"drive_friction_nm": 0.001}, one_absolute={"drive_friction_nm": 0.003},
                    throws={"drive_friction_nm": 6.0})
    errors, without = ErrorModel(**measured, unit_relative={"drive_friction_nm": 0.02}), ErrorModel(**measured)
    for throws in (1, 6, 10_000):
        for value in (0.05, 0.25):
            assert errors.std("drive_friction_nm", value, throws) == pytest.approx(
                np.hypot(without.std("drive_friction_nm", value, throws), 0.02 * value), rel=1e-12)
    assert errors.common("drive_friction_nm", 0.25) == pytest.approx(np.hypot(without.common("drive_friction_nm", 0.25),
                                                                               0.005), rel=1e-12)
    assert ErrorModel(unit_relative={"x": 0.02}).std("x", 0.1) == pytest.approx(0.002)


def test_the_health_tracker_takes_the_model_error_that_stays_at_each_limit():
    """A forecast ends at the limit: the model's error there, its common part (a relative part counts)."""
    errors = ErrorModel(absolute={"bearing_friction": 80.0}, relative={"bearing_friction": 0.05},
                        one_absolute={"bearing_friction": 120.0}, one_relative={"bearing_friction": 0.05},
                        throws={"bearing_friction": 6.0})
    unused = SimpleNamespace(reduced=SimpleNamespace(params=SimpleNamespace(plant=SimpleNamespace(drive=None))))
    switch = SwitchDiagnoser(unused, None, errors, limits={"bearing_friction": 4000.0})
    assert switch.health.model_error["bearing_friction"] == pytest.approx(errors.common("bearing_friction", 4000.0))
    assert switch.health.model_error["bearing_friction"] > 250.0  # not the absolute part alone


def test_a_missing_bearing_carries_what_the_chairs_may_have_done_since_the_last_healthy_throw():
    """A throw tells the sum of the chairs' and a bearing's friction, not the split, and only healthy throws move the
    chairs' level: k faulty throws on, the chairs may have moved k times one throw's allowance (DRIFT), which the
    combined bearing carries (fleet seed 2: chairs drying to twice their friction read as a bearing 1600 N·s/m
    larger, 3.7 std off without it). One throw, or a switch not commissioned (no drift prior), adds nothing."""
    from railswitch.models.plant.reference import DIRECTIONS
    from railswitch.models.diagnosis.switch_diagnoser import (CHAIRS_AS_BEARING, DRIFT, DRIFTING, Baseline, Reported,
                                                    Tracked, population)

    unused = SimpleNamespace(reduced=SimpleNamespace(params=SimpleNamespace(plant=SimpleNamespace(drive=None))))
    baseline = Baseline()
    for direction in DIRECTIONS:
        for _ in range(baseline.needed):
            baseline.add(direction, {"bearing_friction": 0.0, "motor.coulomb_friction_nm": 0.05, DRIFTING: 0.02},
                         {}, 1e-6)
    baseline.follow(DRIFTING, 0.02)
    commissioned = SwitchDiagnoser(unused, population(), ErrorModel(), baseline)
    fresh = SwitchDiagnoser(unused, population(), ErrorModel())

    def verdicts(count):
        return [Tracked.of(SimpleNamespace(index=10 + k, reported={"missing_bearing": Reported(
            "missing_bearing", {"bearing_friction": 5000.0}, {}, 0.0, fit_std={"bearing_friction": 100.0})}),
            "missing_bearing") for k in range(count)]

    assert commissioned.combine("missing_bearing", verdicts(1)).std["bearing_friction"] == pytest.approx(100.0)
    six = commissioned.combine("missing_bearing", verdicts(6))
    unseen = CHAIRS_AS_BEARING * DRIFT * 0.02 * np.mean(range(6))  # equal weights: the mean of 0..5 throws on
    assert six.std["bearing_friction"] == pytest.approx(np.hypot(100.0 / np.sqrt(6), unseen))
    assert fresh.combine("missing_bearing", verdicts(6)).std["bearing_friction"] == pytest.approx(100.0 / np.sqrt(6))


def test_the_calibration_puts_each_force_back_on_its_units_torque_constant():
    """A force read through the current reads as its truth times nominal over the unit's own constant: each case is
    put back on its unit before the envelopes are measured, and the population's spread is added whole. Drive
    frictions read exactly that way leave no envelope; a bolt (a position) is not read through the current."""
    from railswitch.services.core.calibration import error_model

    rng = np.random.default_rng(3)
    truth, unit = rng.uniform(0.03, 0.3, 40), np.exp(rng.normal(0.0, 0.02, 40))
    errors = error_model({"drive_friction_nm": [(t, t * u, t * u, 6, u) for t, u in zip(truth, unit)],
                          "left_bolt_offset": [(t, t + 0.001, t + 0.001, 3, u) for t, u in zip(truth, unit)]})
    for envelope in (errors.absolute, errors.relative, errors.one_absolute, errors.one_relative, errors.bias):
        assert envelope["drive_friction_nm"] == pytest.approx(0.0, abs=1e-12)
    assert errors.unit_relative["drive_friction_nm"] == pytest.approx(0.02, rel=0.02)  # the population's
    assert "left_bolt_offset" not in errors.unit_relative
    assert errors.bias["left_bolt_offset"] == pytest.approx(0.001)


def test_a_baselines_summaries_follow_every_healthy_throw_added_and_its_copy_from_a_dict():
    """Level, gains and model weight are kept between throws (they are read some 24 times a throw); each throw added
    in commissioning changes them as if they were computed afresh, and a baseline read back from its dict has its
    own."""
    from railswitch.models.plant.reference import DIRECTIONS
    from railswitch.models.diagnosis.switch_diagnoser import Baseline

    baseline, rng = Baseline(), np.random.default_rng(5)
    for k in range(baseline.needed):
        for direction in DIRECTIONS:
            baseline.add(direction, {"bearing_friction": float(rng.normal(0.0, 300.0))},
                         {"left_bolt": float(rng.uniform())}, float(rng.uniform(1e-6, 1e-5)))
            added = baseline.healthy[direction]
            values = [h["levels"]["bearing_friction"] for h in added]
            expected = (np.mean(values), np.std(values, ddof=1) if len(values) > 1 else 0.0)
            assert baseline.level(direction, "bearing_friction") == pytest.approx(expected, rel=1e-12, abs=1e-12)
            assert baseline.gains(direction)["left_bolt"] == max(h["gains"]["left_bolt"] for h in added)
            assert baseline.model_weight() == np.median([h["model_weight"] for d in DIRECTIONS
                                                         for h in baseline.healthy[d]])
    copy = Baseline.from_dict(baseline.to_dict())
    assert copy.level(DIRECTIONS[0], "bearing_friction") == baseline.level(DIRECTIONS[0], "bearing_friction")
    assert "_summaries" not in baseline.to_dict()
