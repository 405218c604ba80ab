"""Fault detection by F test on the effective number of residuals."""
import numpy as np

from railswitch.models.estimation import Estimate, effective_samples
from railswitch.models.isolation import judge
from railswitch.models.switch_diagnosis import BOLT_TOLERANCE, ErrorModel, SwitchDiagnoser


def test_effective_sample_count_is_the_count_for_white_noise_and_small_for_smooth_error():
    rng = np.random.default_rng(0)
    white = rng.normal(size=(1000, 3))
    smooth = np.sin(np.linspace(0, 6, 1000))[:, None] * np.ones((1, 3))
    assert effective_samples(white) > 2000
    assert effective_samples(smooth) < 100


def _estimate(mode: str, objective: float, values: dict[str, float] | None = None) -> Estimate:
    return Estimate(mode, {}, {}, values or {}, objective, objective, 1, np.zeros((0, 3)), 500.0)


def test_a_detected_bolt_within_the_setting_tolerance_is_an_adjustment_not_a_fault():
    estimates = {"nominal": _estimate("nominal", 1.0), "left_bolt": _estimate("left_bolt", 0.5)}
    assert judge("left_to_right", estimates)[0] == "left_bolt"
    mode, found = judge("left_to_right", estimates, negligible=["left_bolt"])
    assert mode == "nominal" and found["left_bolt"].detected  # its evidence is kept all the same


def test_the_switch_diagnoser_calls_bolts_within_tolerance_negligible_and_larger_ones_not():
    switch = SwitchDiagnoser.__new__(SwitchDiagnoser)
    switch.errors = ErrorModel(bias={"left_bolt_offset": 0.001})
    small = _estimate("left_bolt", 0.5, {"left_bolt_offset": -BOLT_TOLERANCE + 0.0015})  # -3.5 mm less the bias
    large = _estimate("right_bolt", 0.5, {"right_bolt_offset": BOLT_TOLERANCE + 0.001})
    assert switch.negligible({"left_bolt": small, "right_bolt": large}) == ["left_bolt"]
    assert switch.negligible({"left_bolt": _estimate("left_bolt", 0.5, {"left_bolt_offset": 0.0065})}) == []
