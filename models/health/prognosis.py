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

Some faults grow in steps: a bolt works loose a few millimetres at a time, every ten or twenty
throws. Flat between its steps and leaping at them, such a parameter misleads a filter that follows
the latest trend (no growth for twenty throws, then a fast one). What its future depends on is its
average rate since it began to grow. So the trend and the throws to the limit come from a
broken-stick regression over the parameter's estimates since the switch was commissioned (the
filter's outliers left out unless the next estimate confirms them as a step): flat up to a hinge,
straight after it, the hinge where the two fit best (a changepoint; the line is the least-squares
one, for a linear growth and a staircase alike). It stands only where it fits better than a level
alone (an F test at TREND_FALSE_ALARM, with MIN_RISING estimates past the hinge at least); until
then no trend is shown (the filter's slope is reported, but not taken to the limit). What the line's
slope may be off by is the larger of
- the least-squares covariance from the residuals' scatter, widened by how correlated the residuals
  are (a staircase's are: models/diagnosis/estimation.py effective_samples), and
- the growth's own unsteadiness: how the rates over two, three and four equal stretches of it
  scatter (for a staircase of irregular steps, far more than its residuals about one line say).

Throws to the maintenance limit: (limit - line) / slope for a rising parameter, the line and slope at
the latest throw, its interval the 5 % and 95 % quantiles over draws of (line, slope) from their
covariance, with on the line the model's error and what the path strays from its line beyond the
estimates' noise (a staircase by a twelfth of a step squared). The line rather than the filter's
latest level: right after a staircase's step the level is a whole step ahead of the average growth,
and the next step is on average half an interval further off.

The state is `ok`, `watch` (the level past WATCH_SHARE of the limit, or the limit within
WATCH_THROWS at a trend beyond twice its standard deviation) or `alarm` (the level past the limit
by its standard deviation, or the limit reached within ALARM_THROWS even at the interval's far
end), with hysteresis both ways: a state is entered after ENTER throws in a row call for it (a
step, two estimates in a row far off on the same side, is two such throws already), and left only
after ENTER throws in a row fall short of it by relaxed criteria (a level HYSTERESIS of the limit
lower, a trend beyond one standard deviation, horizons twice as far), so a trend that wavers
about its threshold does not flap the state. A switch starts afresh when it is commissioned (its
estimates are departures from its own baseline from then on) and when it is re-commissioned (a
repaired one).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy import special

from railswitch.models.numerics.statistics import effective_samples
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
TURN_SIGMAS = 2.0  # a step against a slope beyond this many of its standard deviations is a repair (TrendFilter)
# Estimates kept per parameter (its history goes on the bus with the switch's state after every throw): beyond,
# the older half is merged pairwise, so old, flat stretches grow coarse and the recent ones stay whole.
HISTORY = 64
MIN_RISING = 6  # estimates at or past a hinge, at least
TREND_FALSE_ALARM = 1e-3  # the broken stick stands only when it fits better than a level alone at this F test's rate
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

    def update(self, value: float, variance: float) -> tuple[bool, bool, bool]:
        """Fuse one estimate. An innovation beyond SURPRISE standard deviations counts as at most that (Huber),
        so one odd throw barely moves the filter; two in a row on the same side are a step: the level restarts
        there. A step the way the trend goes keeps the trend (a staircase); one against a trend the slope shows is a
        repair (`turned`), and the trend starts afresh: a bearing grown at 300 N·s/m a throw and replaced without a
        word kept its slope and read 14 % of its limit nine throws later, on estimates under 4 %. Returns whether the
        estimate was taken for an outlier, whether it confirmed a step, and whether that step turned the trend."""
        if self.updates == 0:  # the first estimate sets the level; the slope is still unknown
            self._restart(value, variance)
            self.updates += 1
            return False, False, False
        innovation = value - self.x[0]
        s = float(self.p[0, 0]) + variance
        ratio = abs(innovation) / np.sqrt(s)
        outlier = ratio > SURPRISE
        if outlier:
            sign = int(np.sign(innovation))
            if self.surprised == sign:
                # against a trend the slope shows (beyond TURN_SIGMAS of it), the step is a repair, not a stair
                turned = bool(sign * self.x[1] < -TURN_SIGMAS * np.sqrt(max(self.p[1, 1], 0.0)))
                self._restart(value, variance, keep_slope=not turned)
                self.surprised = 0
                self.updates += 1
                return False, True, turned
            self.surprised = sign
            variance = variance * (ratio / SURPRISE) ** 2
            s = float(self.p[0, 0]) + variance
        else:
            self.surprised = 0
        gain = self.p[:, 0] / s
        self.x = self.x + gain * innovation
        self.p = self.p - np.outer(gain, self.p[0, :])
        self.updates += 1
        return outlier, False, False

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


_STALE = object()  # a History's fit before it is computed, or after an estimate came
# A History's rows, one per estimate kept: throw, value, its fit's variance, how many estimates it merges. An array,
# not a list of tuples of floats: a switch keeps one per parameter, each up to HISTORY rows, for as long as it serves.
ROW_COLUMNS = 4


def _merged(old: np.ndarray) -> np.ndarray:
    """Consecutive pairs of rows each as one: throw, value and variance averaged by their counts, the counts
    added (an odd last row is left out)."""
    a, b = old[0:-1:2], old[1::2]
    n = a[:, 3:] + b[:, 3:]
    return np.hstack([(a[:, :3] * a[:, 3:] + b[:, :3] * b[:, 3:]) / n, n])


@dataclass
class History:
    """A parameter's estimates over the throws: rows of (throw, value, its fit's variance, how many estimates it
    merges)."""

    rows: np.ndarray = field(default_factory=lambda: np.empty((0, ROW_COLUMNS)))
    pending: tuple[float, float, float] | None = None  # the latest estimate, when the filter took it for an outlier
    _line: object = field(default=_STALE, repr=False, compare=False)  # the latest fit (fit_broken_stick's)

    def record(self, throw: float, value: float, variance: float, outlier: bool, step: bool) -> None:
        """One estimate, unless the filter took it for an outlier: that one waits, and counts only if the next one
        confirms it as a step."""
        if step and self.pending is not None:
            self.add(*self.pending)
        self.pending = (throw, value, variance) if outlier else None
        if not outlier:
            self.add(throw, value, variance)

    def add(self, throw: float, value: float, variance: float) -> None:
        self.rows = np.vstack([self.rows, [float(throw), float(value), float(variance), 1.0]])
        self._line = _STALE
        if len(self.rows) > HISTORY:  # halve the resolution of the older half, keep the recent half whole
            old, recent = self.rows[:HISTORY // 2], self.rows[HISTORY // 2:]
            merged = _merged(old)
            self.rows = np.vstack([merged, old[len(merged) * 2:], recent])

    def broken_stick(self, now: float) -> tuple[np.ndarray, np.ndarray, float] | None:
        """(line, slope) at `now`, their covariance and how far the path strays from the line (a variance), from
        the best flat-then-straight fit; None while no such fit is better than a level alone."""
        if self._line is _STALE:
            self._line = fit_broken_stick(*self.rows.T.copy()) if len(self.rows) else None
        if self._line is None:
            return None
        hinge, coefficients, covariance, path = self._line
        at = np.array([[1.0, max(now - hinge, 0.0)], [0.0, 1.0]])  # (at the hinge, slope) to (line at now, slope)
        return at @ coefficients, at @ covariance @ at.T, path

    def to_dict(self) -> dict:
        return {"rows": [[t, v, var, int(n)] for t, v, var, n in self.rows.tolist()],
                "pending": None if self.pending is None else list(self.pending)}

    @classmethod
    def from_dict(cls, data: dict) -> History:
        rows = np.array([[float(t), float(v), float(var), int(n)] for t, v, var, n in data["rows"]],
                        dtype=float).reshape(-1, ROW_COLUMNS)
        pending = data.get("pending")
        return cls(rows, None if pending is None else tuple(float(x) for x in pending))


def _suffix(values: np.ndarray) -> np.ndarray:
    return np.cumsum(values[::-1])[::-1]


def _rate(t: np.ndarray, v: np.ndarray, n: np.ndarray) -> float:
    """Weighted least-squares slope."""
    tc = t - np.sum(n * t) / np.sum(n)
    return float(np.sum(n * tc * v) / np.sum(n * tc * tc))


def fit_broken_stick(t: np.ndarray, v: np.ndarray, fit_variance: np.ndarray,
                     n: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, float] | None:
    """The flat-then-straight least-squares fit over every hinge at an estimate with MIN_RISING estimates at or
    after it (sums over the estimates past each hinge, so all hinges cost one pass): (hinge, (value at the hinge,
    slope), their covariance, the path's stray variance), or None when it fits no better than a level alone."""
    if len(t) < MIN_RISING + 3:
        return None
    origin, mean_v = t[0], float(np.sum(n * v) / np.sum(n))
    t, v = t - origin, v - mean_v  # centred: the sums below do not cancel
    s0, s1, s2 = _suffix(n), _suffix(n * t), _suffix(n * t * t)
    v0, t1 = _suffix(n * v), _suffix(n * t * v)
    hinges = np.arange(len(t) - MIN_RISING + 1)
    th = t[hinges]
    sw, sy, syy = float(np.sum(n)), float(np.sum(n * v)), float(np.sum(n * v * v))
    sx = s1[hinges] - th * s0[hinges]
    sxx = s2[hinges] - 2 * th * s1[hinges] + th * th * s0[hinges]
    sxy = t1[hinges] - th * v0[hinges]
    det = sw * sxx - sx**2
    ok = det > 1e-9 * np.maximum(sw * sxx, 1e-300)
    if not ok.any():
        return None
    slope = np.where(ok, (sw * sxy - sx * sy) / np.where(ok, det, 1.0), 0.0)
    intercept = (sy - slope * sx) / sw
    rss = np.where(ok, syy - intercept * sy - slope * sxy, np.inf)
    best = int(np.argmin(rss))
    x = np.maximum(t - th[best], 0.0)
    residual = v - intercept[best] - slope[best] * x
    rss_best = float(np.sum(n * residual**2))
    if rss_best <= 0:
        return None
    f = (syy - rss_best) / 2.0 / (rss_best / (len(v) - 3))  # syy: the level alone's (v is centred)
    if f < special.fdtri(2, len(v) - 3, 1.0 - TREND_FALSE_ALARM):  # no better than a level: no trend shown
        return None
    scatter = rss_best / (len(v) - 2)  # of one estimate about the line (a merged row's weight is its count)
    correlated = len(v) / max(min(effective_samples(residual[:, None]), len(v)), 1.0)
    covariance = scatter * correlated * np.linalg.inv(np.array([[sw, sx[best]], [sx[best], sxx[best]]]))
    rising = t >= th[best]
    covariance[1, 1] = max(covariance[1, 1], unsteadiness(t[rising], v[rising], n[rising]))
    stray = max(scatter - float(np.sum(n * fit_variance) / sw), 0.0)
    return float(th[best] + origin), np.array([intercept[best] + mean_v, slope[best]]), covariance, stray


def unsteadiness(t: np.ndarray, v: np.ndarray, n: np.ndarray) -> float:
    """A growth's own unsteadiness, as a variance of its average rate, whatever the residuals about one line say:
    the rate over each of B equal stretches of it scatters by sqrt(B) times the whole's standard deviation (for a
    steady random growth, such as a staircase of irregular steps); the mean over B = 2, 3 and 4 stretches."""
    estimates = []
    for blocks in (2, 3, 4):
        edges = np.linspace(t[0], t[-1], blocks + 1)
        part = np.minimum(np.searchsorted(edges, t, side="right") - 1, blocks - 1)
        if np.min(np.bincount(part, minlength=blocks)) < 3:
            continue
        rates = [_rate(t[part == k], v[part == k], n[part == k]) for k in range(blocks)]
        estimates.append(float(np.var(rates, ddof=1)) / blocks)
    return float(np.mean(estimates)) if estimates else 0.0


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


@lru_cache(maxsize=8)
def standard_draws(seed: int) -> np.ndarray:
    """DRAWS standard normal pairs (read only): one array for every switch's tracker of a seed, not 6.4 kB each."""
    draws = np.random.default_rng(seed).standard_normal((DRAWS, 2))
    draws.flags.writeable = False
    return draws


class HealthTracker:
    """One switch's parameters over its throws; feed every diagnosed throw."""

    def __init__(self, limits: dict[str, float] | None = None, model_error: dict[str, float] | None = None,
                 seed: int = 0):
        self.limits = {**DEFAULT_LIMITS, **(limits or {})}
        self.model_error = model_error or {}
        self._normal = standard_draws(seed)  # reused: the same draws each throw
        self.reset()

    def reset(self) -> None:
        """A repaired or re-commissioned switch starts afresh."""
        self.last_throw: float | None = None  # the latest throw's place on the histories' axis
        self.renumbered = 0  # added to the source's throw indices since it numbered them from 0 again
        self.filters: dict[str, TrendFilter] = {}
        self.histories: dict[str, History] = {}
        self.states: dict[str, str] = {}
        self._calls: dict[str, tuple[str, int]] = {}
        self.restart(TRACKED)

    def restart(self, names) -> None:
        """These parameters start afresh (a repaired fault: its level went back at once, and its growth so far says
        nothing of what comes)."""
        for name in names:
            span = FAULT_PARAMETERS[name].high - FAULT_PARAMETERS[name].low
            q = np.diag([(LEVEL_WANDER * span) ** 2, (SLOPE_WANDER * span) ** 2])
            self.filters[name] = TrendFilter(q=q)
            self.histories[name] = History()
            self.states[name] = "ok"
            self._calls[name] = ("ok", 0)

    def to_dict(self) -> dict:
        """What a restarted diagnoser needs to go on tracking: every filter and the alarm states."""
        return {"filters": {name: f.to_dict() for name, f in self.filters.items()}, "states": dict(self.states),
                "histories": {name: h.to_dict() for name, h in self.histories.items() if len(h.rows)},
                "calls": {name: list(call) for name, call in self._calls.items()},
                "last_throw": self.last_throw, "renumbered": self.renumbered}

    def load(self, data: dict) -> None:
        for name, filter_state in data["filters"].items():
            if name in self.filters:
                self.filters[name].load(filter_state)
        for name, rows in data.get("histories", {}).items():  # a state saved before histories were kept has none
            if name in self.histories:
                self.histories[name] = History.from_dict(rows)
        self.states.update({name: s for name, s in data["states"].items() if name in self.states})
        self._calls.update({name: (c[0], int(c[1])) for name, c in data["calls"].items() if name in self._calls})
        # a state saved before these were kept: its histories' latest throw
        self.last_throw = data.get("last_throw", max((float(h.rows[-1, 0]) for h in self.histories.values()
                                                      if len(h.rows)), default=None))
        self.renumbered = int(data.get("renumbered", 0))

    def _place(self, throw_index: int) -> float:
        """A throw's place on the histories' axis: its index, moved on past the latest throw when the source numbers
        its throws from 0 again (a trackside unit restarted or replaced), so the switch's life goes on forward."""
        if self.last_throw is not None and throw_index + self.renumbered <= self.last_throw:
            self.renumbered = int(self.last_throw) + 1 - throw_index
        self.last_throw = float(throw_index + self.renumbered)
        return self.last_throw

    def update(self, throw_index: int, estimates: dict[str, tuple[float, float]]) -> Health:
        """`estimates`: parameter -> (value, fit std) from the hypotheses this throw could see."""
        place = self._place(throw_index)
        out = {}
        for name, tracker in self.filters.items():
            tracker.predict()
            step = False
            if name in estimates:
                value, std = estimates[name]
                variance = max(std, 1e-12) ** 2
                outlier, step, turned = tracker.update(value, variance)
                if turned:  # the growth so far is over: the history starts at the step
                    self.histories[name] = History(pending=self.histories[name].pending)
                self.histories[name].record(place, value, variance, outlier, step)
            out[name] = self._health(name, tracker, self.histories[name].broken_stick(place), step)
        ranked = [h for h in out.values() if self.filters[h.name].updates]
        worst = min(ranked, key=lambda h: (h.throws_to_limit if h.throws_to_limit is not None else np.inf,
                                           -h.level / h.limit)) if ranked else None
        state = max((h.state for h in out.values()), key=STATES.index)
        return Health(throw_index, state, worst.name if worst else None, out)

    def _health(self, name: str, tracker: TrendFilter, line: tuple[np.ndarray, np.ndarray, float] | None = None,
                step: bool = False) -> ParameterHealth:
        """The parameter's level (the filter's), its trend and throws to the limit (the broken-stick line's once
        it has one, the filter's before)."""
        limit = self.limits[name]
        if tracker.updates == 0:
            return ParameterHealth(name, 0.0, float("inf"), 0.0, float("inf"), limit, None, None, None, "ok")
        model_error = self.model_error.get(name, 0.0)
        level = float(tracker.x[0])
        level_std = float(np.hypot(np.sqrt(max(tracker.p[0, 0], 0.0)), model_error))
        mean, covariance, stray = line if line is not None else (tracker.x, tracker.p, 0.0)
        slope, slope_std = float(mean[1]), float(np.sqrt(max(covariance[1, 1], 0.0)))
        if level >= limit:
            to_limit, low, high = 0.0, 0.0, 0.0
        elif line is None:  # no trend shown yet (the filter's slope is reported, not extrapolated)
            to_limit, low, high = None, None, None
        else:  # the path strays from its line on the way (a staircase's steps) as much as it has so far
            to_limit, low, high = self._throws_to_limit(mean, covariance, limit, np.sqrt(model_error**2 + stray))
        calls = tuple(self._call(name, level, level_std, slope, slope_std, to_limit, high, relaxed)
                      for relaxed in (False, True))
        by_level = self._call(name, level, level_std, slope, slope_std, None, None, False)
        state = self._state(name, calls, step and by_level == calls[0])
        return ParameterHealth(name, level, level_std, 100.0 * slope, 100.0 * slope_std, limit, to_limit, low, high, state)

    def _throws_to_limit(self, mean: np.ndarray, covariance: np.ndarray, limit: float,
                         level_error: float) -> tuple[float | None, float | None, float | None]:
        """Median-free estimate (limit - level) / slope and its 5 %-95 % interval over draws of (level, slope)
        from their covariance, with `level_error` (a standard deviation) more on the level."""
        level, slope = mean
        if level >= limit:
            return 0.0, 0.0, 0.0
        if slope <= 0:
            return None, None, None
        covariance = covariance + np.diag([level_error**2, 0.0])
        eigenvalues, vectors = np.linalg.eigh(covariance)
        draws = mean + self._normal @ (vectors * np.sqrt(np.maximum(eigenvalues, 0.0))).T
        rising = draws[:, 1] > 0
        times = np.sort(np.maximum((limit - draws[rising, 0]) / draws[rising, 1], 0.0))
        # quantiles over every draw: a draw that never rises never reaches the limit (an infinite time, above all)
        low = float(times[int(LOW_QUANTILE * DRAWS)]) if int(LOW_QUANTILE * DRAWS) < len(times) else None
        high = float(times[int(HIGH_QUANTILE * DRAWS)]) if int(HIGH_QUANTILE * DRAWS) < len(times) else None
        return float((limit - level) / slope), low, high

    def _call(self, name: str, level: float, level_std: float, slope: float, slope_std: float,
              to_limit: float | None, high: float | None, relaxed: bool) -> str:
        """The state a throw calls for; `relaxed`: the criteria a state already entered is held by (a level
        HYSTERESIS of the limit lower, a trend beyond one standard deviation instead of two, horizons twice as
        far), so that what brought a state about must clearly be gone before it is left."""
        limit = self.limits[name]
        margin, sigmas, horizon = (HYSTERESIS * limit, 1.0, 2.0) if relaxed else (0.0, 2.0, 1.0)
        heading = to_limit is not None and slope > sigmas * slope_std  # a trend that is there, not noise
        past = level - (0.0 if relaxed else level_std) >= limit - margin
        if past or (heading and high is not None and high <= horizon * ALARM_THROWS):
            return "alarm"
        if level >= WATCH_SHARE * limit - margin or (heading and to_limit <= horizon * WATCH_THROWS):
            return "watch"
        return "ok"

    def _state(self, name: str, calls: tuple[str, str], step: bool = False) -> str:
        """The state after this throw, from its (strict, relaxed) calls: a higher state is entered after ENTER
        throws in a row call for it (a step, two estimates in a row far off on the same side, is two throws calling
        already), a state is left after ENTER throws in a row fall short of it even by the relaxed criteria."""
        called, held = calls
        current = self.states[name]
        if STATES.index(called) > STATES.index(current):
            wish = called
        elif STATES.index(held) < STATES.index(current):
            wish = held
        else:
            wish = current
        previous, count = self._calls[name]
        count = count + 1 if wish == previous else 1
        if step:  # a step the level alone calls for (its trend is not shown by one step)
            count = max(count, ENTER)
        self._calls[name] = (wish, count)
        if wish != current and count >= ENTER:
            self.states[name] = wish
        return self.states[name]
