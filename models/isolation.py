"""Fault detection and isolation from one switch's throws (paper, section "Fault diagnosis").

Per throw: every hypothesis is fitted (models/estimation.py), then a fault mode
is detected when its fit explains significantly more than the nominal fit. The
significance is an F test whose degrees of freedom come from the residual
itself: model error is smooth, not white, so the number of independent
residuals is estimated from the residual's autocorrelation (Geyer's initial
positive sequence). With white measurement noise that number is the sample
count; with a smooth model-error residual it is small and the test strict. The
threshold is therefore derived from the measured residual, never tuned per case.

A bolt only drives the blades in one direction (the left bolt from left to
right), so a throw can show only the bolt that drives it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from railswitch.models.estimation import DRIVING_BOLT, Estimate, Measurement, ThrowEstimator
from railswitch.schemas.faults import MODE_PARAMETERS

FALSE_ALARM_RATE = 1e-3  # per fault mode and throw, under the nominal hypothesis
MODEL_ERROR_MARGIN = 2.0  # model error varies from throw to throw: allow twice what commissioning saw
OTHER_DIRECTION = {"left_to_right": "right_to_left", "right_to_left": "left_to_right"}


def effective_samples(residual: np.ndarray) -> float:
    """Number of independent residuals: N / (1 + 2 sum of autocorrelations), summed over the signals.

    The sum stops at the first pair of lags whose autocorrelations add up to a
    negative number (Geyer's initial positive sequence, as in MCMC effective
    sample sizes).
    """
    total = 0.0
    for column in np.atleast_2d(residual.T):
        n = len(column)
        centred = column - column.mean()
        spectrum = np.fft.rfft(centred, 2 * n)
        acf = np.fft.irfft(spectrum * np.conj(spectrum))[:n]
        if acf[0] <= 0:
            total += n
            continue
        acf = acf / acf[0]
        tau = -1.0
        for k in range(0, n - 1, 2):
            pair = acf[k] + acf[k + 1]
            if pair < 0:
                break
            tau += 2 * pair
        total += n / max(tau, 1.0)
    return total


@dataclass(frozen=True)
class Evidence:
    """How much better a fault mode fits than nominal: F statistic over its critical value."""

    mode: str
    ratio: float  # above 1: detected

    @property
    def detected(self) -> bool:
        return self.ratio > 1.0


def evidence(estimates: dict[str, Estimate], mode: str, model_gain: float = 0.0) -> Evidence:
    """F test of `mode` against the nominal fit, on the effective number of residuals.

    `model_gain` is what the mode's fit gains on healthy throws by absorbing model
    error (measured at commissioning); only the gain beyond twice that counts.
    """
    fitted, nominal = estimates[mode], estimates["nominal"]
    p = len(MODE_PARAMETERS[mode])
    n = effective_samples(fitted.residual)
    gain = nominal.mse - fitted.mse - MODEL_ERROR_MARGIN * model_gain
    if n <= p + 1 or fitted.mse <= 0:
        return Evidence(mode, 0.0 if gain <= 0 else np.inf)
    f = max(gain, 0.0) / p / (fitted.mse / (n - p))
    critical = stats.f.ppf(1.0 - FALSE_ALARM_RATE, p, n - p)
    return Evidence(mode, f / critical)


@dataclass(frozen=True)
class ThrowVerdict:
    """What one throw says: its most likely mode (or nominal) and the evidence for each."""

    direction: str
    mode: str
    evidence: dict[str, Evidence]
    estimates: dict[str, Estimate]
    end_rail_m: float  # where the decided hypothesis leaves the blades
    fitted: dict[str, np.ndarray]  # the decided hypothesis's outputs at the samples after the start

    @property
    def strength(self) -> float:
        return self.evidence[self.mode].ratio if self.mode in self.evidence else 0.0


def candidate_modes(direction: str) -> list[str]:
    """Modes a throw in `direction` can show: the bolt that drives it, bearings, obstacles."""
    return [m for m in MODE_PARAMETERS if m != DRIVING_BOLT[OTHER_DIRECTION[direction]]]


def judge(direction: str, estimates: dict[str, Estimate],
          model_gains: dict[str, float] | None = None) -> tuple[str, dict[str, Evidence]]:
    """The detected mode with the smallest MSE, or nominal when none is detected."""
    gains = model_gains or {}
    found = {m: evidence(estimates, m, gains.get(m, 0.0)) for m in candidate_modes(direction)}
    detected = [m for m, e in found.items() if e.detected]
    return (min(detected, key=lambda m: estimates[m].mse) if detected else "nominal"), found


def commissioning_gains(estimator: ThrowEstimator, healthy: list[Measurement]) -> dict[str, dict[str, float]]:
    """Per direction and mode: how much the mode's fit improves on healthy throws (one or more each way).

    Like commissioning a point machine: throw the healthy switch each way and note how much of
    the reduced model's error each fault mode can absorb.
    """
    gains: dict[str, dict[str, float]] = {}
    for m in healthy:
        estimates = estimator.fit_all(m)
        gain = {mode: max(estimates["nominal"].mse - estimates[mode].mse, 0.0) for mode in MODE_PARAMETERS}
        seen = gains.setdefault(m.direction, dict.fromkeys(MODE_PARAMETERS, 0.0))
        gains[m.direction] = {mode: max(seen[mode], gain[mode]) for mode in MODE_PARAMETERS}
    return gains
