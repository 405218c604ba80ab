"""Fault detection and isolation from one switch's throws (paper, section "Fault diagnosis").

Per throw: every hypothesis is fitted (models/diagnosis/estimation.py), then a fault mode
is detected when its fit explains significantly more than the nominal fit. The
significance is an F test whose degrees of freedom come from the residual
itself: model error is smooth, not white, so the number of independent
residuals is estimated from the residual's autocorrelation (Geyer's initial
positive sequence). With white measurement noise that number is the sample
count; with a smooth model-error residual it is small and the test strict. The
threshold is therefore derived from the measured residual, never tuned per case.

A fault persists, so its evidence adds up over the throws that can see it: the
statistics of the last k such throws (k up to EVIDENCE_THROWS) are summed and held
against the chi-square critical value of their summed degrees of freedom at the
same false-alarm rate (shared between the k tried), so a fault that each of two
throws shows at two thirds of the one-throw threshold is found. Only what a throw's
own samples add is summed: the part of a fit's gain that comes from its priors (a
hypothesis that frees a parameter the nominal one holds to the population, or to the
switch's baseline, saves that prior's charge) is the same knowledge in every throw,
so it counts once, in the latest throw. Summed, it made a healthy switch whose chairs
are two standard deviations drier than the population's read as a missing bearing
after three throws that each showed it at half the threshold. A bolt only drives
the blades in one direction (the left bolt from left to right), so a throw can show
only the bolt that drives it.

A detected departure is a fault only when it is larger than a healthy switch may be set up
with: an adjuster set within a few millimetres of its mark is an adjustment, not a fault (the
caller names the modes whose fitted size is that small).
"""
from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
from scipy import special

from railswitch.models.diagnosis.estimation import DRIVING_BOLT, WITHOUT, Estimate
from railswitch.schemas.faults import MODE_PARAMETERS

FALSE_ALARM_RATE = 1e-3  # per fault mode and throw, under the nominal hypothesis
MODEL_ERROR_MARGIN = 2.0  # model error varies from throw to throw: allow twice what commissioning saw
OTHER_DIRECTION = {"left_to_right": "right_to_left", "right_to_left": "left_to_right"}
EVIDENCE_THROWS = 3  # the most recent throws whose evidence for a mode is added up
# Two fault modes that both explain a throw are told apart when the better one's advantage is significant at this
# rate; otherwise the throw's direction cannot separate them, and the next throw of the other direction decides.
SEPARATION_RATE = 0.01
# A current-only throw teaches a switch's baseline only when it suspects no fault mode at this rate on that throw alone:
# its samples hardly tell a fault from the switch's own build, so the healthy hypothesis must fit because the throw is a
# healthy switch's, not because the priors prefer it (a current-only throw of a 4200 N·s/m bearing fitted the bearing
# at 0.85 of the detection threshold, the healthy switch with chairs 2.3 times as dry and rolling losses 2.3 population
# std high, both alike to the residual; with angle and velocity the same throws showed the bearing).
SUSPICION_RATE = 0.01


@dataclass(frozen=True)
class Evidence:
    """How much better a fault mode fits than nominal: its test statistic over the critical value (the best
    over the last throws that saw it), and this throw's statistic (p times F, chi-square-like) to add up later."""

    mode: str
    ratio: float  # above 1: detected
    statistic: float = 0.0
    dof: int = 1
    own: float = 0.0  # the statistic without the priors' part: what this throw's samples add to later throws'
    suspicion: float = 0.0  # this throw's statistic over its critical value at SUSPICION_RATE

    @property
    def detected(self) -> bool:
        return self.ratio > 1.0

    @property
    def suspected(self) -> bool:
        """Whether this throw alone makes the mode likely enough that the throw is not a healthy switch's beyond doubt:
        what a current-only throw must not be to teach a switch's baseline."""
        return self.suspicion > 1.0


def accumulated(latest: Evidence, earlier: list[Evidence]) -> Evidence:
    """`latest` with its ratio the best of this throw's own test and the sums over it and the throws before
    (most recent first; their samples' part only), each against chi-square at FALSE_ALARM_RATE shared by the
    windows tried."""
    best = latest.ratio
    windows = min(len(earlier), EVIDENCE_THROWS - 1)
    total, dof = latest.statistic, latest.dof
    for previous in earlier[:windows]:
        total, dof = total + previous.own, dof + previous.dof
        critical = special.chdtri(dof, FALSE_ALARM_RATE / EVIDENCE_THROWS)  # chi-square's upper quantile
        best = max(best, total / critical)
    return Evidence(latest.mode, best, latest.statistic, latest.dof, latest.own, latest.suspicion)


def evidence(estimates: dict[str, Estimate], mode: str, model_gain: float = 0.0) -> Evidence:
    """F test of `mode` against the nominal fit (the switch as it now is), on the effective number of residuals."""
    return compare(estimates[mode], estimates["nominal"], mode, len(MODE_PARAMETERS[mode]), model_gain)


def presence(estimates: dict[str, Estimate], mode: str, model_gain: float = 0.0) -> Evidence:
    """F test of the switch as it now is (with its present fault `mode`) against the same switch without that fault
    (the hypothesis WITHOUT + mode, the fault's parameters at their reference): is the fault still there?"""
    return compare(estimates["nominal"], estimates[WITHOUT + mode], mode, len(MODE_PARAMETERS[mode]), model_gain)


def separable(estimates: dict[str, Estimate], best: str, other: str) -> bool:
    """Whether `best` fits the throw significantly better than `other` (both fault modes added to the switch as it
    now is): their objectives' difference over the residual variance per effective sample, against chi-square's
    upper quantile at SEPARATION_RATE (one degree of freedom: the two explain the same change)."""
    fitted, rival = estimates[best], estimates[other]
    n = fitted.effective_samples
    if n <= 2 or fitted.mse <= 0:
        return rival.objective > fitted.objective
    statistic = (rival.objective - fitted.objective) / (fitted.mse / (n - 1))
    return statistic > special.chdtri(1, SEPARATION_RATE)


def compare(fitted: Estimate, nominal: Estimate, mode: str, p: int, model_gain: float = 0.0) -> Evidence:
    """F test of a fit that frees `p` more parameters (those of `mode`) against `nominal`, which holds them at their
    reference, on the effective number of residuals.

    The samples' part of the statistic is the fit's gain in MSE over the residual variance
    per effective sample; the priors' part is what the mode's fit saves of the priors' charge,
    already a sum of squared standard scores (a nuisance the nominal fit must hold three
    population standard deviations out adds 9, however large the model's error). `model_gain`
    is what the mode's fit gains on healthy throws by absorbing model error (measured at
    commissioning); only the gain beyond twice that counts.
    """
    n = fitted.effective_samples
    data = nominal.mse - fitted.mse - MODEL_ERROR_MARGIN * model_gain
    prior = nominal.prior_charge - fitted.prior_charge  # chi-square-like already: sum of (value - mean)^2 / std^2
    if n <= p + 1 or fitted.mse <= 0:
        found = 0.0 if data + prior <= 0 else np.inf
        return Evidence(mode, found, found, p, 0.0 if data + min(prior, 0.0) <= 0 else np.inf, found)
    samples = data / (fitted.mse / (n - p))  # the samples' part, p times F
    statistic = max(samples + prior, 0.0)
    critical = special.fdtri(p, n - p, 1.0 - FALSE_ALARM_RATE / EVIDENCE_THROWS)  # F's quantile
    own = max(samples + min(prior, 0.0), 0.0)
    suspicion = statistic / p / special.fdtri(p, n - p, 1.0 - SUSPICION_RATE)
    return Evidence(mode, statistic / p / critical, statistic, p, own, suspicion)


def candidate_modes(direction: str) -> list[str]:
    """Modes a throw in `direction` can show: the bolt that drives it, bearings, obstacles."""
    return [m for m in MODE_PARAMETERS if m != DRIVING_BOLT[OTHER_DIRECTION[direction]]]


def healthy_gains(estimates: dict[str, Estimate]) -> dict[str, float]:
    """What each mode's fit gains in MSE over the nominal one (0 at least): on a healthy throw, model error it
    absorbs."""
    return {mode: max(estimates["nominal"].mse - estimates[mode].mse, 0.0) for mode in estimates
            if mode in MODE_PARAMETERS}


def judge(direction: str, estimates: dict[str, Estimate], model_gains: dict[str, float] | None = None,
          earlier: dict[str, list[Evidence]] | None = None,
          negligible: Collection[str] = ()) -> tuple[str, dict[str, Evidence]]:
    """The detected mode with the best fit, or nominal when none is detected; `earlier` holds each mode's
    evidence from the switch's previous throws that could see it, most recent first. A mode in `negligible`
    (its fitted size within what a healthy switch is set up with) keeps its evidence but is not a fault."""
    gains = model_gains or {}
    found = {m: accumulated(evidence(estimates, m, gains.get(m, 0.0)), (earlier or {}).get(m, []))
             for m in candidate_modes(direction) if m in estimates}
    detected = [m for m, e in found.items() if e.detected and m not in negligible]
    return (min(detected, key=lambda m: estimates[m].objective) if detected else "nominal"), found
