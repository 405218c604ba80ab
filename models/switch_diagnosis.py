"""One switch diagnosed throw by throw (paper, section "Fault diagnosis").

Checks that a throw can be diagnosed at all, estimates where it starts (the motor angle
from every sample, the blades where the previous throw's fit left them), fits every
hypothesis (models/estimation.py), judges them (models/isolation.py) and combines the
latest throw of each direction: a bolt only drives the blades one way (the left bolt
from left to right), so the other direction's bolt is held at its latest estimate.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from railswitch.models.estimation import DRIVING_BOLT, Measurement, ThrowEstimator
from railswitch.models.isolation import OTHER_DIRECTION, ThrowVerdict, judge
from railswitch.models.reference import Reference
from railswitch.models.signals import MotorSignals

CLOSED_START_M = {"left_to_right": 1.0, "right_to_left": 1.2}  # where a throw starts when the last one closed
GAP_TOLERANCE = 0.25  # of a sample period, for "the samples are evenly spaced"


@dataclass(frozen=True)
class ThrowInput:
    """One throw as the diagnoser receives it: samples relative to the start event."""

    direction: str
    reference: Reference
    t_s: np.ndarray  # first sample at the start event (t = 0)
    signals: MotorSignals
    duration_s: float | None  # start to end event; None when no end event came
    missing_samples: int = 0


def start_angle(t_s: np.ndarray, signals: MotorSignals) -> float:
    """Motor angle at the throw's start, from every sample rather than the first alone.

    angle(t) = angle(0) + integral of the velocity, so each sample gives an
    estimate of angle(0); their mean is far less noisy than the first sample
    (a wrong start angle shifts the rod and looks like a bolt offset).
    """
    velocity = signals.velocity_rad_s
    travelled = np.concatenate([[0.0], np.cumsum(0.5 * (velocity[1:] + velocity[:-1]) * np.diff(t_s))])
    return float(np.mean(signals.angle_rad - travelled))


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
    if not throw.signals.all_finite() or not np.all(np.isfinite(throw.t_s)):
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
        m = Measurement(throw.direction, throw.reference, throw.signals[1:], start_angle(throw.t_s, throw.signals),
                        start_rail, self.background(throw.direction))
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

