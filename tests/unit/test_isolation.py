"""Fault detection by F test on the effective number of residuals."""
import numpy as np

from railswitch.models.estimation import effective_samples


def test_effective_sample_count_is_the_count_for_white_noise_and_small_for_smooth_error():
    rng = np.random.default_rng(0)
    white = rng.normal(size=(1000, 3))
    smooth = np.sin(np.linspace(0, 6, 1000))[:, None] * np.ones((1, 3))
    assert effective_samples(white) > 2000
    assert effective_samples(smooth) < 100
