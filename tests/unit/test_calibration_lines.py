"""The calibration's bias line: least absolute deviations, so a few misfits do not move it."""
import numpy as np

from railswitch.services.core.calibration import POSITIONS, median_line


def test_the_bias_line_recovers_an_offset_and_a_slope_through_misfits():
    rng = np.random.default_rng(3)
    truth = rng.uniform(0.01, 0.2, 40)  # bolt offsets, m
    estimate = truth + 0.0014 + 0.01 * truth + rng.normal(0.0, 2e-4, 40)
    estimate[:4] += 0.03  # four fits that went astray
    b, r = median_line(truth, estimate, proportional=True)
    assert abs(b - 0.0014) < 3e-4 and abs(r - 0.01) < 3e-3


def test_a_bias_with_no_slope_gets_none_and_positions_get_a_median():
    truth = np.linspace(1000.0, 9000.0, 30)
    b, r = median_line(truth, truth + 50.0 + np.tile([-1.0, 1.0], 15), proportional=True)
    assert abs(r) < 1e-3 and abs(b - 50.0) < 2.0
    assert median_line(truth, truth + 50.0 + 0.1 * truth, proportional=False)[1] == 0.0


def test_bolt_offsets_are_sizes_and_may_take_a_proportional_bias():
    assert "left_bolt_offset" not in POSITIONS and "right_bolt_offset" not in POSITIONS
    assert "obstacle_position" in POSITIONS
