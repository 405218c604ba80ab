"""A switch's health over time: each fault parameter's level, trend and throws to its limit (issue 15).

Every throw's diagnosis estimates each fault parameter under its own hypothesis, as a departure
from the switch's commissioned baseline, with the fit's standard deviation (and a model error that
is the same in every throw). A local-linear-trend Kalman filter per parameter fuses them:

    level(k+1) = level(k) + slope(k) + w_level,   slope(k+1) = slope(k) + w_slope
    estimate(k) = level(k) + v,                   v ~ N(0, fit std^2)

(Harvey, "Forecasting, structural time series models and the Kalman filter", 1989, ch. 2). The
process noises allow a slowly growing fault: a level that moves by LEVEL_WANDER of the parameter's
range per throw and a slope that changes by SLOPE_WANDER of it per throw squared. A bolt is updated
only by the throws it drives; the other parameters by every throw. The model's error does not
average out, so it is added once to the level's reported spread (not fed to the filter).

Throws to the maintenance limit: (limit - level) / slope for a rising parameter, its interval the
5 % and 95 % quantiles over draws of (level, slope) from the filter's covariance. The state is
`ok`, `watch` (the limit within WATCH_THROWS at the present trend, if the trend is beyond twice its
standard deviation, or the level past WATCH_SHARE of it) or `alarm` (the level past the limit, or reached within ALARM_THROWS even at the interval's
far end), with hysteresis: a state is entered after ENTER consecutive throws that call for it and
left only when the level has fallen back by HYSTERESIS of the limit. A re-commissioned switch (a
repaired one) starts afresh.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from railswitch.schemas.faults import FAULT_PARAMETERS

# Maintenance limits (departures from the commissioned baseline) where a switch needs a visit. Defaults,
# configurable per deployment (HealthTracker(limits=...)): a third of a bolt's range (free play that
# delays the blades by a second), half the bearing range, a tenth of the obstacle's, a drive friction
# two thirds of the motor's own Coulomb friction.
DEFAULT_LIMITS = {
    "left_bolt_offset": 0.06,
    "right_bolt_offset": 0.06,
    "bearing_friction": 5000.0,
    "obstacle_friction": 30_000.0,
    "drive_friction_nm": 0.08,
}
TRACKED = tuple(DEFAULT_LIMITS)  # the obstacle's position is no trend
LEVEL_WANDER = 1e-4  # level's random walk per throw, as a share of the parameter's range
SLOPE_WANDER = 5e-5  # slope's random walk per throw, as a share of the parameter's range
WATCH_THROWS = 500
ALARM_THROWS = 50
WATCH_SHARE = 0.5
HYSTERESIS = 0.1
ENTER = 2
SURPRISE = 4.0  # innovations beyond this many standard deviations are outliers (or, twice running, a step)
STATES = ("ok", "watch", "alarm")
DRAWS = 400
LOW_QUANTILE, HIGH_QUANTILE = 0.05, 0.95  # of the throws-to-limit interval


@dataclass
class TrendFilter:
    """Level and slope (per throw) of one parameter, with their covariance."""

    x: np.ndarray = field(default_factory=lambda: np.zeros(2))
    p: np.ndarray = field(default_factory=lambda: np.diag([1e12, 1e12]))
    updates: int = 0
    q: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    surprised: int = 0  # the sign of the last throw's innovation when it was an outlier, else 0

    def predict(self) -> None:
        f = np.array([[1.0, 1.0], [0.0, 1.0]])
        self.x = f @ self.x
        self.p = f @ self.p @ f.T + self.q

    def update(self, value: float, variance: float) -> None:
        """Fuse one estimate. An innovation beyond SURPRISE standard deviations counts as at most that (Huber),
        so one odd throw barely moves the filter; two in a row on the same side are a step: the level restarts there."""
        if self.updates == 0:  # the first estimate sets the level; the slope is still unknown
            self._restart(value, variance)
            self.updates += 1
            return
        innovation = value - self.x[0]
        s = float(self.p[0, 0]) + variance
        ratio = abs(innovation) / np.sqrt(s)
        if ratio > SURPRISE:
            sign = int(np.sign(innovation))
            if self.surprised == sign:
                self._restart(value, variance, keep_slope=True)
                self.surprised = 0
                self.updates += 1
                return
            self.surprised = sign
            variance = variance * (ratio / SURPRISE) ** 2
            s = float(self.p[0, 0]) + variance
        else:
            self.surprised = 0
        gain = self.p[:, 0] / s
        self.x = self.x + gain * innovation
        self.p = self.p - np.outer(gain, self.p[0, :])
        self.updates += 1

    def to_dict(self) -> dict:
        return {"x": self.x.tolist(), "p": self.p.tolist(), "updates": self.updates, "surprised": self.surprised}

    def load(self, data: dict) -> None:
        self.x, self.p = np.array(data["x"], dtype=float), np.array(data["p"], dtype=float)
        self.updates, self.surprised = int(data["updates"]), int(data["surprised"])

    def _restart(self, value: float, variance: float, keep_slope: bool = False) -> None:
        """The level starts again at `value`. After a step (keep_slope) the trend goes on: a bolt loosening a few
        millimetres at a time is a staircase whose steps are its slope."""
        if keep_slope and self.p[1, 1] < 1e11:
            self.x = np.array([value, self.x[1]])
            self.p = np.diag([variance, self.p[1, 1]])
        else:
            self.x = np.array([value, 0.0])
            self.p = np.diag([variance, self.q[1, 1] * 1e4])


@dataclass(frozen=True)
class ParameterHealth:
    name: str
    level: float
    level_std: float
    slope_per_100: float
    slope_std_per_100: float
    limit: float
    throws_to_limit: float | None  # None: not heading for its limit
    throws_to_limit_low: float | None
    throws_to_limit_high: float | None
    state: str


@dataclass(frozen=True)
class Health:
    """A switch's health after one throw."""

    throw_index: int
    state: str  # the worst parameter's
    worst: str | None  # the parameter closest to its limit (fewest throws, else highest share of it)
    parameters: dict[str, ParameterHealth]


class HealthTracker:
    """One switch's parameters over its throws; feed every diagnosed throw."""

    def __init__(self, limits: dict[str, float] | None = None, model_error: dict[str, float] | None = None,
                 seed: int = 0):
        self.limits = {**DEFAULT_LIMITS, **(limits or {})}
        self.model_error = model_error or {}
        self._normal = np.random.default_rng(seed).standard_normal((DRAWS, 2))  # reused: the same draws each throw
        self.reset()

    def reset(self) -> None:
        """A repaired or re-commissioned switch starts afresh."""
        self.filters: dict[str, TrendFilter] = {}
        for name in TRACKED:
            span = FAULT_PARAMETERS[name].high - FAULT_PARAMETERS[name].low
            q = np.diag([(LEVEL_WANDER * span) ** 2, (SLOPE_WANDER * span) ** 2])
            self.filters[name] = TrendFilter(q=q)
        self.states = dict.fromkeys(TRACKED, "ok")
        self._calls = {name: ("ok", 0) for name in TRACKED}

    def to_dict(self) -> dict:
        """What a restarted diagnoser needs to go on tracking: every filter and the alarm states."""
        return {"filters": {name: f.to_dict() for name, f in self.filters.items()}, "states": dict(self.states),
                "calls": {name: list(call) for name, call in self._calls.items()}}

    def load(self, data: dict) -> None:
        for name, filter_state in data["filters"].items():
            if name in self.filters:
                self.filters[name].load(filter_state)
        self.states.update({name: s for name, s in data["states"].items() if name in self.states})
        self._calls.update({name: (c[0], int(c[1])) for name, c in data["calls"].items() if name in self._calls})

    def update(self, throw_index: int, estimates: dict[str, tuple[float, float]]) -> Health:
        """`estimates`: parameter -> (value, fit std) from the hypotheses this throw could see."""
        out = {}
        for name, tracker in self.filters.items():
            tracker.predict()
            if name in estimates:
                value, std = estimates[name]
                tracker.update(value, max(std, 1e-12) ** 2)
            out[name] = self._health(name, tracker)
        ranked = [h for h in out.values() if self.filters[h.name].updates]
        worst = min(ranked, key=lambda h: (h.throws_to_limit if h.throws_to_limit is not None else np.inf,
                                           -h.level / h.limit)) if ranked else None
        state = max((h.state for h in out.values()), key=STATES.index)
        return Health(throw_index, state, worst.name if worst else None, out)

    def _health(self, name: str, tracker: TrendFilter) -> ParameterHealth:
        limit = self.limits[name]
        level, slope = float(tracker.x[0]), float(tracker.x[1])
        level_std = float(np.hypot(np.sqrt(max(tracker.p[0, 0], 0.0)), self.model_error.get(name, 0.0)))
        slope_std = float(np.sqrt(max(tracker.p[1, 1], 0.0)))
        if tracker.updates == 0:
            return ParameterHealth(name, 0.0, float("inf"), 0.0, float("inf"), limit, None, None, None, "ok")
        to_limit, low, high = self._throws_to_limit(tracker, limit, self.model_error.get(name, 0.0))
        rising = slope > 2.0 * slope_std  # a trend that is there, not the filter's noise
        state = self._state(name, level, level_std, to_limit if rising else None, high)
        return ParameterHealth(name, level, level_std, 100.0 * slope, 100.0 * slope_std, limit, to_limit, low, high, state)

    def _throws_to_limit(self, tracker: TrendFilter, limit: float,
                         model_error: float) -> tuple[float | None, float | None, float | None]:
        """Median-free estimate (limit - level) / slope and its 5 %-95 % interval over draws of (level, slope)
        from the filter's covariance with the model's error on the level."""
        level, slope = tracker.x
        if level >= limit:
            return 0.0, 0.0, 0.0
        if slope <= 0:
            return None, None, None
        covariance = tracker.p + np.diag([model_error**2, 0.0])
        eigenvalues, vectors = np.linalg.eigh(covariance)
        draws = tracker.x + self._normal @ (vectors * np.sqrt(np.maximum(eigenvalues, 0.0))).T
        rising = draws[:, 1] > 0
        times = np.sort(np.maximum((limit - draws[rising, 0]) / draws[rising, 1], 0.0))
        # quantiles over every draw: a draw that never rises never reaches the limit (an infinite time, above all)
        low = float(times[int(LOW_QUANTILE * DRAWS)]) if int(LOW_QUANTILE * DRAWS) < len(times) else None
        high = float(times[int(HIGH_QUANTILE * DRAWS)]) if int(HIGH_QUANTILE * DRAWS) < len(times) else None
        return float((limit - level) / slope), low, high

    def _state(self, name: str, level: float, level_std: float, to_limit: float | None, high: float | None) -> str:
        limit = self.limits[name]
        if level - level_std >= limit or (to_limit is not None and high is not None and high <= ALARM_THROWS):
            called = "alarm"
        elif level >= WATCH_SHARE * limit or (to_limit is not None and to_limit <= WATCH_THROWS):
            called = "watch"
        else:
            called = "ok"
        current = self.states[name]
        previous, count = self._calls[name]
        count = count + 1 if called == previous else 1
        self._calls[name] = (called, count)
        if STATES.index(called) > STATES.index(current):
            if count >= ENTER:
                self.states[name] = called
        elif STATES.index(called) < STATES.index(current):
            # leave only when the level has fallen back below the state's threshold by HYSTERESIS of the limit
            threshold = limit if current == "alarm" else WATCH_SHARE * limit
            if level < threshold - HYSTERESIS * limit and count >= ENTER:
                self.states[name] = called
        return self.states[name]
