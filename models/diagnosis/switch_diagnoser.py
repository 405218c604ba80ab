"""One switch diagnosed throw by throw, against its own commissioned baseline (paper, section "Fault diagnosis").

A real switch is not the reduced model's twin: its motor, supply, point-machine friction
and slide chairs differ from the nominal ones and change with the weather. So every
hypothesis frees, beside its fault parameters, what the population lets vary and the
reduced model can show:

- the switch's own weather (winding resistance, supply, slide-chair Coulomb friction): free
  in every throw, the resistance and supply with the population as their prior; the chairs'
  friction once commissioned with the switch's own recent level as the prior's mean and DRIFT of
  it as its spread, so that chairs drying out over many throws are followed while a sudden change
  is not explained away; the level follows each throw that shows nothing new as far as its samples
  say the change is the chairs' and not a bearing's (_follow_chairs, docs/method.md);
- its healthy levels of two fault-like parameters, the extra rail damping that the
  bearing fault adds to (rolling losses differ from switch to switch) and the point
  machine's Coulomb friction that the drive-friction fault adds to: free with the
  population as their prior until the switch is commissioned, with its own baseline after.

A prior charges a fit for straying (models/diagnosis/estimation.py HypothesisSpec), so a switch is
called healthy when its throw is what a plausible member of the population (or, once
commissioned, the switch itself) would do, not whatever the nuisances could be bent to.

Commissioning: the first `needed` throws each way that are healthy against the population
teach the switch's baseline (the levels above and how much each fault mode's fit gains on
a healthy throw by absorbing model error). Until then decisions are provisional, judged
against the population. A fault is a departure the free parameters cannot explain:
bearing friction and drive friction are reported as departures from the baseline.

A switch's state is a set of present faults (models/diagnosis/fault_set.py). Each throw checks that it
can be diagnosed, estimates where it starts (the motor angle from every sample, the blades where
the previous throw's fit left them), fits the switch as it now is (its present faults free), the
same plus each mode it does not have and the same without each present fault (a bolt only in the
throws it drives; the other bolt is held at its latest estimate), judges them (models/diagnosis/isolation.py)
and adds or repairs faults. Each present fault's size combines every throw since it was confirmed
that can see it, weighted by their own variances, with the model's error (which does not average
out) added once. A switch that cannot be commissioned as healthy says so, and an operator may
accept it as it is (SwitchDiagnoser.accept).
"""
from __future__ import annotations

import copy
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import stats

from railswitch.models.plant.drive import DriveParams
from railswitch.models.diagnosis.estimation import DRIVING_BOLT, WITHOUT, Estimate, HypothesisSpec, Measurement, ThrowEstimator
from railswitch.models.health.features import BAND_FLOOR, PROFILE_BINS, STILL_SHARE, FeatureTrends, stroke_profile, throw_features
from railswitch.models.diagnosis.fault_set import (
    MAGNITUDE,
    RETURN_SIGMAS,
    Fault,
    Undecided,
    decide_between,
    describe_standing,
    observable,
    repaired,
    size_of,
)
from railswitch.models.health.prognosis import TRACKED, Health, HealthTracker
from railswitch.models.diagnosis.isolation import (
    EVIDENCE_THROWS,
    FALSE_ALARM_RATE,
    MODEL_ERROR_MARGIN,
    OTHER_DIRECTION,
    Evidence,
    candidate_modes,
    healthy_gains,
    judge,
    presence,
    separable,
)
from railswitch.models.plant.population import COPPER_PER_K, credible_range, resistance_at, spread
from railswitch.models.reduced.hybrid import NUISANCES
from railswitch.models.plant.reference import DIRECTIONS
from railswitch.models.plant.signals import MotorSignals, ThrowInput
from railswitch.schemas.faults import FAULT_PARAMETERS, MODE_PARAMETERS
from railswitch.schemas.plant import PLANT_PARAMETERS

CLOSED_START_M = {"left_to_right": 1.0, "right_to_left": 1.2}  # where a throw starts when the last one closed
SHORT_START_M = 0.002  # a throw starting further than this from the stock rail starts short (SwitchDiagnoser._judged)
# An obstacle fitted this close to where a throw's own loose bolt stops the blades short is that stroke end (within half
# an obstacle's width: the ones seen sat within 1 mm of it; a real one 12 mm from it was found).
STROKE_END_M = 0.006
OBSTACLE_REACH_M = 0.024  # an obstacle drags the blades within two of its widths (models/plant/faults.py: 12 mm) either side
GAP_TOLERANCE = 0.25  # of a sample period, for "the samples are evenly spaced"
# A throw ends when the point machine detects its end position, earlier or later than its reference profile
# ends; it is cut short only when it ends while the motor is still asked to turn (or, where measured, still
# turns) at more than STILL_SHARE of its top speed (models/health/features.py: where the motor has stopped).
# The throws a decided fault's size is combined over: those since it appeared, at most the latest TRACKED_THROWS (ten
# days of a switch's throws). Each throw of a fault left in place adds to its switch's memory (a Tracked: the
# fault's few parameters; figures in docs/results.md, benchmarks.memory); combined over so many, the model's error, whose
# common part does not average out (ErrorModel.std), is what the combined size's std holds.
TRACKED_THROWS = 1000
MAX_THROW_S = 30.0  # longer than any point machine's throw, stalled or not
COMMISSIONING_THROWS = 4  # healthy throws each way that make a switch's baseline (at most 6 are asked for)
# Fault-like parameters with a healthy level per switch: the extra rail damping of the bearing port and
# the point machine's Coulomb friction.
BASELINED = ("bearing_friction", "motor.coulomb_friction_nm")
# Free in every throw, with the population as prior: the winding's resistance (its temperature) and the chairs'
# Coulomb friction (lubrication, ice). The supply shows only while the controller saturates, which only a
# near-stall obstacle makes it do: free in those hypotheses. A unit's torque constant is constant, and what it
# does (the current scaled by a few per cent) the baselined levels absorb.
FOLLOWED = ("motor.resistance_ohm", "rail.chair_friction_coefficient")
SATURATION = ("motor.supply_v",)
# A commissioned level's standard deviation as a prior: its spread over the healthy throws, at least this
# (what a healthy switch may still vary by from throw to throw).
BASELINE_FLOOR = {"bearing_friction": 300.0, "motor.coulomb_friction_nm": 0.006}
# The rolling losses of a switch's chairs (schemas/plant.py) act like bearing friction at the drive point:
# per node the same viscous friction, i.e. bearing friction = delta per chair x sum of shape^2 (37.8).
CHAIR_TO_BEARING = 37.8
# The chairs' Coulomb coefficient and the bearing friction do nearly the same to a throw (their sensitivities' cosine
# is 0.987): what a unit of the one does, 1.006e5 N·s/m of the other does (the first's sensitivity projected on the
# second's over a nominal throw; the same within 0.5 % for every representation, direction and bearing level). A
# throw tells their sum, not their split; the split comes from the priors.
CHAIRS_AS_BEARING = 1.006e5
OUTSIDE_SIGMAS = 4.0  # a commissioned level this far from the population's mean is reported
DRIFTING = "rail.chair_friction_coefficient"
DRIFT = 0.1  # how much the chairs' friction may change from its recent level in one throw (a fraction of it),
# beyond what its estimates scatter from throw to throw on the healthy switch
FOLLOW = 0.5  # the weight of each healthy throw in the recent level
BOUND_SIGMAS = 5.0  # a commissioned level's hard limits, in its standard deviations
# An adjuster bolt set within this of its mark is a healthy switch's adjustment, not a fault (a bolt's fitted
# offset this small is not reported as one): the setting tolerance of a few millimetres a fitter works to, and
# about what the model's error reads as a bolt on a healthy switch unlike the nominal one (a machine type
# stroking 30 % slower reads -3 mm on both bolts; the worst population switch on nn up to 4 mm).
BOLT_TOLERANCE = 0.005
# A bolt read tighter than its mark by less than this, on a switch with another present fault, is no fault either. The
# reduced model's contact between rod and adjuster is four times softer than a real bolt's (ReducedParams:
# 2.5e5 N/m along the rod, for its 10 ms step), so what another fault adds to the force that starts the blades delays
# them in the model, and the fit makes up for it with a tighter bolt: 5 to 8 mm beside a missing bearing, an
# obstacle, drive friction or a loose bolt of the other direction (which leaves the next throw starting short), always
# tight, never loose (poly, benchmarks.aging's stacked sequences).
TIGHT_TOLERANCE = 0.010
# A throw that starts with the blades short of the stock rail (a loose bolt of the other direction, or an obstacle that
# stalled them, left them there) reads its own bolt within this share of how far short it started, in rod travel (the
# blades' times the linkage ratio), of its truth either way (SwitchDiagnoser._judged says why): 4 mm tight beside a
# 50 mm left bolt (a tenth of the shortfall), 6 to 44 mm loose beside right bolts of 116 to 186 mm (causal,
# benchmarks.fleet seed 1: up to three tenths). A bolt that small there is not told from none.
SHORT_SHARE = 0.35
# An obstacle fitted below this friction is no fault: on healthy switches the obstacle's hypothesis reads the model's
# error as one of 2000 to 2600 N·s/m at an end of the travel, and on a switch whose rollers lose 1.8 times the
# population's, as 3500 to 4000 (seen with poly); a third of its maintenance limit (models/health/prognosis.py), a tenth of the
# smallest obstacle any benchmark or test injects.
OBSTACLE_TOLERANCE = 10_000.0
# How far a missing bearing's fit may go beyond the contract's range: a switch whose rollers lose twice what the
# population's do (a standing condition) reads as about 11 000 N·s/m of bearing friction before it is accepted.
BEARING_REACH = 1.5
# A switch's own quantity that no fault mode names is an anomaly when the fit puts it at its credible bound (within
# AT_BOUND of the range) from a commissioned level well inside it, or moves it further than the weather can: from its
# commissioned level, more than the winding's temperature spans over a year (-25 … +55 °C: models/plant/population.py); from
# its recent level, more than a day's swing with the winding's own warming (30 K). A switch thrown less often than
# daily may see more between two throws. Downwards each allows the supply's tolerance too: a supply below its usual
# reads as a lower resistance (the drive gives less current for the same demand), and a healthy switch's supply may sit
# anywhere within +-10 % of its nominal (models/plant/population.py).
# A throw no hypothesis explains is an anomaly: the best fit's residual (its MSE over its effective samples) beyond
# MODEL_ERROR_MARGIN times what the switch's commissioning throws left, at the chi-square quantile of its effective
# samples at FALSE_ALARM_RATE (models/diagnosis/isolation.py: the same test a fault's detection makes).
ANOMALOUS = "motor.resistance_ohm"
AT_BOUND = 0.005
SEASON = resistance_at(55.0) / resistance_at(-25.0)
DAY_SWING = COPPER_PER_K * 30.0
SUPPLY_TOLERANCE = 0.1
BOLT_GRID = tuple(np.round(np.arange(-0.02, 0.2001, 0.02), 4))
OBSTACLE_GRID = tuple({"obstacle_position": round(float(p), 3), "obstacle_friction": f}
                      for p in np.arange(1.02, 1.1801, 0.02) for f in (3e4, 1.5e5))
# A gearbox that binds at one point of the stroke loads the motor there, and at the same motor angle whichever way the
# switch throws; the reduced models have no such load and read it as an obstacle, a bearing or drive friction. Its
# mark in the stroke's current profile against the commissioning throws' (models/health/features.py): in both directions a
# rise above BAND_FLOOR of the commissioned peak current where it is highest, LOCAL times its mean rise over the
# stroke (a load along the whole stroke raises it alike: drive friction evenly, a missing bearing, whose friction
# follows the blades' speed, mid-stroke at about twice its mean; a bell a tenth of the stroke wide, about ten times),
# the two highest within SAME_PLACE of the stroke of each other. A blade obstacle's lie the adjuster's free play apart,
# on the rod twice 40 mm of its 488 mm stroke, 0.16 (0.12 beside the tightest bolt of BOLT_GRID); a binding gearbox's,
# only the speed loop's lag apart (within 0.035 in the plant).
LOCAL = 3.0
SAME_PLACE = 0.06
# A settled throw's (models/diagnosis/estimation.py SETTLED): an obstacle that appears without changing the throw is a small one.
SMALL_OBSTACLE_GRID = tuple(point for point in OBSTACLE_GRID if point["obstacle_friction"] == 3e4)


def small(mode: str, departures: dict[str, float], loaded: bool = False, short_m: float = 0.0) -> bool:
    """Whether a fault of `mode` this size (its parameters' departures from their marks, the model's bias taken off)
    is no fault: a bolt within BOLT_TOLERANCE of its mark (an adjustment), or read tight by less than TIGHT_TOLERANCE
    on a switch `loaded` by another present fault, and within SHORT_SHARE of how far short (`short_m`, in rod metres)
    the throw started more either way; an obstacle below OBSTACLE_TOLERANCE (what the model's error reads as one)."""
    if mode in DRIVING_BOLT.values():
        offset = departures[MODE_PARAMETERS[mode][0]]
        start = SHORT_SHARE * abs(short_m)
        return -(TIGHT_TOLERANCE if loaded else BOLT_TOLERANCE) - start < offset < BOLT_TOLERANCE + start
    if mode == "obstacle":
        return departures["obstacle_friction"] < OBSTACLE_TOLERANCE
    return False


@dataclass(frozen=True)
class ErrorModel:
    """The reduced model's error on each fault parameter, measured against the plant over the population
    (`railswitch calibrate`): a bias (its median, constant + proportional to the value), taken off every
    estimate, and what is left as a standard deviation, absolute + relative * |value|, for an estimate
    combined over `throws[name]` throws. Part of the error differs from throw to throw (the two directions see
    an obstacle differently; the weather moves the nuisances) and averages out; the rest is the same in every
    throw and does not. `one_absolute` and `one_relative` give the error of a single throw's estimate, and the
    two envelopes split into a common part and a per-throw part that falls as 1/sqrt(throws).

    `unit_relative` is the part no fit can see and no calibration case should be trusted to sample: the point
    machine's own torque constant (unit-to-unit, 2 % in the population) scales every force the model reads
    through the motor current, so a friction or a missing bearing reads as its value times the nominal constant
    over the unit's own. It is the same in every throw of the switch, taken from the population's spread, and
    added to the common part; the calibration's envelopes measure the rest (services/core/calibration.py)."""

    absolute: dict[str, float] = field(default_factory=dict)
    relative: dict[str, float] = field(default_factory=dict)
    bias: dict[str, float] = field(default_factory=dict)
    bias_relative: dict[str, float] = field(default_factory=dict)
    one_absolute: dict[str, float] = field(default_factory=dict)
    one_relative: dict[str, float] = field(default_factory=dict)
    throws: dict[str, float] = field(default_factory=dict)  # how many throws the envelope above was measured on
    unit_relative: dict[str, float] = field(default_factory=dict)  # relative std, common to every throw

    def std(self, name: str, value: float, throws: int = 1) -> float:
        """The model's error of an estimate combined over `throws` throws that see the parameter."""
        common, per_throw = self._variances(name, value)
        return float(np.sqrt(common + per_throw / max(throws, 1)))

    def common(self, name: str, value: float) -> float:
        """The part of the model's error that is the same in every throw: what no number of throws removes."""
        return float(np.sqrt(self._variances(name, value)[0]))

    def _variances(self, name: str, value: float) -> tuple[float, float]:
        """(common, per-throw) variances at `value`: the envelopes' and the unit's, which is common."""
        common, per_throw = self._envelopes(name, value)
        return common + (self.unit_relative.get(name, 0.0) * value) ** 2, per_throw

    def _envelopes(self, name: str, value: float) -> tuple[float, float]:
        """(common, per-throw) variances at `value`, from the envelopes over one throw and over `throws[name]`."""
        many = self.absolute.get(name, 0.0) + self.relative.get(name, 0.0) * abs(value)
        measured = self.throws.get(name, 1.0)
        if name not in self.one_absolute or measured <= 1.0:
            return many**2, 0.0
        one = self.one_absolute[name] + self.one_relative.get(name, 0.0) * abs(value)
        if one <= many:  # nothing averages out (within the calibration's sampling)
            return many**2, 0.0
        per_throw = min(one**2, (one**2 - many**2) * measured / (measured - 1.0))
        return one**2 - per_throw, per_throw

    def slope(self, name: str) -> float:
        """1 + r of estimate = truth(1 + r) + b: what a departure in the truth reads as in the estimate."""
        return 1.0 + self.bias_relative.get(name, 0.0)

    def corrected(self, name: str, estimate: float) -> float:
        """The estimate less the model's bias: (estimate - b) / (1 + r) inverts estimate = truth(1 + r) + b."""
        return (estimate - self.bias.get(name, 0.0)) / self.slope(name)


@dataclass(frozen=True)
class Population:
    """What the diagnosis expects of a switch it has not commissioned yet."""

    prior: dict[str, tuple[float, float]]  # mean and standard deviation of the nuisance and baselined parameters
    bounds: dict[str, tuple[float, float]]  # their credible ranges: hard limits
    gains: dict[str, dict[str, float]]  # per direction and mode: the MSE gain on a healthy throw (model error)
    model_weight: float  # healthy throws' nominal MSE over effective samples (models/diagnosis/estimation.py fit_all)


LOG_PRIOR = ("rail.chair_friction_coefficient", "motor.coulomb_friction_nm")  # skewed, positive: priors on log


def population(gains: dict[str, dict[str, float]] | None = None, model_weight: float = 0.0) -> Population:
    """The population of models/plant/population.py, in the reduced model's parameters (the chairs' and the point
    machine's friction on a log scale); `gains` and `model_weight` come from the reduced model's calibration on
    healthy switches of the population."""
    prior = {name: spread(name, log=name in LOG_PRIOR) for name in NUISANCES}
    bounds = {name: credible_range(name) for name in NUISANCES}
    chairs_mean, chairs_std = spread("rail.chair_viscous_n_s_m")
    nominal = PLANT_PARAMETERS["rail.chair_viscous_n_s_m"].nominal
    prior["bearing_friction"] = ((chairs_mean - nominal) * CHAIR_TO_BEARING, chairs_std * CHAIR_TO_BEARING)
    low, high = credible_range("rail.chair_viscous_n_s_m")
    bounds["bearing_friction"] = ((low - nominal) * CHAIR_TO_BEARING, (high - nominal) * CHAIR_TO_BEARING)
    return Population(prior, bounds, gains or {d: {} for d in DIRECTIONS}, model_weight)


@dataclass
class Baseline:
    """A switch's commissioning: the nominal fit's baselined values and each mode's gain on its healthy throws, and
    what an operator accepted as the switch's own (`railswitch commission SW --accept`)."""

    needed: int = COMMISSIONING_THROWS
    healthy: dict[str, list[dict]] = field(default_factory=lambda: {d: [] for d in DIRECTIONS})
    recent: dict[str, float] = field(default_factory=dict)  # drifting nuisances' recent levels (DRIFTING)
    # Accepted standing conditions: what each baselined parameter's level is beside the population's (before
    # commissioning) or beside its healthy throws (after: they are kept relative to it, so a later acceptance moves
    # the level by what it adds); the marks of the bolts and an obstacle (where the switch as it is has them); and
    # each accepted mode's departures as accepted, for the record.
    shift: dict[str, float] = field(default_factory=dict)
    marks: dict[str, float] = field(default_factory=dict)
    accepted: dict[str, dict[str, float]] = field(default_factory=dict)
    # Its summaries (level, gains, model_weight), by what they summarise and how many healthy throws there were: a
    # commissioned switch's never change, and every throw's hypotheses read them some 24 times (a noticeable share of
    # a settled throw's time). Healthy throws are only ever appended (add), so the count names the throws summarised.
    _summaries: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def _summary(self, key: tuple, throws: int, compute: Callable[[], object]):
        cached = self._summaries.get(key)
        if cached is None or cached[0] != throws:
            cached = self._summaries[key] = (throws, compute())
        return cached[1]

    def count(self, direction: str) -> int:
        return len(self.healthy[direction])

    @property
    def complete(self) -> bool:
        return all(self.count(d) >= self.needed for d in DIRECTIONS)

    def add(self, direction: str, levels: dict[str, float], gains: dict[str, float], model_weight: float) -> None:
        if self.count(direction) < self.needed:
            relative = {name: value - self.shift.get(name, 0.0) for name, value in levels.items()}
            self.healthy[direction].append({"levels": relative, "gains": gains, "model_weight": model_weight})

    def model_weight(self) -> float:
        """The median over the healthy throws of the nominal fit's MSE over its effective samples."""
        return self._summary(("model_weight",), sum(map(self.count, DIRECTIONS)), lambda: float(
            np.median([h["model_weight"] for d in DIRECTIONS for h in self.healthy[d]])))

    def level(self, direction: str, name: str) -> tuple[float, float]:
        """Mean and spread of a baselined parameter over the healthy throws of a direction (with what was accepted)."""
        def compute() -> tuple[float, float]:
            values = np.array([h["levels"][name] for h in self.healthy[direction] if name in h["levels"]])
            if not len(values):
                return float("nan"), 0.0
            return float(values.mean()), float(values.std(ddof=1)) if len(values) > 1 else 0.0
        mean, spread_ = self._summary(("level", direction, name), self.count(direction), compute)
        return mean + self.shift.get(name, 0.0), spread_

    def gains(self, direction: str) -> dict[str, float]:
        return dict(self._summary(("gains", direction), self.count(direction), lambda: {
            mode: max(h["gains"].get(mode, 0.0) for h in self.healthy[direction]) for mode in MODE_PARAMETERS}))

    def follow(self, name: str, value: float, weight: float = 1.0) -> None:
        """Move a drifting nuisance's recent level towards a healthy throw's estimate, by FOLLOW times `weight`."""
        previous = self.recent.get(name)
        self.recent[name] = value if previous is None else previous + weight * FOLLOW * (value - previous)

    def to_dict(self) -> dict:
        return {"needed": self.needed, "healthy": self.healthy, "recent": self.recent, "shift": self.shift,
                "marks": self.marks, "accepted": self.accepted}

    @classmethod
    def from_dict(cls, data: dict) -> Baseline:
        baseline = cls(int(data["needed"]))
        for direction in DIRECTIONS:
            baseline.healthy[direction] = [dict(h) for h in data["healthy"].get(direction, [])]
        for name in ("recent", "shift", "marks"):  # a state saved before they were kept has none
            setattr(baseline, name, {k: float(v) for k, v in data.get(name, {}).items()})
        baseline.accepted = {mode: {k: float(v) for k, v in values.items()}
                             for mode, values in data.get("accepted", {}).items()}
        return baseline


def start_angle(t_s: np.ndarray, signals: MotorSignals, direction: str, drive: DriveParams) -> float:
    """Motor angle at the throw's start, from every sample rather than the first alone.

    angle(t) = angle(0) + integral of the velocity, so each sample gives an
    estimate of angle(0); their mean is far less noisy than the first sample
    (a wrong start angle shifts the rod and looks like a bolt offset). Without
    angle and velocity (a current-only unit), the crank's dead centre the throw
    starts from: there the rod hardly moves with the angle, so little is lost.
    """
    velocity = signals.velocity_rad_s
    if signals.angle_rad is None:
        return 0.0 if direction == "left_to_right" else drive.throw_angle_rad
    if velocity is None:
        return float(signals.angle_rad[0])
    travelled = np.concatenate([[0.0], np.cumsum(0.5 * (velocity[1:] + velocity[:-1]) * np.diff(t_s))])
    return float(np.mean(signals.angle_rad - travelled))


def settled_mse(previous: ThrowVerdict | None, m: Measurement, base: frozenset[str]) -> float | None:
    """The nominal fit's MSE on the switch's previous throw in this direction, when that throw showed nothing new, was
    fitted with the same present faults (`base`) and measured the same signals (ThrowEstimator.fit_all: a throw whose
    nominal fit is within SETTLED of it is settled)."""
    if previous is None or previous.mode != "nominal" or previous.base != base:
        return None
    nominal = previous.estimates["nominal"]
    return nominal.mse if nominal.residual.shape[1] == len(m.signals.names) else None


def measurement(throw: ThrowInput, start_rail_m: float, drive: DriveParams = DriveParams()) -> Measurement:
    """What the estimator fits: the samples after the start, from the start's angle and the given rail position."""
    return Measurement(throw.direction, throw.reference, throw.t_s[1:], throw.signals[1:],
                       start_angle(throw.t_s, throw.signals, throw.direction, drive), start_rail_m)


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
    if throw.duration_s > MAX_THROW_S:
        return f"throw lasted {throw.duration_s:.1f} s, longer than any point machine's ({MAX_THROW_S:g} s)"
    return cut_short(throw)


def cut_short(throw: ThrowInput) -> str | None:
    """Why the throw looks cut off while the rails were still moving, or None when they had stopped."""
    commanded = np.abs(throw.reference.velocity_rad_s)
    top = float(commanded.max())
    if abs(float(throw.reference(throw.duration_s))) > STILL_SHARE * top:
        last_moving = int(np.flatnonzero(commanded > STILL_SHARE * top)[-1])
        stops = float(throw.reference.t_s[min(last_moving + 1, len(commanded) - 1)])
        return (f"throw ended at {throw.duration_s:.2f} s while its motor was still asked to turn "
                f"(its reference stops at {stops:.2f} s)")
    velocity = throw.signals.velocity_rad_s
    if velocity is not None and abs(float(velocity[-1])) > STILL_SHARE * max(top, float(np.max(np.abs(velocity)))):
        return f"throw ended at {throw.duration_s:.2f} s while its motor was still turning"
    return None


@dataclass(frozen=True)
class Reported:
    """A hypothesis as a diagnosis reports it: fault parameters as departures from the baseline, their
    standard deviations (the fit's and the model's error), what the throw cannot see, and the nuisances."""

    mode: str
    params: dict[str, float]
    std: dict[str, float]
    mse: float
    unobservable: tuple[str, ...] = ()
    nuisance: dict[str, float] = field(default_factory=dict)
    fit_std: dict[str, float] = field(default_factory=dict)  # the fit's own part of std


def modes_of(label: str, base: frozenset[str], direction: str) -> frozenset[str]:
    """The faults a hypothesis (SwitchDiagnoser.specs) is fitted with, on a throw with present faults `base`: those,
    one more, one fewer, or every mode the throw can show."""
    if label == "nominal":
        return base
    if label.startswith(WITHOUT):
        return base - {label[len(WITHOUT):]}
    if label == "joint":
        return frozenset(candidate_modes(direction))
    return base | {label}


@dataclass(frozen=True)
class ThrowVerdict:
    """What one throw says: the fault it shows beyond the switch's present ones (or nominal), the evidence for each
    mode and every hypothesis, fitted with the present faults it could see (`base`)."""

    index: int
    direction: str
    mode: str
    evidence: dict[str, Evidence]
    estimates: dict[str, Estimate]
    reported: dict[str, Reported]
    end_rail_m: float  # where the hypothesis that explains the throw leaves the blades
    fitted: dict[str, np.ndarray]  # that hypothesis's outputs at the samples after the start
    provisional: bool
    base: frozenset[str] = frozenset()

    def modes_of(self, label: str) -> frozenset[str]:
        """The faults a hypothesis of this throw was fitted with."""
        return modes_of(label, self.base, self.direction)

    def kept(self, slopes: bool = True) -> ThrowVerdict:
        """The verdict as its switch keeps it for the next throws (their warm starts, the slopes they borrow, what
        settles them): without the fits' residuals, the fitted outputs, the evidence and the reports, which no later
        throw reads (the switch keeps its own evidence, and a fault's track its Tracked), and with slopes only after
        a throw that showed nothing new, the only ones a later throw borrows (a settled throw follows such a one:
        ThrowEstimator.fit_all), and never without `slopes` (SwitchDiagnoser.lean)."""
        estimates = {mode: e.kept(slopes=slopes and self.mode == "nominal") for mode, e in self.estimates.items()}
        return replace(self, estimates=estimates, fitted={}, evidence={}, reported={})


@dataclass(frozen=True, slots=True)
class Tracked:
    """What combining a fault over its throws reads of one throw (SwitchDiagnoser.combine): the throw's index and
    the fault's parameters as that throw reported them, with the fit's own std, in MODE_PARAMETERS order. A switch
    keeps one per throw of each present fault, up to TRACKED_THROWS: a few numbers, not the throw's verdict."""

    index: int
    params: tuple[float, ...]
    fit_std: tuple[float, ...]

    @classmethod
    def of(cls, verdict: ThrowVerdict, mode: str, short_m: float = 0.0) -> Tracked:
        """`short_m`: how far short (rod travel) the throw started, when `mode` is its own bolt. Its reading may be
        off by up to that much (SwitchDiagnoser._held_short), so that is two of its standard deviations."""
        report = verdict.reported[mode]
        names = MODE_PARAMETERS[mode]
        return cls(verdict.index, tuple(float(report.params[n]) for n in names),
                   tuple(float(np.hypot(report.fit_std[n], short_m / 2.0)) for n in names))


@dataclass(frozen=True)
class Combined:
    """A fault's size combined over the throws since it appeared that can see it."""

    mode: str
    params: dict[str, float]
    std: dict[str, float]
    throws: int
    since_throw: int
    fit_std: dict[str, float] = field(default_factory=dict)  # the fits' own part of std


@dataclass(frozen=True)
class Outcome:
    """The switch's decision after a throw (its newest present fault, or nominal), why, this throw's verdict, the
    newest fault's combined size, the switch's health, every present fault and each one's combined size."""

    decision: str
    reason: str | None
    verdict: ThrowVerdict | None
    estimate: Combined | None
    health: Health | None = None
    faults: tuple[str, ...] = ()
    estimates: dict[str, Combined] = field(default_factory=dict)
    standing: str | None = None  # said once: the switch cannot be commissioned as healthy, and why
    features: dict[str, float | None] = field(default_factory=dict)  # the throw's (models/health/features.py)
    feature_health: list[dict] = field(default_factory=list)  # once commissioned: FeatureTrends.update's
    anomalies: list[dict] = field(default_factory=list)  # what no fault mode names (SwitchDiagnoser._anomalies)

    def named(self) -> str:
        """The present faults joined by '+', nominal, or unknown: as Diagnosis.named says it."""
        return "+".join(self.faults) or ("unknown" if self.decision == "unknown" else "nominal")


class SwitchDiagnoser:
    """Diagnoses one switch throw by throw; holds its baseline, present faults, latest verdicts and health."""

    def __init__(self, estimator: ThrowEstimator, prior: Population, errors: ErrorModel | None = None,
                 baseline: Baseline | None = None, limits: dict[str, float] | None = None, lean: bool = False):
        self.estimator = estimator
        # lean: keep no slopes for the next throw to borrow, so its settled throws' fits compute their first
        # Jacobian afresh: a switch keeps about half as much, each settled throw takes a little longer, and the
        # fits end where SLOPES_AGE 0 ends them (figures in docs/results.md, benchmarks.memory and .diagnosis)
        self.lean = lean
        self.prior = prior
        self.errors = errors or ErrorModel()
        self.baseline = baseline or Baseline()
        self.health = HealthTracker(limits)  # the model's error that stays, near the limit where a forecast ends
        self.health.model_error = {name: self.errors.common(name, self.health.limits[name]) for name in TRACKED}
        self.latest: dict[str, ThrowVerdict] = {}
        self.rail_m: float | None = None  # blades' position after the last diagnosed throw
        self.faults: dict[str, Fault] = {}  # the present faults, by mode
        self.undecided: Undecided | None = None
        self.evidence: dict[str, list[Evidence]] = {}  # per mode, from the latest throws that saw it, latest first
        self.standing: str | None = None  # why the switch cannot be commissioned as healthy, once said
        self._unchanged = dict.fromkeys(DIRECTIONS, 0)  # throws each way with the same faults, uncommissioned
        # an uncommissioned switch's latest throws each way that showed nothing new beside its present faults: what
        # its baseline becomes if an operator accepts it as it is (Baseline.add's records)
        self.candidates: dict[str, list[dict]] = {d: [] for d in DIRECTIONS}
        self.drive = estimator.reduced.params.plant.drive
        self.trends = FeatureTrends(self.baseline.needed)  # the throws' features, against their commissioning band
        self.anomalous_since: int | None = None  # the first throw of the anomalies the latest throws showed

    # -- commissioning ------------------------------------------------------------------------
    def restart_commissioning(self) -> None:
        """After maintenance: forget the baseline, what was accepted and the switch's history; learn it again."""
        self.baseline = Baseline(self.baseline.needed)
        self.trends.reset()
        self._forget()

    def _forget(self) -> None:
        self.anomalous_since = None
        self.latest.clear()
        self.faults.clear()
        self.evidence.clear()
        self.undecided = None
        self.standing = None
        self._unchanged = dict.fromkeys(DIRECTIONS, 0)
        self.candidates = {d: [] for d in DIRECTIONS}
        self.health.reset()

    def accept(self) -> dict[str, dict[str, float]]:
        """Take the switch as it now is as its own (`railswitch commission SW --accept`): each present fault's level
        becomes part of its baseline (a missing bearing's and the point machine's friction as the baselined levels'
        shift, a bolt's or an obstacle's parameters as its marks) and is recorded as accepted; health starts afresh
        from there, and more of the same is a fault again. An uncommissioned switch is commissioned from its latest
        throws that showed nothing new beside those faults (`candidates`: also those that fitted a fault about as
        well as a healthy switch, which its commissioning did not count), as far as there are enough of them, and
        from its next throws for the rest. Returns what was accepted (departures, as reported)."""
        accepted = {}
        provisional = not self.baseline.complete
        for mode, fault in self.faults.items():
            combined = self._combined(mode)
            accepted[mode] = (combined.params if combined is not None
                              else self._departures(mode, fault.values, self.latest_direction(mode)))
            if mode == "missing_bearing":
                b0 = self.level(self.latest_direction(mode), "bearing_friction")
                self._shift("bearing_friction", fault.values["bearing_friction"] - b0)
            elif mode == "drive_friction":
                self._shift("motor.coulomb_friction_nm", fault.values["drive_friction_nm"])
            else:
                self.baseline.marks.update({name: fault.values[name] for name in MODE_PARAMETERS[mode]})
            previous = self.baseline.accepted.get(mode, {})  # departures from what was accepted before add up
            self.baseline.accepted[mode] = {name: value + (previous.get(name, 0.0) if name != "obstacle_position"
                                                           else 0.0) for name, value in accepted[mode].items()}
        candidates = self.candidates
        if not accepted and not (provisional and any(candidates.values())):
            return accepted
        if provisional:  # its levels are the switch's as it is, kept relative to the shift (Baseline.add)
            if accepted:  # healthy throws counted before were judged without what is now accepted
                self.baseline.healthy = {d: [] for d in DIRECTIONS}
            for direction in DIRECTIONS:
                for record in candidates[direction]:
                    self.baseline.add(direction, **record)
            chairs = [r["levels"][DRIFTING] for d in DIRECTIONS for r in candidates[d]]
            if chairs:
                self.baseline.recent[DRIFTING] = float(np.mean(chairs))
        self._forget()
        return accepted

    def _shift(self, name: str, by: float) -> None:
        self.baseline.shift[name] = self.baseline.shift.get(name, 0.0) + by

    def latest_direction(self, mode: str) -> str:
        """A direction whose throws see `mode` (the bolt's own; else either)."""
        return next(d for d in DIRECTIONS if observable(mode, d))

    def _prior(self, direction: str, name: str) -> tuple[float, float]:
        """Mean and standard deviation a baselined parameter is expected at: the switch's own once commissioned
        (the population's, on log(value) for those in LOG_PRIOR, before), with what was accepted."""
        if not self.baseline.complete:
            mean, std = self.prior.prior[name]
            shift = self.baseline.shift.get(name, 0.0)
            if shift and name in LOG_PRIOR:
                return float(np.log(max(np.exp(mean) + shift, 1e-300))), std
            return mean + shift, std
        mean, spread_ = self.baseline.level(direction, name)
        return mean, max(spread_, BASELINE_FLOOR[name])

    def level(self, direction: str, name: str) -> float:
        """The level a baselined parameter is expected at, as a value (its prior's mean, back from log)."""
        mean = self._prior(direction, name)[0]
        return float(np.exp(mean)) if name in self._log_prior() else mean

    def _log_prior(self) -> tuple[str, ...]:
        """Which priors are on log(value): the population's skewed ones; once commissioned, the chairs' drift."""
        return (DRIFTING,) if self.baseline.complete else LOG_PRIOR

    def _bounds(self, direction: str, name: str, drift: tuple[float, float] | None) -> tuple[float, float]:
        """Where a nuisance or baselined parameter may go at all: the population's credible range (shifted by what was
        accepted), or BOUND_SIGMAS of the switch's own baseline once commissioned. The chairs, followed once
        commissioned (`drift`: their prior, _drift_prior), may also go BOUND_SIGMAS of their drift beyond their
        recent level (within the plant's range): chairs that dry out slowly leave the population's range, and there
        their drying must not become a fault."""
        if name == DRIFTING and drift is not None:
            low, high = self.prior.bounds[name]
            physical = PLANT_PARAMETERS[name]
            mean, std = drift
            return (max(min(low, float(np.exp(mean - BOUND_SIGMAS * std))), physical.low),
                    min(max(high, float(np.exp(mean + BOUND_SIGMAS * std))), physical.high))
        if name not in BASELINED or not self.baseline.complete:
            low, high = self.prior.bounds[name]
            shift = self.baseline.shift.get(name, 0.0) if name in BASELINED else 0.0
            return low + shift, high + shift
        mean, std = self._prior(direction, name)
        return mean - BOUND_SIGMAS * std, mean + BOUND_SIGMAS * std

    def _drift_prior(self) -> tuple[float, float] | None:
        """Once commissioned, the chairs' prior on log(value): their recent level, spread by DRIFT and by how
        their estimates scatter from throw to throw on the healthy switch."""
        if not self.baseline.complete or DRIFTING not in self.baseline.recent:
            return None
        recent = max(self.baseline.recent[DRIFTING], self.prior.bounds[DRIFTING][0])
        scatter = max(self.baseline.level(d, DRIFTING)[1] for d in DIRECTIONS)  # its throw-to-throw estimates
        return float(np.log(recent)), float(np.hypot(DRIFT, scatter / recent))

    def _gains(self, direction: str) -> dict[str, float]:
        return self.baseline.gains(direction) if self.baseline.complete else self.prior.gains.get(direction, {})

    def outside_population(self) -> list[str]:
        """Baselined parameters whose commissioned level lies outside the population's credible range (those an
        operator accepted aside)."""
        if not self.baseline.complete:
            return []
        out = []
        for name in BASELINED:
            if self.baseline.shift.get(name):
                continue
            mean, std = self.prior.prior[name]
            for d in DIRECTIONS:
                level = self.baseline.level(d, name)[0]
                level = np.log(max(level, 1e-300)) if name in LOG_PRIOR else level
                if abs(level - mean) > OUTSIDE_SIGMAS * std:
                    out.append(name)
                    break
        return out

    # -- hypotheses ---------------------------------------------------------------------------
    def present(self, direction: str) -> frozenset[str]:
        """The present faults a throw in `direction` can see (a bolt only in the throws it drives)."""
        return frozenset(mode for mode in self.faults if observable(mode, direction))

    def specs(self, direction: str) -> dict[str, HypothesisSpec]:
        """The hypotheses a throw in `direction` is fitted under: the switch as it now is ("nominal": its present
        faults that the throw can see, their parameters free), the same plus each fault mode it does not have, the
        same without each present fault (WITHOUT + mode: a repair), and every mode at once ("joint")."""
        base = self.present(direction)
        out = {"nominal": self._spec("nominal", direction, base)}
        for mode in candidate_modes(direction):
            if mode not in base:
                out[mode] = self._spec(mode, direction, base | {mode}, grid_of=mode)
        for mode in sorted(base):
            out[WITHOUT + mode] = self._spec(WITHOUT + mode, direction, base - {mode})
        out["joint"] = self._spec("joint", direction, frozenset(candidate_modes(direction)))
        return out

    def _spec(self, label: str, direction: str, modes: frozenset[str], grid_of: str | None = None) -> HypothesisSpec:
        """The hypothesis that the switch has the faults `modes` (their parameters free, within their ranges) and no
        others (held at their marks: a bolt's or an obstacle's reference, nominal unless accepted); the other
        direction's bolt held at its latest estimate. The switch's own parameters are free with their priors, but a
        baselined one a fault adds to: a missing bearing frees the bearing friction beyond its baseline, without
        its prior; drive friction holds the point machine's own friction at its baseline and frees the fault's.
        `grid_of`: the mode whose grid of starting points (and settled grid, and scan) the hypothesis takes."""
        bolt = DRIVING_BOLT[direction]
        bolt_name = MODE_PARAMETERS[bolt][0]
        other_name = MODE_PARAMETERS[DRIVING_BOLT[OTHER_DIRECTION[direction]]][0]
        drift = self._drift_prior()
        bounds = {name: self._bounds(direction, name, drift) for name in (*FOLLOWED, *SATURATION, *BASELINED)}
        prior = {**{name: self.prior.prior[name] for name in (*FOLLOWED, *SATURATION)},
                 **{name: self._prior(direction, name) for name in BASELINED}}
        if drift is not None:
            prior[DRIFTING] = drift
        fault = {n: (p.low, p.high) for n, p in FAULT_PARAMETERS.items()}
        free = {name: bounds[name] for name in (*FOLLOWED, *BASELINED)}
        held = {other_name: self.background(direction)}
        initial = {name: value for mode in modes & self.faults.keys() for name, value in self.faults[mode].values.items()}
        if bolt in modes:
            free[bolt_name] = fault[bolt_name]
        else:
            held[bolt_name] = self.mark(bolt_name)
        if "obstacle" in modes:
            free.update({n: fault[n] for n in MODE_PARAMETERS["obstacle"]})
            free.update({name: bounds[name] for name in SATURATION})
        else:
            held.update({n: self.baseline.marks[n] for n in MODE_PARAMETERS["obstacle"] if n in self.baseline.marks})
        if "missing_bearing" in modes:
            b0 = self.level(direction, "bearing_friction")
            free["bearing_friction"] = (b0 + fault["bearing_friction"][0], b0 + BEARING_REACH * fault["bearing_friction"][1])
            del prior["bearing_friction"]
        if "drive_friction" in modes:
            del free["motor.coulomb_friction_nm"], prior["motor.coulomb_friction_nm"]
            held["motor.coulomb_friction_nm"] = self.level(direction, "motor.coulomb_friction_nm")
            free["drive_friction_nm"] = fault["drive_friction_nm"]
        grid, settled_grid, scanned = (), None, ()
        if label == "nominal":  # each present fault back at its reference: a start where a repair would leave it (a
            # bolt set right sat 13 mm from its mark when fitted from its loose 77 mm, a basin the fit could not leave)
            grid = tuple(self._reference(direction, mode) for mode in sorted(modes))
        elif grid_of == bolt:
            grid, settled_grid, scanned = (tuple({bolt_name: float(b)} for b in BOLT_GRID),
                                           ({bolt_name: self.mark(bolt_name)},), (bolt_name,))
        elif grid_of == "missing_bearing":
            b0 = self.level(direction, "bearing_friction")
            grid, settled_grid = tuple({"bearing_friction": b0 + f} for f in (500.0, 2e3, 5e3, 1e4)), ()
        elif grid_of == "obstacle":
            grid, settled_grid = OBSTACLE_GRID, SMALL_OBSTACLE_GRID
        elif grid_of == "drive_friction":
            grid, settled_grid = tuple({"drive_friction_nm": f} for f in (0.02, 0.08, 0.2)), ()
        return HypothesisSpec(label, free, held, grid, prior, self._log_prior(), settled_grid=settled_grid,
                              scanned=scanned, initial=initial)

    def _reference(self, direction: str, mode: str) -> dict[str, float]:
        """A mode's parameters where the switch has no such fault: its baselined level or its marks."""
        if mode == "missing_bearing":
            return {"bearing_friction": self.level(direction, "bearing_friction")}
        if mode == "drive_friction":
            return {"drive_friction_nm": 0.0}
        if mode == "obstacle":
            return {"obstacle_friction": self.mark("obstacle_friction")}
        return {name: self.mark(name) for name in MODE_PARAMETERS[mode]}

    def mark(self, name: str) -> float:
        """Where a bolt or an obstacle parameter is when it is no fault: nominal, or where an operator accepted it."""
        return self.baseline.marks.get(name, FAULT_PARAMETERS[name].nominal)

    def background(self, direction: str) -> float:
        """The other direction's bolt: its present fault's latest estimate, else its mark."""
        other = DRIVING_BOLT[OTHER_DIRECTION[direction]]
        name = MODE_PARAMETERS[other][0]
        present = self.faults.get(other)
        return present.values[name] if present is not None else self.mark(name)

    def _departures(self, mode: str, values: dict[str, float], direction: str) -> dict[str, float]:
        """A mode's parameters as departures from the switch's baseline and marks (the model's values, uncorrected)."""
        out = {}
        for name in MODE_PARAMETERS[mode]:
            if name == "bearing_friction":
                out[name] = values[name] - self.level(direction, name)
            elif name == "obstacle_position" or name == "drive_friction_nm":
                out[name] = values[name]
            else:
                out[name] = values[name] - self.mark(name)
        return out

    def _report(self, direction: str, estimate: Estimate, modes: frozenset[str] | tuple[str, ...],
                label: str | None = None) -> Reported:
        """The parameters of `modes` relative to the baseline, each with the model's error added to the fit's."""
        params, fit_std = {}, {}
        for mode in modes:
            raw = self._departures(mode, estimate.values, direction)
            for name in MODE_PARAMETERS[mode]:
                if name in estimate.params:
                    params[name] = self.errors.corrected(name, raw[name])
                    fit_std[name] = estimate.std[name] / self.errors.slope(name)
        std = {name: float(np.hypot(fit_std[name], self.errors.std(name, params[name]))) for name in params}
        nuisance = {name: estimate.values[name] for name in NUISANCES}
        return Reported(label or estimate.mode, params, std, estimate.mse, (), nuisance, fit_std)

    def _unobservable(self, direction: str, mse: float) -> Reported:
        """The bolt this throw cannot see: its held value, flagged, no std (its hypothesis is the nominal one)."""
        other = DRIVING_BOLT[OTHER_DIRECTION[direction]]
        name = MODE_PARAMETERS[other][0]
        return Reported(other, {name: self.background(direction) - self.mark(name)}, {}, mse, (name,))

    def _warm(self, previous: ThrowVerdict | None, specs: dict[str, HypothesisSpec],
              direction: str) -> dict[str, dict[str, float]] | None:
        """Each hypothesis's start from the switch's previous throw in this direction: that throw's fit of the same
        faults where it made one (a fault just confirmed was that throw's added mode), else its fit of the same label;
        a parameter that fit did not free starts where the hypothesis starts it (HypothesisSpec.initial: a present
        fault's latest estimate)."""
        if previous is None:
            return None
        base = self.present(direction)
        by_modes = {previous.modes_of(label): e for label, e in previous.estimates.items()}
        out = {}
        for label, spec in specs.items():
            source = by_modes.get(modes_of(label, base, direction), previous.estimates.get(label))
            if source is not None:
                out[label] = {**source.values, **{name: value for name, value in spec.initial.items()
                                                  if name in spec.free and name not in source.params}}
        return out

    # -- one throw ----------------------------------------------------------------------------
    def diagnose(self, throw: ThrowInput) -> Outcome:
        """The switch's present faults after this throw, with this throw's verdict."""
        why = problem(throw)
        if why is not None:
            self.rail_m = None  # unknown where the blades are: assume the next throw starts closed
            return Outcome("unknown", why, None, None, faults=tuple(sorted(self.faults)),
                           estimates=self._estimates())
        direction = throw.direction
        features = throw_features(throw.t_s, throw.signals, throw.reference, throw.duration_s, self.drive)
        profile = stroke_profile(throw.t_s, throw.signals, throw.reference, self.drive)
        start_rail = self.rail_m if self.rail_m is not None else CLOSED_START_M[direction]
        m = measurement(throw, start_rail, self.drive)
        provisional = not self.baseline.complete
        weight = self.prior.model_weight if provisional else self.baseline.model_weight()
        gains = self._gains(direction)
        previous = self.latest.get(direction)
        base = self.present(direction)
        prepared = self.estimator.prepare(m)  # once for the fits and the fitted outputs
        specs = self.specs(direction)
        estimates = self.estimator.fit_all(
            prepared, specs, weight,
            decide=lambda fits: judge(direction, fits, gains, self.evidence,
                                      self.negligible(fits, direction, start_rail))[0],
            warm=self._warm(previous, specs, direction),
            settled_mse=settled_mse(previous, m, base),
            slopes=None if previous is None else {mode: e.slopes for mode, e in previous.estimates.items()
                                                if e.slopes is not None})
        negligible = self.negligible(estimates, direction, start_rail)
        best, found = judge(direction, estimates, gains, self.evidence, negligible)
        explained = estimates[best] if best != "nominal" else estimates["nominal"]  # where it leaves the blades
        fitted = self.estimator.simulate(prepared, explained.values)
        end_rail = float(fitted["rail_position_m"][-1])
        judged = self._judged(direction, start_rail, end_rail)
        short = self.shortfall(start_rail, direction)
        held = self._held_short(direction, short, estimates["nominal"], judged)
        if held is not None:  # not told from the bolt as it is: the blades end where that bolt leaves them
            judged = frozenset()
            fitted = self.estimator.simulate(prepared, {**explained.values, **held})
            end_rail = float(fitted["rail_position_m"][-1])
        for name, seen in found.items():
            if name in judged:
                self.evidence[name] = [seen, *self.evidence.get(name, [])][:EVIDENCE_THROWS]
        detected = sorted((mode for mode, e in found.items() if e.detected and mode not in negligible and mode in judged),
                          key=lambda mode: estimates[mode].objective)
        shown = best if best in judged else "nominal"
        reported = self._reports(direction, estimates, base)
        verdict = ThrowVerdict(throw.index, direction, shown, found, estimates, reported, end_rail, fitted, provisional,
                               base)
        # A throw that repairs a fault adds none: its other modes were tested against the switch with that fault.
        repaired = self._repairs(direction, estimates, reported, gains, shown, judged, short)
        added = None if repaired else self._additions(verdict, detected)
        self.latest[direction] = verdict.kept(slopes=not self.lean)
        self.rail_m = verdict.end_rail_m
        if "missing_bearing" in judged:
            self._follow_chairs(verdict)
        unchanged = shown == "nominal" and self.undecided is None and not repaired and added is None
        suspected = (sorted(mode for mode, e in found.items() if e.suspected and mode not in negligible)
                     if m.signals.names == ("current_a",) else [])
        if added is not None or repaired:
            self.candidates = {d: [] for d in DIRECTIONS}
        if provisional and unchanged:
            record = self._commissioning_record(direction, estimates)
            if not self.faults and not suspected:
                self.baseline.add(direction, **record)
            else:  # the switch as it is, should an operator accept it
                self.candidates[direction] = [*self.candidates[direction], record][-self.baseline.needed:]
        for mode, fault in self.faults.items():
            if mode in judged and mode in reported:
                own = mode == DRIVING_BOLT[direction]
                fault.track.append(Tracked.of(verdict, mode, short if own else 0.0))
        standing = self._standing(direction, provisional, bool(added or repaired), suspected)
        if provisional and self.baseline.complete:  # from now on its estimates depart from its own baseline
            self.health.reset()
            health = self.health.update(throw.index, {})
        else:
            self.health.restart(name for mode in repaired for name in MODE_PARAMETERS[mode] if name in TRACKED)
            health = self.health.update(throw.index, {name: value for name, value in self._health_estimates(
                verdict).items() if FAULT_PARAMETERS[name].mode in judged})
        estimates_now = self._estimates()
        decision = self.decision()
        reason = self._reason(repaired, provisional, suspected if provisional and unchanged else [])
        if unchanged and not self.faults and not suspected:  # a healthy throw: the band's, until it has enough
            self.trends.learn(direction, features, profile)
        feature_health = [] if provisional else self.trends.update(throw.index, direction, features, profile)
        anomalies = [] if provisional else [*self._anomalies(verdict), *self._binding()]
        if not anomalies:
            self.anomalous_since = None
        elif self.anomalous_since is None:
            self.anomalous_since = throw.index
        if not anomalies and shown == "nominal" and not provisional:  # the weather's level, followed
            self.baseline.follow(ANOMALOUS, verdict.estimates["nominal"].values[ANOMALOUS])
        return Outcome(decision, reason, verdict, estimates_now.get(decision), health, tuple(sorted(self.faults)),
                       estimates_now, standing, features, feature_health, anomalies)

    def _anomalies(self, verdict: ThrowVerdict) -> list[dict]:
        """What the commissioned switch as it is fitted shows that no fault mode names: its winding resistance at the
        edge of the population's range, or beyond the weather from its commissioned or recent level (ANOMALOUS). The
        drive's other quantities read through it: a weaker torque constant needs more current for the same torque
        and gives less back-EMF, which the fit reads as a higher resistance; a supply sag that saturates the drive
        limits the current, which it reads as a lower one. Each anomaly names what may have changed."""
        value = float(verdict.estimates["nominal"].values[ANOMALOUS])
        levels = [self.baseline.level(d, ANOMALOUS)[0] for d in DIRECTIONS]
        commissioned = float(np.mean(levels)) if all(np.isfinite(levels)) else None  # a state from before it was kept
        recent = self.baseline.recent.get(ANOMALOUS, commissioned)
        low, high = self.prior.bounds[ANOMALOUS]
        edge = AT_BOUND * (high - low)
        since = "" if commissioned is None else f", commissioned at {commissioned:.2f} Ω"
        why = None
        # at a bound its commissioned level was well inside of (one that sat at it from the first throw, the model's
        # error on that switch did put there: one in some dozens of healthy switches)
        if commissioned is not None and value >= high - edge and commissioned < high * (1.0 - DAY_SWING):
            why = f"at the highest the population allows ({high:.2f} Ω){since}"
        elif commissioned is not None and value <= low + edge and (
                commissioned > low * (1.0 + DAY_SWING + SUPPLY_TOLERANCE)):
            why = f"at the lowest the population allows ({low:.2f} Ω){since}"
        elif commissioned is not None and not (1.0 - SUPPLY_TOLERANCE) / SEASON <= value / commissioned <= SEASON:
            why = f"{100.0 * (value / commissioned - 1.0):+.0f} % from its commissioned {commissioned:.2f} Ω, more than a year's weather"
        elif recent is not None and not -(DAY_SWING + SUPPLY_TOLERANCE) <= value / recent - 1.0 <= DAY_SWING:
            why = f"{100.0 * (value / recent - 1.0):+.0f} % from its recent {recent:.2f} Ω in one throw, more than a day's weather"
        if why is None:
            return self._unexplained(verdict)
        high_side = value > (recent if recent is not None else 0.5 * (low + high))
        frictions = sorted(self.faults.keys() & {"missing_bearing", "drive_friction"})
        if high_side and frictions:  # weaker magnets need more current for the same torque: friction too
            suspects = ["motor.torque_constant_nm_a", "motor.resistance_ohm"]
            cause = (f"weakened magnets (a lower torque constant reads as a higher resistance and as friction: the "
                     f"{' and '.join(frictions)} beside it may be the magnets), or a cable or winding fault?")
        elif high_side:
            suspects = ["motor.resistance_ohm", "motor.torque_constant_nm_a"]
            cause = "a cable or winding fault, or weakened magnets (a lower torque constant reads as a higher resistance)?"
        else:
            suspects = ["motor.supply_v", "motor.resistance_ohm"]
            cause = "a supply sag that saturates the drive, or a shorted winding?"
        return [{"quantity": ANOMALOUS, "value": value, "commissioned": commissioned, "unit": "Ω",
                 "reason": f"winding resistance {value:.2f} Ω {why}: {cause}", "suspects": suspects}]

    def _binding(self) -> list[dict]:
        """An anomaly when the latest throw of each direction shows a load at one point of the stroke, at the same
        place both ways (LOCAL, SAME_PLACE): a gearbox that binds there, whatever fault the fit reads it as."""
        rises, shares = [], []
        for direction in DIRECTIONS:
            excess, band = self.trends.excess(direction), self.trends.band(direction, "peak_current_a")
            if excess is None or band is None or not np.any(np.isfinite(excess)):
                return []
            at = int(np.nanargmax(excess))
            if excess[at] < BAND_FLOOR * band[0] or excess[at] < LOCAL * max(float(np.nanmean(excess)), 0.0):
                return []
            rises.append(float(excess[at]))
            shares.append((at + 0.5) / PROFILE_BINS)
        if abs(shares[0] - shares[1]) > SAME_PLACE:
            return []
        return [{"quantity": "stroke_current_a", "value": float(np.mean(rises)), "commissioned": 0.0, "unit": "A",
                 "suspects": ["drive.binding_torque_nm"],
                 "reason": f"the current rises {np.mean(rises):.1f} A above its commissioned level at "
                           f"{100.0 * np.mean(shares):.0f} % of the stroke both ways, a load at one motor angle (a blade "
                           f"obstacle's would lie the adjuster's free play apart): a gearbox that binds there?"}]

    def _unexplained(self, verdict: ThrowVerdict) -> list[dict]:
        """An anomaly when no hypothesis explains the throw as well as the switch's commissioning throws were explained
        (module constants); named a supply sag when the motor lagged its reference further than a healthy switch's.
        Beside a fault confirmed before the anomalies began, or at the throw they began, the test says nothing: the
        model's error grows with the fault (a near-stall obstacle's fit left three times a healthy throw's residual, from
        the throw that confirmed it on), and commissioning measured it on the healthy switch only. A fault confirmed
        later, while the switch was anomalous, may be the anomaly misread (a saturated drive read as a loose bolt after
        some throws), and the test goes on."""
        began = self.anomalous_since if self.anomalous_since is not None else verdict.index
        if any(fault.since <= began for fault in self.faults.values()):
            return []
        best = min(verdict.estimates.values(), key=lambda e: e.mse)
        weight = self.baseline.model_weight()
        if weight <= 0.0 or best.effective_samples <= 0.0:
            return []
        ratio = best.mse / best.effective_samples / weight
        dof = max(best.effective_samples, 1.0)
        limit = MODEL_ERROR_MARGIN * float(stats.chi2.ppf(1.0 - FALSE_ALARM_RATE, dof) / dof)
        if ratio <= limit:
            return []
        lag = self.trends.latest(verdict.direction, "speed_lag_rad_s")
        band = self.trends.band(verdict.direction, "speed_lag_rad_s")
        if lag is not None and band is not None and lag > band[2]:
            return [{"quantity": "motor.supply_v", "value": None, "commissioned": None, "unit": "V",
                     "reason": f"no fault explains the throw (its residual {ratio:.1f} times the commissioned one) and "
                               f"the motor lagged its reference by {lag:.0f} rad/s (commissioned {band[0]:.0f}): "
                               f"the drive ran short of voltage, a supply sag?", "suspects": ["motor.supply_v"]}]
        return [{"quantity": "residual", "value": ratio, "commissioned": 1.0, "unit": "",
                 "reason": f"no fault explains the throw: its residual is {ratio:.1f} times the commissioned one "
                           f"(a binding gearbox, a damaged rod or a fault no mode names?)", "suspects": []}]

    def diagnose_aside(self, throw: ThrowInput) -> Outcome:
        """A throw's outcome that leaves the switch as it was (maintenance: the team's throws teach no baseline, trend or
        fault); only where the blades were left is kept, the next throw starts there."""
        kept = copy.deepcopy(self.state())
        aside = (self.latest.copy(), {m: list(e) for m, e in self.evidence.items()}, self.undecided, dict(self._unchanged))
        try:
            return self.diagnose(throw)
        finally:
            self.resume(kept)
            self.latest, self.evidence, self.undecided, self._unchanged = aside

    def _commissioning_record(self, direction: str, estimates: dict[str, Estimate]) -> dict:
        """What a throw that showed nothing new teaches of the switch as it is: its baselined levels as the switch as it
        is fitted them (a missing bearing's friction and drive friction added to the levels they add to), what each
        fault mode's fit gains on it (a present fault's own: the population's), and its model weight."""
        base = estimates["nominal"]
        values = base.values
        levels = {"bearing_friction": values["bearing_friction"],
                  "motor.coulomb_friction_nm": values["motor.coulomb_friction_nm"] + values["drive_friction_nm"],
                  DRIFTING: values[DRIFTING], ANOMALOUS: values[ANOMALOUS]}
        gains = {**self.prior.gains.get(direction, {}), **healthy_gains(estimates)}
        return {"levels": levels, "gains": gains, "model_weight": base.mse / base.effective_samples}

    def _reports(self, direction: str, estimates: dict[str, Estimate], base: frozenset[str]) -> dict[str, Reported]:
        """Each hypothesis as the diagnosis reports it: a present fault from the switch as it is, a mode it does not
        have from that mode's own fit (its parameters only), the switch as it is with its present faults, without
        each of them, every mode at once, and the bolt this throw cannot see (held)."""
        reported = {}
        for label, estimate in estimates.items():
            if label == "joint":
                reported[label] = self._report(direction, estimate, candidate_modes(direction))
            elif label == "nominal":
                reported[label] = self._report(direction, estimate, base)
                reported.update({mode: self._report(direction, estimate, (mode,), mode) for mode in sorted(base)})
            elif label.startswith(WITHOUT):
                reported[label] = self._report(direction, estimate, (), label[len(WITHOUT):])
            else:
                reported[label] = self._report(direction, estimate, (label,))
        hidden = self._unobservable(direction, estimates["nominal"].mse)
        reported[hidden.mode] = hidden
        return reported

    def _judged(self, direction: str, start_rail_m: float, end_rail_m: float) -> frozenset[str]:
        """The modes a throw's evidence counts for: every mode it can show, but only its own bolt when it starts with
        the blades short of the stock rail and a loose bolt of the other direction left them there (a judgement of
        what the fitted blades' end says alone would hold a fault whose fit leaves them short from ever being judged
        gone: an obstacle, removed, did so for good). Resting short, the
        blades lean on that bolt's face, and in the plant they follow it back from the throw's first instant; the
        reduced model, whose chairs hold no static friction, has them elsewhere when this throw's bolt meets the
        adjuster, and misfits the current there twenty times the noise (poly, a 50 mm left bolt): fitted anyway, such
        a throw read a missing bearing of 3300 N·s/m as 400 to 700 and drive friction where there was none. Its own
        bolt it reads within SHORT_SHARE of how far short it started (`small`), as it does when anything else left the
        blades short (an obstacle that stalls them). A present obstacle is judged only by a throw whose blades passed it
        (one that stalls them short leaves the next throw, the other way, starting short of it: there it read as
        gone)."""
        modes = frozenset(candidate_modes(direction))
        obstacle = self.faults.get("obstacle")
        if obstacle is not None:  # a present obstacle the blades did not pass in this throw is not seen by it
            position = obstacle.values["obstacle_position"]
            low, high = sorted((start_rail_m, end_rail_m))
            if not low - OBSTACLE_REACH_M <= position <= high + OBSTACLE_REACH_M:
                modes = modes - {"obstacle"}
        if abs(start_rail_m - CLOSED_START_M[direction]) > SHORT_START_M and (
                DRIVING_BOLT[OTHER_DIRECTION[direction]] in self.faults):
            return modes & {DRIVING_BOLT[direction]}
        return modes

    def _held_short(self, direction: str, short_m: float, nominal: Estimate,
                    judged: frozenset[str]) -> dict[str, float] | None:
        """A present bolt's values, when a throw that judges that bolt alone (it started short after a loose bolt of
        the other direction: _judged) reads it no further from them than how far short it started (`short_m`, in rod
        travel: shortfall); else None. Resting short, the blades are where the reduced model cannot hold them (its chairs have no static
        friction): anywhere from there to closed when this throw's bolt meets the adjuster, so its reading may be
        off by up to the whole shortfall (SHORT_SHARE is how far it usually is), and a change that small is not told
        from none: the throw neither repairs the bolt nor resizes it. Both bolts loose, every throw starts short: a
        right bolt of 47 mm beside a left one of 38 mm read 1.5 mm (poly) and 15 mm (causal, 49 mm short) on such a
        throw and was repaired at once, and the left bolt, read on the next throw with the blades taken to have
        started closed, crept from 38 to 60 mm (benchmarks.aging)."""
        own = DRIVING_BOLT[direction]
        fault = self.faults.get(own)
        if fault is None or judged != {own}:
            return None
        name = MODE_PARAMETERS[own][0]
        change = abs(nominal.values[name] - fault.values[name])
        return {name: fault.values[name]} if change <= short_m else None

    def _repairs(self, direction: str, estimates: dict[str, Estimate], reported: dict[str, Reported],
                 gains: dict[str, float], shown: str, judged: frozenset[str], short_m: float) -> list[str]:
        """The present faults this throw shows gone (fault_set.repaired); the others take this throw's estimates. A
        throw that shows a new fault (`shown`) bends the switch as it is (a bolt appearing put a present bearing of
        4000 N·s/m at 900 in it): there a fault is repaired only by a sudden drop of its size in the fit that adds the
        new fault, and none takes this throw's estimates."""
        gone = []
        for mode in sorted(self.present(direction) & judged):
            fault = self.faults[mode]
            now = presence(estimates, mode, gains.get(mode, 0.0))
            report = reported[mode] if shown == "nominal" else self._report(direction, estimates[shown], (mode,))
            size = size_of(mode, report.params)
            size_std = float(np.hypot(report.fit_std.get(MAGNITUDE[mode], 0.0), self._reference_std(direction, mode)))
            if repaired(fault, now, size, size_std, small(mode, report.params, self.loaded(mode), short_m),
                        sudden_only=shown != "nominal"):
                gone.append(mode)
                del self.faults[mode]
                continue
            if shown != "nominal" or fault.dropped:  # a drop to confirm is judged against the size before it
                continue
            fault.presence = [now, *fault.presence][:EVIDENCE_THROWS - 1]
            fault.values = {name: estimates["nominal"].values[name] for name in MODE_PARAMETERS[mode]}
            fault.size, fault.size_std = size, size_std
        if "missing_bearing" in gone and DRIFTING in self.baseline.recent:
            # the chairs' level followed part of the bearing while it grew unseen; the throw without it says where
            # they are
            self.baseline.recent[DRIFTING] = estimates[WITHOUT + "missing_bearing"].values[DRIFTING]
        if gone:
            self.evidence.clear()  # the switch as it is changed: earlier throws' evidence was against another
        return gone

    def _reference_std(self, direction: str, mode: str) -> float:
        """How far a healthy switch's own level of what `mode` adds to may lie from where it is held (the baselined
        level's spread, in the fault parameter's unit): a missing bearing and drive friction are departures from it,
        so one repaired reads within that of zero (a repaired drive friction of nn read 0.005 N·m, its fit's std a
        tenth of that, the commissioned level's floor 0.006)."""
        name = {"missing_bearing": "bearing_friction", "drive_friction": "motor.coulomb_friction_nm"}.get(mode)
        if name is None:
            return 0.0
        std = self._prior(direction, name)[1]
        return std * self.level(direction, name) if name in self._log_prior() else std

    def _additions(self, verdict: ThrowVerdict, detected: list[str]) -> str | None:
        """The fault this throw confirms (fault_set: the best detected, unless this direction cannot tell it from
        another; an undecided pair settled by a throw of the other direction), added to the present ones."""
        direction, estimates = verdict.direction, verdict.estimates
        undecided, self.undecided = self.undecided, None
        if undecided is not None and undecided.direction != direction:
            mode = decide_between(undecided, direction, detected)
            values = estimates[mode].values if mode in detected else undecided.values.get(mode, {})
        elif detected:
            mode = detected[0]
            alike = tuple(other for other in detected[1:] if not separable(estimates, mode, other))
            if alike:
                self.undecided = Undecided((mode, *alike), direction, verdict.index,
                                           {m: estimates[m].values for m in (mode, *alike)})
                return None
            values = estimates[mode].values
        else:
            return None
        if mode is None:
            return None
        report = verdict.reported.get(mode)
        size = size_of(mode, report.params) if report is not None and not report.unobservable else 0.0
        self.faults[mode] = Fault(mode, verdict.index, {name: values[name] for name in MODE_PARAMETERS[mode]}, size,
                                  0.0 if report is None else report.fit_std.get(MAGNITUDE[mode], 0.0),
                                  presence=list(self.evidence.get(mode, [])[:EVIDENCE_THROWS - 1]),
                                  track=deque(maxlen=TRACKED_THROWS))
        self.evidence.clear()  # the switch as it is changed: earlier throws' evidence was against another
        return mode

    def _follow_chairs(self, verdict: ThrowVerdict) -> None:
        """After a throw that showed nothing new, the chairs' recent level moves towards the switch as it is fitted
        there (Baseline.follow), by how much the throw's own samples say the change is the chairs' rather than a
        bearing's. A throw tells the two frictions' sum well and their split only a little (viscous losses grow with
        speed, Coulomb friction does not): a bearing's hypothesis that explains the throw's samples better than the
        chairs (the samples' part S of its statistic, chi-square-like, about 1 when nothing tells them apart; not what
        it saves of the chairs' prior, which is the lag itself) is a likelihood ratio of exp(S / 2) that what moved is
        a bearing, and the level follows by exp(-(S - 1) / 2) of its step at most. Chairs drying out are followed (the
        split leans their way, or is even); a bearing drying out slowly, throw by throw, is not absorbed, so the
        nominal fit must pay for it in the chairs' prior and the bearing is found (a step the nominal fit of such a
        throw took whole, with the bearing left at its baseline, until it read as 70 % of its limit). A present missing
        bearing is fitted beside the chairs, and its throws do not move them (_unseen_chairs)."""
        if verdict.mode != "nominal" or "missing_bearing" in verdict.base:
            return
        bearing = verdict.evidence.get("missing_bearing")
        weight = 1.0 if bearing is None else float(np.exp(-max(bearing.own - 1.0, 0.0) / 2.0))
        self.baseline.follow(DRIFTING, verdict.estimates["nominal"].values[DRIFTING], weight)

    def _standing(self, direction: str, provisional: bool, changed: bool, suspected: list[str]) -> str | None:
        """Once an uncommissioned switch has shown the same present faults (or, with none, throws that fit a fault
        about as well as a healthy switch) for as many throws each way as commissioning needs, it cannot be
        commissioned as healthy: say so once, in words an operator understands."""
        stalled = self.faults and not changed or not self.faults and suspected
        if not provisional or not stalled:
            self._unchanged = dict.fromkeys(DIRECTIONS, 0)
            return None
        self._unchanged[direction] += 1
        if self.standing is not None or min(self._unchanged.values()) < self.baseline.needed:
            return None
        chair = PLANT_PARAMETERS["rail.chair_viscous_n_s_m"].nominal * CHAIR_TO_BEARING
        machine = float(np.exp(self.prior.prior["motor.coulomb_friction_nm"][0]))
        parts = []
        for mode in sorted(self.faults):
            combined = self._combined(mode)
            departures = combined.params if combined is not None else self._departures(
                mode, self.faults[mode].values, self.latest_direction(mode))
            parts.append(f"{describe_standing(mode, departures, chair, machine)}, reads as {mode}")
        if not parts:
            parts.append("its throws fit " + " or ".join(suspected) + " about as well as a healthy switch")
        self.standing = "cannot be commissioned as healthy: " + "; ".join(parts)
        return self.standing

    def negligible(self, estimates: dict[str, Estimate], direction: str, start_rail_m: float) -> list[str]:
        """The modes whose fitted size is no fault: a bolt's or an obstacle's hypothesis fitted that small (`small`), an
        obstacle where the throw's own loose bolt stops the blades (_at_short_end); a missing bearing or drive friction
        fitted within RETURN_SIGMAS of its reference (its fit's and the baselined level's spread together), whose fit
        beat the switch as it is by fitting the rest better, not by the fault (a near-stall obstacle's nominal fit
        stopped in a worse basin than the bearing's, and a bearing of zero was confirmed)."""
        out = []
        for mode in MODE_PARAMETERS:
            if mode not in estimates:
                continue
            estimate = estimates[mode]
            departures = {name: self.errors.corrected(name, value) for name, value in
                          self._departures(mode, estimate.values, direction).items()}
            if mode in ("missing_bearing", "drive_friction"):
                name = MAGNITUDE[mode]
                spread = float(np.hypot(estimate.std.get(name, 0.0), self._reference_std(direction, mode)))
                if departures[name] <= RETURN_SIGMAS * spread:
                    out.append(mode)
            elif small(mode, departures, self.loaded(mode), self.shortfall(start_rail_m, direction)):
                out.append(mode)
            elif mode == "obstacle" and self._at_short_end(direction, estimate.values["obstacle_position"]):
                out.append(mode)
        return out

    def _at_short_end(self, direction: str, position_m: float) -> bool:
        """Whether an obstacle there sits where this throw's own loose bolt stops the blades short: the end of the
        stroke, which the model misfits alike (a 186 mm right bolt stopped them at 1.093 m, where an obstacle of
        20 000 N·s/m was fitted on every right-to-left throw)."""
        bolt = self.faults.get(DRIVING_BOLT[direction])
        if bolt is None:
            return False
        name = MODE_PARAMETERS[bolt.mode][0]
        short = (bolt.values[name] - self.mark(name)) / self.drive.linkage_ratio
        if short <= SHORT_START_M:
            return False
        end = CLOSED_START_M[OTHER_DIRECTION[direction]] + (short if direction == "right_to_left" else -short)
        return abs(position_m - end) < STROKE_END_M

    def shortfall(self, start_rail_m: float, direction: str) -> float:
        """How far short of the stock rail a throw starts, in rod travel (0 within SHORT_START_M)."""
        short = abs(start_rail_m - CLOSED_START_M[direction])
        return 0.0 if short <= SHORT_START_M else self.drive.linkage_ratio * short

    def loaded(self, mode: str) -> bool:
        """Whether the switch has a present fault besides `mode`."""
        return bool(self.faults.keys() - {mode})

    def _health_estimates(self, verdict: ThrowVerdict) -> dict[str, tuple[float, float]]:
        """Each tracked parameter this throw could see, as it estimated it: a present fault's from the switch as it is,
        another's from its own hypothesis, unless the throw showed a new fault of another mode (whose effect that
        hypothesis bends to: a bearing grown past detection shows as drive friction in the drive-friction
        hypothesis, which cannot free the bearing that far; a loose bolt as bearing friction).

        Once commissioned, the bearing friction counts the chairs' departure from their commissioned level too
        (CHAIRS_AS_BEARING): the chairs follow the weather throw by throw, as far as each throw's samples say the change
        is theirs (_follow_chairs), and a bearing that dries out very slowly (40 N·s/m a throw: each throw's split says
        nothing) is still followed by them, and would be hidden from the trend. Weather then wanders the bearing's
        level (chairs a fifth drier: some 400 N·s/m, a twelfth of its limit); a worn bearing
        shows whole, and the decisions, which the chairs' prior carries, tell the two apart."""
        out = {}
        for name in TRACKED:
            mode = FAULT_PARAMETERS[name].mode
            if not observable(mode, verdict.direction):
                continue
            if mode not in verdict.base and verdict.mode not in ("nominal", mode):
                continue
            reported = verdict.reported.get(mode)
            if reported is not None and name in reported.params and not reported.unobservable:
                out[name] = (reported.params[name], reported.fit_std[name])
        if "bearing_friction" in out and self.baseline.complete:
            value, std = out["bearing_friction"]
            label = "nominal" if "missing_bearing" in verdict.base else "missing_bearing"
            chairs = verdict.estimates[label].values[DRIFTING]
            commissioned = self.baseline.level(verdict.direction, DRIFTING)[0]
            chairs_as_bearing = CHAIRS_AS_BEARING * (chairs - commissioned) / self.errors.slope("bearing_friction")
            out["bearing_friction"] = (value + chairs_as_bearing, std)  # corrected as _report corrects the bearing
        return out

    def decision(self) -> str:
        """The newest present fault (the latest confirmed; the larger evidence among those confirmed together), or
        nominal."""
        if not self.faults:
            return "nominal"
        return max(self.faults.values(), key=lambda f: f.since).mode

    def _reason(self, repaired: list[str], provisional: bool, suspected: list[str]) -> str | None:
        """The present faults and since when, a repair, an undecided pair, how far commissioning is (and why a throw
        did not count), why the switch cannot be commissioned, a baseline outside the population."""
        notes = []
        if self.faults:
            notes.append("present: " + ", ".join(f"{mode} since throw {f.since}"
                                                 for mode, f in sorted(self.faults.items())))
        if repaired:
            notes.append("repaired: " + ", ".join(repaired))
        if self.undecided is not None:
            notes.append(self.undecided.describe())
        if provisional:
            seen = sum(min(self.baseline.count(d), self.baseline.needed) for d in DIRECTIONS)
            notes.append(f"provisional: commissioning {seen} of {self.baseline.needed * len(DIRECTIONS)}")
        if suspected:
            notes.append("not counted: the throw fits " + " or ".join(suspected) + " about as well as a healthy switch")
        if self.standing is not None and provisional:
            notes.append(self.standing + " (railswitch commission --accept takes it as the switch's own)")
        outside = self.outside_population()
        if outside:
            notes.append("baseline outside the population: " + ", ".join(outside))
        return "; ".join(notes) or None

    # -- a present fault over throws ------------------------------------------------------------
    def _combined(self, mode: str) -> Combined | None:
        fault = self.faults.get(mode)
        if fault is None or not fault.track:
            return None
        return self.combine(mode, list(fault.track))

    def _estimates(self) -> dict[str, Combined]:
        """Each present fault's size combined over the throws since it was confirmed that see it."""
        return {mode: combined for mode in sorted(self.faults) if (combined := self._combined(mode)) is not None}

    def combine(self, mode: str, verdicts: list[Tracked]) -> Combined:
        """A mode's parameters over several throws: the fits weighted by their variances, the model's error
        added as it stands after that many throws (its common part once, its per-throw part averaged)."""
        params, std, fit_std = {}, {}, {}
        for k, name in enumerate(MODE_PARAMETERS[mode]):
            values = np.array([v.params[k] for v in verdicts])
            fit = np.array([max(v.fit_std[k], 1e-12) for v in verdicts])
            weights = 1.0 / fit**2
            mean = float(np.sum(weights * values) / np.sum(weights))
            params[name], fit_std[name] = mean, float(np.sqrt(1.0 / np.sum(weights)))
            std[name] = float(np.hypot(fit_std[name], self.errors.std(name, mean, len(verdicts))))
            if name == "bearing_friction":
                std[name] = float(np.hypot(std[name], self._unseen_chairs(verdicts, weights)))
        return Combined(mode, params, std, len(verdicts), verdicts[0].index, fit_std)

    def _unseen_chairs(self, verdicts: list[Tracked], weights: np.ndarray) -> float:
        """What the chairs may have done since the throw before `verdicts` began, in bearing friction: a throw tells
        their sum with a bearing's, not the split (CHAIRS_AS_BEARING), and only healthy throws move the chairs'
        prior (Baseline.follow), so a bearing fitted k throws after the last healthy one holds what the chairs did
        in between, beyond the one throw's change (DRIFT) its fit allows for. Weather persists (chairs dry out over
        many throws), so k throws may change them k times as much; combined with `weights`, as the estimates are.
        Seen on the fleet: chairs drying to twice their friction over 16 throws put a missing bearing's estimate
        1000 to 1600 N·s/m high after 12 faulty throws, 3.7 of its standard deviations without this."""
        drift = self._drift_prior()
        if drift is None:
            return 0.0
        after = np.array([v.index - verdicts[0].index for v in verdicts], dtype=float)  # throws beyond the first
        throws = float(np.sum(weights * after) / np.sum(weights))
        return CHAIRS_AS_BEARING * DRIFT * float(np.exp(drift[0])) * throws / self.errors.slope("bearing_friction")

    # -- persistence ------------------------------------------------------------------------------
    def state(self) -> dict:
        """What a restarted diagnoser (or the one that takes the switch over) needs to resume it: its
        baseline, its present faults and its health over the throws so far."""
        return {"baseline": self.baseline.to_dict(), "health": self.health.to_dict(),
                "faults": [fault.to_dict() for fault in self.faults.values()], "standing": self.standing,
                "candidates": self.candidates, "features": self.trends.to_dict(), "anomalous_since": self.anomalous_since}

    def resume(self, state: dict) -> None:
        self.baseline = Baseline.from_dict(state["baseline"])
        if "health" in state:
            self.health.load(state["health"])
        self.faults = {f["mode"]: Fault.from_dict(f, TRACKED_THROWS) for f in state.get("faults", [])}
        self.standing = state.get("standing")
        self.candidates = {d: list(state.get("candidates", {}).get(d, [])) for d in DIRECTIONS}
        self.trends = FeatureTrends(self.baseline.needed)
        self.trends.load(state.get("features", {}))  # a state saved before features were trended has none
        self.anomalous_since = state.get("anomalous_since")
