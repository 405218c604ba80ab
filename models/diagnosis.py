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
right), so a switch's decision combines its latest throw in each direction.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from models.estimation import DRIVING_BOLT, Estimate, Measurement, ThrowEstimator
from models.plant import Plant
from models.reference import DIRECTIONS, Reference
from models.switch import SwitchSimulation
from schemas.faults import MODE_PARAMETERS

FALSE_ALARM_RATE = 1e-3  # per fault mode and throw, under the nominal hypothesis
MODEL_ERROR_MARGIN = 2.0  # model error varies from throw to throw: allow twice what commissioning saw
OTHER_DIRECTION = {"left_to_right": "right_to_left", "right_to_left": "left_to_right"}
CLOSED_START_M = {"left_to_right": 1.0, "right_to_left": 1.2}  # where a throw starts when the last one closed
GAP_TOLERANCE = 0.25  # of a sample period, for "the samples are evenly spaced"


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


def commissioning_gains(estimator: ThrowEstimator, plant: Plant) -> dict[str, dict[str, float]]:
    """Per direction and mode: how much the mode's fit improves on healthy, noise-free plant throws.

    Like commissioning a point machine: throw the healthy switch once each way
    and note how much of the reduced model's error each fault mode can absorb.
    """
    switch = SwitchSimulation(plant, rate_hz=estimator.reduced.rate_hz)
    gains, rail = {}, CLOSED_START_M["left_to_right"]
    for _ in DIRECTIONS:
        angle_at_start = plant.signals_at(switch.state)["angle_rad"]  # exact: the plant's own state
        throw = switch.throw()
        samples, n = throw.samples, estimator.samples
        m = Measurement(throw.reference, samples.current_a[:n], samples.angle_rad[:n], samples.velocity_rad_s[:n],
                        angle_at_start, rail)
        estimates = estimator.fit_all(m)
        gains[throw.direction] = {mode: max(estimates["nominal"].mse - estimates[mode].mse, 0.0) for mode in MODE_PARAMETERS}
        rail = CLOSED_START_M[OTHER_DIRECTION[throw.direction]]
    return gains


@dataclass(frozen=True)
class ThrowInput:
    """One throw as the diagnoser receives it: samples relative to the start event."""

    direction: str
    reference: Reference
    t_s: np.ndarray  # first sample at the start event (t = 0)
    current_a: np.ndarray
    angle_rad: np.ndarray
    velocity_rad_s: np.ndarray
    duration_s: float | None  # start to end event; None when no end event came
    missing_samples: int = 0


def start_angle(t_s: np.ndarray, angle_rad: np.ndarray, velocity_rad_s: np.ndarray) -> float:
    """Motor angle at the throw's start, from every sample rather than the first alone.

    angle(t) = angle(0) + integral of the velocity, so each sample gives an
    estimate of angle(0); their mean is far less noisy than the first sample
    (a wrong start angle shifts the rod and looks like a bolt offset).
    """
    travelled = np.concatenate([[0.0], np.cumsum(0.5 * (velocity_rad_s[1:] + velocity_rad_s[:-1]) * np.diff(t_s))])
    return float(np.mean(angle_rad - travelled))


def sample_rate_hz(t_s: np.ndarray) -> float:
    """Sample rate of evenly spaced times (the median step, so one gap does not change it)."""
    return float(1.0 / np.median(np.diff(t_s)))


def problem(throw: ThrowInput) -> str | None:
    """Why a throw cannot be diagnosed, or None when it can."""
    if throw.duration_s is None:
        return "throw has no end event (the stream stopped, or the next throw started, before it ended)"
    if len(throw.t_s) < 3:
        return f"throw has {len(throw.t_s)} samples"
    if throw.missing_samples:
        return f"{throw.missing_samples} samples missing inside the throw"
    signals = np.concatenate([throw.current_a, throw.angle_rad, throw.velocity_rad_s])
    if not np.all(np.isfinite(signals)) or not np.all(np.isfinite(throw.t_s)):
        return "throw has non-finite sample values"
    rate_hz = sample_rate_hz(throw.t_s)
    period = 1.0 / rate_hz
    steps = np.diff(throw.t_s)
    if abs(throw.t_s[0]) > GAP_TOLERANCE * period or np.any(np.abs(steps - period) > GAP_TOLERANCE * period):
        worst = float(np.max(steps)) if len(steps) else 0.0
        return f"samples are not evenly spaced at {rate_hz:g} Hz (largest gap {worst * 1e3:.0f} ms)"
    if throw.t_s[-1] < throw.duration_s - GAP_TOLERANCE * period:
        return f"samples stop at {throw.t_s[-1]:.2f} s of a {throw.duration_s:.2f} s throw"
    if throw.duration_s < float(throw.reference.t_s[-1]) - GAP_TOLERANCE * period:
        return f"throw ended at {throw.duration_s:.2f} s, before its {throw.reference.t_s[-1]:.2f} s reference"
    return None


@dataclass
class SwitchDiagnoser:
    """Diagnoses one switch throw by throw; remembers the latest verdict per direction."""

    estimator_for: Callable[[float, int], tuple[ThrowEstimator, dict]]  # (rate, samples) -> estimator and its
    # commissioning gains, built once and shared
    latest: dict[str, ThrowVerdict] = field(default_factory=dict)
    rail_m: float | None = None  # blades' position after the last diagnosed throw

    def diagnose(self, throw: ThrowInput) -> tuple[str, str | None, ThrowVerdict | None]:
        """(decision, reason, this throw's verdict); the decision combines both directions."""
        why = problem(throw)
        if why is not None:
            self.rail_m = None  # unknown where the blades are: assume the next throw starts closed
            return "unknown", why, None
        estimator, gains = self.estimator_for(round(sample_rate_hz(throw.t_s), 6), len(throw.t_s) - 1)
        start_rail = self.rail_m if self.rail_m is not None else CLOSED_START_M[throw.direction]
        m = Measurement(throw.reference, throw.current_a[1:], throw.angle_rad[1:], throw.velocity_rad_s[1:],
                        start_angle(throw.t_s, throw.angle_rad, throw.velocity_rad_s), start_rail,
                        self.background(throw.direction))
        estimates = estimator.fit_all(m)
        mode, found = judge(throw.direction, estimates, gains[throw.direction])
        fitted = estimator.simulate(m, estimates[mode].params)
        end_rail = float(fitted.pop("final_state")[4])
        verdict = ThrowVerdict(throw.direction, mode, found, estimates, end_rail, fitted)
        self.latest[throw.direction] = verdict
        self.rail_m = end_rail
        decision, reason = self.combined()
        return decision, reason, verdict

    def background(self, direction: str) -> dict[str, float]:
        """The other direction's bolt as its latest throw estimated it (this throw cannot show it)."""
        other = OTHER_DIRECTION[direction]
        verdict = self.latest.get(other)
        if verdict is None or verdict.mode != DRIVING_BOLT[other]:
            return {}
        return dict(verdict.estimates[verdict.mode].params)

    def combined(self) -> tuple[str, str | None]:
        """Nominal if the latest throw in each direction is; else the fault with the strongest evidence."""
        faulty = [v for v in self.latest.values() if v.mode != "nominal"]
        if not faulty:
            return "nominal", None
        strongest = max(faulty, key=lambda v: v.strength)
        others = [f"{v.mode} ({v.direction})" for v in faulty if v is not strongest and v.mode != strongest.mode]
        reason = f"{strongest.mode} seen in the latest {strongest.direction.replace('_', ' ')} throw"
        if others:
            reason += "; also " + ", ".join(others)
        return strongest.mode, reason

