"""One switch diagnosed throw by throw, against its own commissioned baseline (paper, section "Fault diagnosis").

A real switch is not the reduced model's twin: its motor, supply, point-machine friction
and slide chairs differ from the nominal ones and change with the weather. So every
hypothesis frees, beside its fault parameters, what the population lets vary and the
reduced model can show:

- the switch's own weather (winding resistance, supply, slide-chair Coulomb friction): free
  in every throw, the resistance and supply with the population as their prior; the chairs'
  friction once commissioned with the switch's own recent level (an average over its latest
  healthy throws) as the prior's mean and DRIFT of it as its spread, so that chairs drying out
  over many throws are followed while a sudden change is not explained away (with the model's
  error, the chairs' Coulomb friction and a bearing's viscous friction are not told apart
  within a throw: how fast they change is what tells them apart);
- its healthy levels of two fault-like parameters, the extra rail damping that the
  bearing fault adds to (rolling losses differ from switch to switch) and the point
  machine's Coulomb friction that the drive-friction fault adds to: free with the
  population as their prior until the switch is commissioned, with its own baseline after.

A prior charges a fit for straying (models/estimation.py HypothesisSpec), so a switch is
called healthy when its throw is what a plausible member of the population (or, once
commissioned, the switch itself) would do, not whatever the nuisances could be bent to.

Commissioning: the first `needed` throws each way that are healthy against the population
teach the switch's baseline (the levels above and how much each fault mode's fit gains on
a healthy throw by absorbing model error). Until then decisions are provisional, judged
against the population. A fault is a departure the free parameters cannot explain:
bearing friction and drive friction are reported as departures from the baseline.

Each throw checks that it can be diagnosed, estimates where it starts (the motor angle
from every sample, the blades where the previous throw's fit left them), fits every
hypothesis the throw can show (a bolt only in the throws it drives; the other bolt is
held at its latest estimate) and judges them (models/isolation.py). The decided fault's
size combines every throw since it appeared that can see it, weighted by their own
variances, with the model's error (which does not average out) added once.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from railswitch.models.drive import DriveParams
from railswitch.models.estimation import DRIVING_BOLT, Estimate, HypothesisSpec, Measurement, ThrowEstimator
from railswitch.models.health import TRACKED, Health, HealthTracker
from railswitch.models.isolation import EVIDENCE_THROWS, OTHER_DIRECTION, Evidence, healthy_gains, judge
from railswitch.models.population import credible_range, spread
from railswitch.models.reduced import NUISANCES
from railswitch.models.reference import DIRECTIONS, Reference
from railswitch.models.signals import MotorSignals
from railswitch.schemas.faults import FAULT_PARAMETERS, MODE_PARAMETERS
from railswitch.schemas.plant import PLANT_PARAMETERS

CLOSED_START_M = {"left_to_right": 1.0, "right_to_left": 1.2}  # where a throw starts when the last one closed
GAP_TOLERANCE = 0.25  # of a sample period, for "the samples are evenly spaced"
# A throw ends when the point machine detects its end position, earlier or later than its reference profile
# ends; it is cut short only when it ends while the motor is still asked to turn (or, where measured, still
# turns) at more than this share of its top speed.
STILL_SHARE = 0.1
# The throws a decided fault's size is combined over: those since it appeared, at most the latest TRACKED_THROWS (ten
# days of a switch's throws). Each throw of a fault left in place adds to its switch's memory (about 1 kB as
# ThrowVerdict.tracked keeps it; kept whole, 117 kB and without end); combined over so many, the model's error, whose
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
BOLT_GRID = tuple(np.round(np.arange(-0.02, 0.2001, 0.02), 4))
OBSTACLE_GRID = tuple({"obstacle_position": round(float(p), 3), "obstacle_friction": f}
                      for p in np.arange(1.02, 1.1801, 0.02) for f in (3e4, 1.5e5))
# A settled throw's (models/estimation.py SETTLED): an obstacle that appears without changing the throw is a small one.
SMALL_OBSTACLE_GRID = tuple(point for point in OBSTACLE_GRID if point["obstacle_friction"] == 3e4)


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
    model_weight: float  # healthy throws' nominal MSE over effective samples (models/estimation.py fit_all)


LOG_PRIOR = ("rail.chair_friction_coefficient", "motor.coulomb_friction_nm")  # skewed, positive: priors on log


def population(gains: dict[str, dict[str, float]] | None = None, model_weight: float = 0.0) -> Population:
    """The population of models/population.py, in the reduced model's parameters (the chairs' and the point
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
    """A switch's commissioning: the nominal fit's baselined values and each mode's gain on its healthy throws."""

    needed: int = COMMISSIONING_THROWS
    healthy: dict[str, list[dict]] = field(default_factory=lambda: {d: [] for d in DIRECTIONS})
    recent: dict[str, float] = field(default_factory=dict)  # drifting nuisances' recent levels (DRIFTING)
    # Its summaries (level, gains, model_weight), by what they summarise and how many healthy throws there were: a
    # commissioned switch's never change, and every throw's hypotheses read them some 24 times (1 ms of a settled
    # throw's 30). Healthy throws are only ever appended (add), so the count names the throws summarised.
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
            self.healthy[direction].append({"levels": levels, "gains": gains, "model_weight": model_weight})

    def model_weight(self) -> float:
        """The median over the healthy throws of the nominal fit's MSE over its effective samples."""
        return self._summary(("model_weight",), sum(map(self.count, DIRECTIONS)), lambda: float(
            np.median([h["model_weight"] for d in DIRECTIONS for h in self.healthy[d]])))

    def level(self, direction: str, name: str) -> tuple[float, float]:
        """Mean and spread of a baselined parameter over the healthy throws of a direction."""
        def compute() -> tuple[float, float]:
            values = np.array([h["levels"][name] for h in self.healthy[direction] if name in h["levels"]])
            if not len(values):
                return float("nan"), 0.0
            return float(values.mean()), float(values.std(ddof=1)) if len(values) > 1 else 0.0
        return self._summary(("level", direction, name), self.count(direction), compute)

    def gains(self, direction: str) -> dict[str, float]:
        return dict(self._summary(("gains", direction), self.count(direction), lambda: {
            mode: max(h["gains"].get(mode, 0.0) for h in self.healthy[direction]) for mode in MODE_PARAMETERS}))

    def follow(self, name: str, value: float) -> None:
        """Move a drifting nuisance's recent level towards a healthy throw's estimate."""
        previous = self.recent.get(name)
        self.recent[name] = value if previous is None else previous + FOLLOW * (value - previous)

    def to_dict(self) -> dict:
        return {"needed": self.needed, "healthy": self.healthy, "recent": self.recent}

    @classmethod
    def from_dict(cls, data: dict) -> Baseline:
        baseline = cls(int(data["needed"]))
        for direction in DIRECTIONS:
            baseline.healthy[direction] = [dict(h) for h in data["healthy"].get(direction, [])]
        baseline.recent = {k: float(v) for k, v in data.get("recent", {}).items()}
        return baseline


@dataclass(frozen=True)
class ThrowInput:
    """One throw as the diagnoser receives it: samples relative to the start event."""

    index: int
    direction: str
    reference: Reference
    t_s: np.ndarray  # first sample at the start event (t = 0)
    signals: MotorSignals
    duration_s: float | None  # start to end event; None when no end event came
    missing_samples: int = 0


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


def settled_mse(previous: ThrowVerdict | None, m: Measurement) -> float | None:
    """The nominal fit's MSE on the switch's previous throw in this direction, when that throw was healthy and
    measured the same signals (ThrowEstimator.fit_all: a throw whose nominal fit is within SETTLED of it is
    settled)."""
    if previous is None or previous.mode != "nominal":
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


@dataclass(frozen=True)
class ThrowVerdict:
    """What one throw says: its most likely mode (or nominal), the evidence for each and every hypothesis."""

    index: int
    direction: str
    mode: str
    evidence: dict[str, Evidence]
    estimates: dict[str, Estimate]
    reported: dict[str, Reported]
    end_rail_m: float  # where the decided hypothesis leaves the blades
    fitted: dict[str, np.ndarray]  # the decided hypothesis's outputs at the samples after the start
    provisional: bool

    @property
    def strength(self) -> float:
        return self.evidence[self.mode].ratio if self.mode in self.evidence else 0.0

    def kept(self) -> ThrowVerdict:
        """The verdict as its switch keeps it for the next throws (their warm starts, the slopes they borrow, what
        settles them, evidence, reports): without the fits' residuals and the fitted outputs, which no later throw
        reads, and with slopes only after a throw decided healthy, the only ones a later throw borrows (a settled
        throw follows a healthy one: ThrowEstimator.fit_all). Kept whole, a verdict held 115 kB."""
        return replace(self, estimates={mode: e.kept(slopes=self.mode == "nominal") for mode, e in self.estimates.items()},
                       fitted={})

    def tracked(self) -> ThrowVerdict:
        """What combining the decided fault over its throws reads of this one (SwitchDiagnoser.combine): its index,
        direction, mode and that mode's report."""
        return replace(self, evidence={}, estimates={}, fitted={},
                       reported={mode: r for mode, r in self.reported.items() if mode == self.mode})


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
    """The switch's decision after a throw, why, this throw's verdict, the decided fault's combined size and
    the switch's health over its throws."""

    decision: str
    reason: str | None
    verdict: ThrowVerdict | None
    estimate: Combined | None
    health: Health | None = None


def observable(mode: str, direction: str) -> bool:
    """A bolt shows only in the throws it drives; every other mode in both directions."""
    return mode not in DRIVING_BOLT.values() or DRIVING_BOLT[direction] == mode


class SwitchDiagnoser:
    """Diagnoses one switch throw by throw; holds its baseline, latest verdicts and the decided fault's history."""

    def __init__(self, estimator: ThrowEstimator, prior: Population, errors: ErrorModel | None = None,
                 baseline: Baseline | None = None, limits: dict[str, float] | None = None):
        self.estimator = estimator
        self.prior = prior
        self.errors = errors or ErrorModel()
        self.baseline = baseline or Baseline()
        self.health = HealthTracker(limits)  # the model's error that stays, near the limit where a forecast ends
        self.health.model_error = {name: self.errors.common(name, self.health.limits[name]) for name in TRACKED}
        self.latest: dict[str, ThrowVerdict] = {}
        self.rail_m: float | None = None  # blades' position after the last diagnosed throw
        self.track: deque[ThrowVerdict] = deque(maxlen=TRACKED_THROWS)  # throws since the decided fault appeared
        self.evidence: dict[str, list[Evidence]] = {}  # per mode, from the latest throws that saw it, latest first
        self.drive = estimator.reduced.params.plant.drive

    # -- commissioning ------------------------------------------------------------------------
    def restart_commissioning(self) -> None:
        """After maintenance: forget the baseline and the switch's history; learn it again."""
        self.baseline = Baseline(self.baseline.needed)
        self.latest.clear()
        self.track.clear()
        self.evidence.clear()
        self.health.reset()

    def _prior(self, direction: str, name: str) -> tuple[float, float]:
        """Mean and standard deviation a baselined parameter is expected at: the switch's own once commissioned
        (the population's, on log(value) for those in LOG_PRIOR, before)."""
        if not self.baseline.complete:
            return self.prior.prior[name]
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
        """Where a nuisance or baselined parameter may go at all: the population's credible range, or
        BOUND_SIGMAS of the switch's own baseline once commissioned. The chairs, followed once commissioned
        (`drift`: their prior, _drift_prior), may also go BOUND_SIGMAS of their drift beyond their recent level
        (within the plant's range): chairs that dry out slowly leave the population's range, and there their
        drying must not become a fault."""
        if name == DRIFTING and drift is not None:
            low, high = self.prior.bounds[name]
            physical = PLANT_PARAMETERS[name]
            mean, std = drift
            return (max(min(low, float(np.exp(mean - BOUND_SIGMAS * std))), physical.low),
                    min(max(high, float(np.exp(mean + BOUND_SIGMAS * std))), physical.high))
        if name not in BASELINED or not self.baseline.complete:
            return self.prior.bounds[name]
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
        """Baselined parameters whose commissioned level lies outside the population's credible range."""
        if not self.baseline.complete:
            return []
        out = []
        for name in BASELINED:
            mean, std = self.prior.prior[name]
            for d in DIRECTIONS:
                level = self.baseline.level(d, name)[0]
                level = np.log(max(level, 1e-300)) if name in LOG_PRIOR else level
                if abs(level - mean) > OUTSIDE_SIGMAS * std:
                    out.append(name)
                    break
        return out

    # -- hypotheses ---------------------------------------------------------------------------
    def specs(self, direction: str) -> dict[str, HypothesisSpec]:
        """The hypotheses a throw in `direction` can show, with what each frees, holds and expects."""
        bolt = DRIVING_BOLT[direction]
        other = DRIVING_BOLT[OTHER_DIRECTION[direction]]
        held = {MODE_PARAMETERS[other][0]: self.background(direction)}
        drift = self._drift_prior()
        bounds = {name: self._bounds(direction, name, drift) for name in (*FOLLOWED, *SATURATION, *BASELINED)}
        prior = {**{name: self.prior.prior[name] for name in (*FOLLOWED, *SATURATION)},
                 **{name: self._prior(direction, name) for name in BASELINED}}
        if drift is not None:
            prior[DRIFTING] = drift
        healthy = {name: bounds[name] for name in (*FOLLOWED, *BASELINED)}
        logs = self._log_prior()
        b0, c0 = self.level(direction, "bearing_friction"), self.level(direction, "motor.coulomb_friction_nm")
        fault = {n: (p.low, p.high) for n, p in FAULT_PARAMETERS.items()}
        bearing_fault = (b0 + fault["bearing_friction"][0], b0 + fault["bearing_friction"][1])
        without = {name: prior[name] for name in (*FOLLOWED, *SATURATION)}  # priors when a baselined one is the fault
        saturation = {name: bounds[name] for name in SATURATION}
        bolt_name = MODE_PARAMETERS[bolt][0]
        obstacle = {n: fault[n] for n in MODE_PARAMETERS["obstacle"]}
        machine = {"drive_friction_nm": fault["drive_friction_nm"]}
        bearing_prior = {**without, "bearing_friction": prior["bearing_friction"]}
        return {
            "nominal": HypothesisSpec("nominal", healthy, held, prior=prior, log_prior=logs),
            bolt: HypothesisSpec(bolt, {bolt_name: fault[bolt_name], **healthy}, held,
                                 tuple({bolt_name: float(b)} for b in BOLT_GRID), prior, logs,
                                 settled_grid=({bolt_name: 0.0},), scanned=(bolt_name,)),
            "missing_bearing": HypothesisSpec(
                "missing_bearing", {**healthy, "bearing_friction": bearing_fault}, held,
                tuple({"bearing_friction": b0 + f} for f in (500.0, 2e3, 5e3, 1e4)),
                {**without, "motor.coulomb_friction_nm": prior["motor.coulomb_friction_nm"]}, logs, settled_grid=()),
            "obstacle": HypothesisSpec("obstacle", {**obstacle, **healthy, **saturation}, held, OBSTACLE_GRID, prior,
                                       logs, settled_grid=SMALL_OBSTACLE_GRID),
            "drive_friction": HypothesisSpec(
                "drive_friction", {**{n: bounds[n] for n in FOLLOWED}, "bearing_friction": bounds["bearing_friction"],
                                   **machine}, {**held, "motor.coulomb_friction_nm": c0},
                tuple({"drive_friction_nm": f} for f in (0.02, 0.08, 0.2)), bearing_prior, logs, settled_grid=()),
            "joint": HypothesisSpec(
                "joint", {bolt_name: fault[bolt_name], **obstacle, **healthy, **saturation,
                          "bearing_friction": bearing_fault, **machine}, held,
                prior={**without, "motor.coulomb_friction_nm": prior["motor.coulomb_friction_nm"]}, log_prior=logs),
        }

    def background(self, direction: str) -> float:
        """The other direction's bolt, as the throws that drive it estimated it (nominal when none did)."""
        other = OTHER_DIRECTION[direction]
        name = MODE_PARAMETERS[DRIVING_BOLT[other]][0]
        verdict = self.latest.get(other)
        if verdict is None or verdict.mode != DRIVING_BOLT[other]:
            return FAULT_PARAMETERS[name].nominal
        return verdict.estimates[verdict.mode].values[name]

    def _report(self, direction: str, estimate: Estimate) -> Reported:
        """Fault parameters relative to the baseline, each with the model's error added to the fit's."""
        b0 = self.level(direction, "bearing_friction")
        params, fit_std = {}, {}
        for name in FAULT_PARAMETERS:
            if name in estimate.params and (estimate.mode == "joint" or FAULT_PARAMETERS[name].mode == estimate.mode):
                raw = estimate.values[name] - (b0 if name == "bearing_friction" else 0.0)
                params[name] = self.errors.corrected(name, raw)
                fit_std[name] = estimate.std[name] / self.errors.slope(name)
        std = {name: float(np.hypot(fit_std[name], self.errors.std(name, params[name]))) for name in params}
        nuisance = {name: estimate.values[name] for name in NUISANCES}
        return Reported(estimate.mode, params, std, estimate.mse, (), nuisance, fit_std)

    def _unobservable(self, direction: str, mse: float) -> Reported:
        """The bolt this throw cannot see: its held value, flagged, no std (its hypothesis is the nominal one)."""
        other = DRIVING_BOLT[OTHER_DIRECTION[direction]]
        name = MODE_PARAMETERS[other][0]
        return Reported(other, {name: self.background(direction)}, {}, mse, (name,))

    # -- one throw ----------------------------------------------------------------------------
    def diagnose(self, throw: ThrowInput) -> Outcome:
        """The switch's decision after this throw (combining both directions), with this throw's verdict."""
        why = problem(throw)
        if why is not None:
            self.rail_m = None  # unknown where the blades are: assume the next throw starts closed
            return Outcome("unknown", why, None, None)
        start_rail = self.rail_m if self.rail_m is not None else CLOSED_START_M[throw.direction]
        m = measurement(throw, start_rail, self.drive)
        provisional = not self.baseline.complete
        weight = self.prior.model_weight if provisional else self.baseline.model_weight()
        gains = self._gains(throw.direction)
        previous = self.latest.get(throw.direction)
        prepared = self.estimator.prepare(m)  # once for the fits and the fitted outputs
        estimates = self.estimator.fit_all(
            prepared, self.specs(throw.direction), weight,
            decide=lambda fits: judge(throw.direction, fits, gains, self.evidence, self.negligible(fits))[0],
            warm=None if previous is None else {mode: e.values for mode, e in previous.estimates.items()},
            settled_mse=settled_mse(previous, m),
            slopes=None if previous is None else {mode: e.slopes for mode, e in previous.estimates.items()
                                                if e.slopes is not None})
        mode, found = judge(throw.direction, estimates, gains, self.evidence, self.negligible(estimates))
        for name, seen in found.items():
            self.evidence[name] = [seen, *self.evidence.get(name, [])][:EVIDENCE_THROWS]
        fitted = self.estimator.simulate(prepared, estimates[mode].values)
        reported = {name: self._report(throw.direction, e) for name, e in estimates.items()}
        hidden = self._unobservable(throw.direction, estimates["nominal"].mse)
        reported[hidden.mode] = hidden
        verdict = ThrowVerdict(throw.index, throw.direction, mode, found, estimates, reported,
                               float(fitted["rail_position_m"][-1]), fitted, provisional)
        self.latest[throw.direction] = verdict.kept()
        self.rail_m = verdict.end_rail_m
        if mode == "nominal":
            nominal = estimates["nominal"]
            self.baseline.follow(DRIFTING, nominal.values[DRIFTING])
            if provisional:
                levels = {name: nominal.values[name] for name in (*BASELINED, DRIFTING)}
                self.baseline.add(throw.direction, levels, healthy_gains(estimates), nominal.mse / nominal.effective_samples)
        decision, reason = self.combined()
        if provisional and self.baseline.complete:  # from now on its estimates depart from its own baseline
            self.health.reset()
            health = self.health.update(throw.index, {})
        else:
            health = self.health.update(throw.index, self._health_estimates(verdict, decision))
        return Outcome(decision, self._provisional_note(reason, provisional), verdict, self._follow(decision, verdict),
                       health)

    def negligible(self, estimates: dict[str, Estimate]) -> list[str]:
        """The bolt modes whose fitted offset (less the model's bias) is within BOLT_TOLERANCE: an adjustment."""
        out = []
        for mode in DRIVING_BOLT.values():
            if mode in estimates:
                name = MODE_PARAMETERS[mode][0]
                if abs(self.errors.corrected(name, estimates[mode].values[name])) < BOLT_TOLERANCE:
                    out.append(mode)
        return out

    def _health_estimates(self, verdict: ThrowVerdict, decision: str) -> dict[str, tuple[float, float]]:
        """Each tracked parameter as its own hypothesis estimated it in this throw, if the throw could see it and
        neither the throw nor the switch (over both directions) was decided as another fault: another fault's
        hypothesis bends to the decided one's effect (a bearing grown past detection shows as drive friction in the
        drive-friction hypothesis, which cannot free the bearing that far; a loose bolt as bearing friction).

        Once commissioned, the bearing friction counts the chairs' departure from their commissioned level too
        (CHAIRS_AS_BEARING): the diagnosis lets the chairs follow the weather throw by throw, which would also let
        them absorb bearings that dry out slowly, throw by throw, and hide the growth from the trend. Weather then
        wanders the bearing's level a little (a fifth drier chairs: some 400 N·s/m); a worn bearing shows whole."""
        out = {}
        for name in TRACKED:
            mode = FAULT_PARAMETERS[name].mode
            if {verdict.mode, decision} - {"nominal", "unknown", mode}:  # its hypothesis bends to another's effect
                continue
            reported = verdict.reported.get(mode)
            if reported is not None and name in reported.params and not reported.unobservable:
                out[name] = (reported.params[name], reported.fit_std[name])
        if "bearing_friction" in out and self.baseline.complete:
            value, std = out["bearing_friction"]
            chairs = verdict.estimates["missing_bearing"].values[DRIFTING]
            commissioned = self.baseline.level(verdict.direction, DRIFTING)[0]
            chairs_as_bearing = CHAIRS_AS_BEARING * (chairs - commissioned) / self.errors.slope("bearing_friction")
            out["bearing_friction"] = (value + chairs_as_bearing, std)  # corrected as _report corrects the bearing
        return out

    def _provisional_note(self, reason: str | None, provisional: bool) -> str | None:
        notes = [reason] if reason else []
        if provisional:
            seen = sum(min(self.baseline.count(d), self.baseline.needed) for d in DIRECTIONS)
            notes.append(f"provisional: commissioning {seen} of {self.baseline.needed * len(DIRECTIONS)}")
        outside = self.outside_population()
        if outside:
            notes.append("baseline outside the population: " + ", ".join(outside))
        return "; ".join(notes) or None

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

    # -- the decided fault over throws ------------------------------------------------------------
    def _follow(self, decision: str, verdict: ThrowVerdict) -> Combined | None:
        """Keep the throws since the decided fault appeared; combine those that can see it."""
        if decision in ("nominal", "unknown"):
            self.track.clear()
            return None
        if self.track and self.track[0].mode != decision and not any(v.mode == decision for v in self.track):
            self.track.clear()
        self.track.append(verdict.tracked())
        seeing = [v for v in self.track if observable(decision, v.direction) and v.mode == decision]
        if not seeing:
            return None
        return self.combine(decision, seeing)

    def combine(self, mode: str, verdicts: list[ThrowVerdict]) -> Combined:
        """A mode's parameters over several throws: the fits weighted by their variances, the model's error
        added as it stands after that many throws (its common part once, its per-throw part averaged)."""
        params, std, fit_std = {}, {}, {}
        for name in MODE_PARAMETERS[mode]:
            values = np.array([v.reported[mode].params[name] for v in verdicts])
            fit = np.array([max(v.reported[mode].fit_std[name], 1e-12) for v in verdicts])
            weights = 1.0 / fit**2
            mean = float(np.sum(weights * values) / np.sum(weights))
            params[name], fit_std[name] = mean, float(np.sqrt(1.0 / np.sum(weights)))
            std[name] = float(np.hypot(fit_std[name], self.errors.std(name, mean, len(verdicts))))
            if name == "bearing_friction":
                std[name] = float(np.hypot(std[name], self._unseen_chairs(verdicts, weights)))
        return Combined(mode, params, std, len(verdicts), verdicts[0].index, fit_std)

    def _unseen_chairs(self, verdicts: list[ThrowVerdict], weights: np.ndarray) -> float:
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
        baseline and its health over the throws so far."""
        return {"baseline": self.baseline.to_dict(), "health": self.health.to_dict()}

    def resume(self, state: dict) -> None:
        self.baseline = Baseline.from_dict(state["baseline"])
        if "health" in state:
            self.health.load(state["health"])
