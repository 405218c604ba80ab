"""A throw's features as point-machine monitors trend them, and their trend against a band learnt at commissioning.

Computed from what every source gives alike (the samples from the start event, the reference profile and the
throw's duration), so a throw read from MCAP, CSV or the bus has the same features:

- throw time: from the start event (the motor starts) to the end position, where the motor stops (the last sample
  turning faster than STILL_SHARE of the reference's top speed); a unit that logs the current alone gives the
  end event, when the point machine detected its end position;
- the stroke: while the reference asks for its top speed, from SETTLE_S after it first does (the speed loop's
  overshoot, in which the current swings through zero, ends the start-up surge) to when it starts slowing down;
- peak and mean current: the highest and the mean magnitude of the current over the stroke;
- (not trended) the stroke's current profile: its mean magnitude in each of PROFILE_BINS equal shares of the rod's
  stroke (0 at the left end position, 1 at the right; by the reference's angle, so a current log gives it too),
  against the commissioning throws' mean profile: where a load sits along the stroke (SwitchDiagnoser._binding);
- energy: the current's magnitude integrated over the throw, times the supply's nominal voltage (what a monitor
  that logs the current alone reports; the supply's own voltage is not measured);
- lock current: the mean magnitude over the stroke's part in which the crank runs into its dead centre, where the
  end-position hook latches (models/plant/lock.py: the last end_zone of rod travel, by the reference's angle);
- speed lag: how far the motor's speed fell short of its reference at most, from the start to the stroke's end (a
  unit that logs the speed only): a speed-controlled drive follows its reference unless it runs short of voltage.

A feature the throw cannot give (no stroke at top speed, no sample in the lock zone) is None.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from railswitch.models.plant.drive import DriveParams
from railswitch.models.plant.lock import LockParams
from railswitch.models.plant.reference import DIRECTIONS, Reference
from railswitch.models.plant.signals import MotorSignals
from railswitch.schemas.plant import PLANT_PARAMETERS

FEATURES = ("throw_time_s", "peak_current_a", "mean_current_a", "energy_j", "lock_current_a", "speed_lag_rad_s")
TOP_SHARE = 0.95  # of the reference's top speed: the stroke
STILL_SHARE = 0.1  # of the reference's top speed: the motor has stopped (a throw's end, and models/diagnosis/switch_diagnoser.py
# cut_short: a throw that ends while the motor turns faster is cut short)
SETTLE_S = 0.1  # after the reference first reaches its top speed: the start-up surge and the speed loop's overshoot
SUPPLY_V = PLANT_PARAMETERS["motor.supply_v"].nominal
# The band a commissioned switch's feature may wander within: BAND_SIGMAS of its spread over the commissioning throws,
# at least BAND_FLOOR of its level (the weather moves a healthy switch's currents: chairs a fifth drier, a cold night)
BAND_SIGMAS = 4.0
BAND_FLOOR = 0.1
RECENT_THROWS = 20  # per direction: what a feature's slope is fitted over
PROFILE_BINS = 40  # of the rod's stroke: a fortieth is 12 mm of rod, about three samples of a throw's stroke


def throw_features(t_s: np.ndarray, signals: MotorSignals, reference: Reference, duration_s: float | None,
                   drive: DriveParams = DriveParams(), lock: LockParams = LockParams()) -> dict[str, float | None]:
    """The features of one throw (module docstring), by name with its unit."""
    current = np.abs(np.asarray(signals.current_a, dtype=float))
    top = float(np.max(np.abs(reference.velocity_rad_s)))
    out: dict[str, float | None] = dict.fromkeys(FEATURES)
    if len(t_s) < 2 or top <= 0.0:
        return out
    out["throw_time_s"] = _throw_time(t_s, signals, top, duration_s)
    out["energy_j"] = float(SUPPLY_V * np.trapezoid(current, t_s))
    commanded, fast, stroke, angle = _stroke(t_s, reference, top)
    if np.count_nonzero(stroke) >= 2:
        out["peak_current_a"] = float(np.max(current[stroke]))
        out["mean_current_a"] = float(np.mean(current[stroke]))
    # against the angle at which the crank enters its lock zone
    entry = drive.gear_ratio * math.acos(lock.end_zone_m / drive.crank_radius_m - 1.0)
    locking = stroke & (angle >= entry)
    if np.count_nonzero(locking) >= 2:
        out["lock_current_a"] = float(np.mean(current[locking]))
    if signals.velocity_rad_s is not None:
        until = t_s <= float(reference.t_s[fast[-1]])
        out["speed_lag_rad_s"] = max(0.0, float(np.max(commanded[until] - np.abs(signals.velocity_rad_s[until]))))
    return out


def _stroke(t_s: np.ndarray, reference: Reference, top: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The reference's speed magnitude at each sample, its top-speed breakpoints, the stroke's samples (module
    docstring) and the reference's motor angle at each sample (from the throw's start, a magnitude)."""
    commanded = np.abs(reference(t_s))
    fast = np.flatnonzero(np.abs(reference.velocity_rad_s) >= TOP_SHARE * top)
    first_top = float(reference.t_s[fast[0]])
    stroke = (commanded >= TOP_SHARE * top) & (t_s >= first_top + SETTLE_S)
    stroke &= t_s <= float(reference.t_s[fast[-1]])  # before it slows down
    angle = np.concatenate([[0.0], np.cumsum(0.5 * (commanded[1:] + commanded[:-1]) * np.diff(t_s))])
    return commanded, fast, stroke, angle


def stroke_profile(t_s: np.ndarray, signals: MotorSignals, reference: Reference,
                   drive: DriveParams = DriveParams()) -> np.ndarray | None:
    """The stroke's mean current magnitude in each of PROFILE_BINS shares of the rod's stroke, from its left end
    position (NaN where no stroke sample fell), or None when the throw has no stroke at top speed."""
    top = float(np.max(np.abs(reference.velocity_rad_s)))
    if len(t_s) < 2 or top <= 0.0:
        return None
    _, _, stroke, angle = _stroke(t_s, reference, top)
    if np.count_nonzero(stroke) < 2:
        return None
    share = 0.5 * (1.0 - np.cos(np.minimum(angle[stroke] / drive.gear_ratio, np.pi)))
    if np.sum(reference.velocity_rad_s) < 0.0:  # right to left: the rod comes back from the right end
        share = 1.0 - share
    bins = np.minimum((share * PROFILE_BINS).astype(int), PROFILE_BINS - 1)
    current = np.abs(np.asarray(signals.current_a, dtype=float))[stroke]
    count = np.bincount(bins, minlength=PROFILE_BINS)
    with np.errstate(invalid="ignore"):
        return np.bincount(bins, weights=current, minlength=PROFILE_BINS) / count


def _throw_time(t_s: np.ndarray, signals: MotorSignals, top: float, duration_s: float | None) -> float | None:
    velocity = signals.velocity_rad_s
    if velocity is None:
        return duration_s
    turning = np.flatnonzero(np.abs(velocity) > STILL_SHARE * top)
    return float(t_s[turning[-1]]) if len(turning) else duration_s


def _row(index: int, features: dict[str, float | None]) -> list[float]:
    """A recent throw as FeatureTrends keeps it: its index, then its features in FEATURES order, NaN where it had
    none."""
    return [float(index), *(np.nan if features.get(name) is None else float(features[name]) for name in FEATURES)]


def _no_recent() -> np.ndarray:
    return np.empty((0, 1 + len(FEATURES)))


@dataclass
class FeatureTrends:
    """A switch's features per direction: the commissioning throws' values (its band) and its recent ones."""

    needed: int
    learnt: dict[str, list[dict[str, float]]] = field(default_factory=lambda: {d: [] for d in DIRECTIONS})
    # per direction, a row per throw of the latest RECENT_THROWS (_row: its index, its features): an array, not
    # dicts or tuples of floats, since every switch keeps them for as long as it serves
    recent: dict[str, np.ndarray] = field(default_factory=lambda: {d: _no_recent() for d in DIRECTIONS})
    profiles: dict[str, list[np.ndarray]] = field(default_factory=lambda: {d: [] for d in DIRECTIONS})  # learnt
    profile: dict[str, np.ndarray | None] = field(default_factory=lambda: dict.fromkeys(DIRECTIONS))  # the latest

    def learn(self, direction: str, features: dict[str, float | None], profile: np.ndarray | None = None) -> None:
        """A healthy commissioning throw's features (and stroke profile) join its direction's band."""
        if len(self.learnt[direction]) < self.needed:
            self.learnt[direction].append({n: v for n, v in features.items() if v is not None})
            if profile is not None:
                self.profiles[direction].append(profile)

    def excess(self, direction: str) -> np.ndarray | None:
        """The direction's latest stroke profile less its commissioning throws' mean (per share of the stroke), or
        None before both are known."""
        latest, learnt = self.profile[direction], self.profiles[direction]
        if latest is None or len(learnt) < 2:
            return None
        with np.errstate(invalid="ignore"):
            return latest - np.nanmean(np.array(learnt), axis=0)

    def band(self, direction: str, name: str) -> tuple[float, float, float] | None:
        """(mean, low, high) a feature of a direction may wander within, or None before it was learnt."""
        values = np.array([f[name] for f in self.learnt[direction] if name in f])
        if len(values) < 2:
            return None
        mean = float(values.mean())
        half = max(BAND_SIGMAS * float(values.std(ddof=1)), BAND_FLOOR * abs(mean))
        return mean, mean - half, mean + half

    def update(self, index: int, direction: str, features: dict[str, float | None],
               profile: np.ndarray | None = None) -> list[dict]:
        """A throw of the commissioned switch: each feature's value, band, slope over the recent throws (per 100
        throws of the switch) and state, for the features its band knows."""
        self.recent[direction] = np.vstack([self.recent[direction], _row(index, features)])[-RECENT_THROWS:]
        self.profile[direction] = profile
        out = []
        for name in FEATURES:
            band, value = self.band(direction, name), features.get(name)
            if band is None or value is None:
                continue
            mean, low, high = band
            out.append({"name": name, "direction": direction, "value": value, "mean": mean, "low": low, "high": high,
                        "slope_per_100": self._slope(direction, name),
                        "state": "ok" if low <= value <= high else "outside"})
        return out

    def latest(self, direction: str, name: str) -> float | None:
        """A feature's value in the direction's latest throw (None before one, or where that throw had none)."""
        if not len(self.recent[direction]):
            return None
        value = float(self.recent[direction][-1, 1 + FEATURES.index(name)])
        return None if math.isnan(value) else value

    def _slope(self, direction: str, name: str) -> float:
        recent = self.recent[direction]
        x, y = recent[:, 0], recent[:, 1 + FEATURES.index(name)]
        x, y = x[~np.isnan(y)], y[~np.isnan(y)]
        if len(x) < 3:
            return 0.0
        if np.ptp(x) == 0.0:
            return 0.0
        return float(100.0 * np.polyfit(x, y, 1)[0])

    def reset(self) -> None:
        self.learnt = {d: [] for d in DIRECTIONS}
        self.recent = {d: _no_recent() for d in DIRECTIONS}
        self.profiles = {d: [] for d in DIRECTIONS}
        self.profile = dict.fromkeys(DIRECTIONS)

    def to_dict(self) -> dict:
        """Compact: each throw's features as a row in the order of `names`, to six significant digits (far below any
        feature's throw-to-throw scatter), null where the throw had none."""
        def row(values: dict[str, float]) -> list[float | None]:
            return [None if values.get(n) is None else float(f"{values[n]:.6g}") for n in FEATURES]
        def curve(values: np.ndarray | None) -> list[float | None] | None:
            return None if values is None else [None if np.isnan(v) else float(f"{v:.4g}") for v in values]
        return {"names": list(FEATURES), "learnt": {d: [row(f) for f in self.learnt[d]] for d in DIRECTIONS},
                "recent": {d: [[int(r[0]), *row({n: v for n, v in zip(FEATURES, r[1:]) if not math.isnan(v)})]
                               for r in self.recent[d].tolist()] for d in DIRECTIONS},
                "profiles": {d: [curve(p) for p in self.profiles[d]] for d in DIRECTIONS},
                "profile": {d: curve(self.profile[d]) for d in DIRECTIONS}}

    def load(self, data: dict) -> None:
        self.reset()
        names = data.get("names", FEATURES)

        def curve(values: list | None) -> np.ndarray | None:
            return None if values is None else np.array([np.nan if v is None else v for v in values], dtype=float)

        def values(row: list) -> dict[str, float]:
            return {n: float(v) for n, v in zip(names, row) if v is not None and n in FEATURES}
        for direction in DIRECTIONS:
            self.learnt[direction] = [values(r) for r in data.get("learnt", {}).get(direction, [])][:self.needed]
            rows = [_row(int(index), values(row)) for index, *row in data.get("recent", {}).get(direction, [])]
            self.recent[direction] = np.array(rows, dtype=float).reshape(-1, 1 + len(FEATURES))[-RECENT_THROWS:]
            # a state saved before profiles were kept has none: the binding test waits for a new commissioning
            self.profiles[direction] = [curve(p) for p in data.get("profiles", {}).get(direction, [])][:self.needed]
            self.profile[direction] = curve(data.get("profile", {}).get(direction))
