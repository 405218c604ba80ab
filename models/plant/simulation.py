"""One simulated switch over time: throws, idle periods, measurement noise.

Pure: it produces arrays of samples; the services turn them into messages.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from railswitch.models.plant.high_fidelity import Plant
from railswitch.models.plant.reference import DIRECTIONS, STROKE_S, THROW_DURATION_S, Reference, throw_reference
from railswitch.models.plant.signals import SIGNAL_NAMES, MotorSignals

SETTLE_S = 1.0  # unpowered settling before the first sample, from the closed left position


@dataclass(frozen=True)
class Samples:
    """Measured motor signals at consecutive sample indices (index * 1/rate seconds from start)."""

    first_index: int
    signals: MotorSignals
    rail_position_m: np.ndarray  # not measured by the point machine; kept for tests and plots

    def __len__(self) -> int:
        return len(self.signals)


@dataclass(frozen=True)
class Throw:
    """One throw: its direction, reference profile, sample index span and samples."""

    index: int
    direction: str
    reference: Reference
    start_index: int  # sample index at the throw's start (already emitted before the throw)
    samples: Samples

    @property
    def end_index(self) -> int:
        return self.samples.first_index + len(self.samples) - 1


def sample_time_ns(start_ns: int, sample_index: int, rate_hz: float) -> int:
    """Integer nanoseconds of a sample index: start_ns plus its time from the simulation's start."""
    return start_ns + round(sample_index * 1_000_000_000 / rate_hz)


@lru_cache(maxsize=4)
def nominal_peaks(plant: Plant, rate_hz: float = 50.0) -> dict[str, float]:
    """Peak magnitude of each measured signal over a nominal left-right-left pair of throws."""
    switch = SwitchSimulation(plant, rate_hz=rate_hz)
    throws = [switch.throw() for _ in range(2)]
    return {name: float(max(np.abs(getattr(t.samples.signals, name)).max() for t in throws)) for name in SIGNAL_NAMES}


class SwitchSimulation:
    """Advances one plant through throws (alternating, starting left to right from 1.00 m)."""

    def __init__(self, plant: Plant, *, rate_hz: float = 50.0, faults: dict[str, float] | None = None,
                 noise_rel: float = 0.0, seed: int = 0, start_ns: int = 0, own: dict[str, float] | None = None,
                 stroke_s: float = STROKE_S, end_s: float | None = None):
        """`own`: this switch's build and weather (plant variables, schemas/plant.py) where not nominal.
        `stroke_s`: its machine type's stroke time (the reference profile holds still for another
        THROW_DURATION_S - STROKE_S after it); `end_s`: when each throw's end event comes (default: when the
        reference profile ends; earlier or later, as a machine detecting its end position would have it)."""
        self.plant = plant
        self.stroke_s = float(stroke_s)
        self.end_s = float(end_s) if end_s is not None else self.reference_end_s
        throw_reference(DIRECTIONS[0], plant.params.drive, self.stroke_s, self.reference_end_s)  # checks stroke_s
        self.start_ns = int(start_ns)
        self.rate_hz = float(rate_hz)
        self.faults = dict(faults or {})
        self.own = dict(own or {})
        plant.variables(self.own)  # unknown names fail here, not at the first throw
        self.noise_rel = float(noise_rel)
        self._rng = np.random.default_rng(seed)
        self._noise_std = {name: noise_rel * peak for name, peak in nominal_peaks(plant, rate_hz).items()} if noise_rel > 0 else {}
        settled = plant.run(plant.rest_state(1.0, plant=self.own), SETTLE_S, self.rate_hz, self.faults, plant=self.own)
        self.state = settled.states[:, -1]
        self.sample_index = 0
        self.throw_count = 0

    def set_faults(self, faults: dict[str, float]) -> None:
        """Replace the injected faults; they act from the next sample on."""
        self.faults = dict(faults)

    def set_own(self, own: dict[str, float]) -> None:
        """Replace the switch's own parameters where not nominal (weather, wear); from the next sample on."""
        self.plant.variables(own)
        self.own = dict(own)

    def _samples(self, trajectory, first_index: int) -> Samples:
        measured = {}
        for name in SIGNAL_NAMES:
            values = trajectory[name]
            if name in self._noise_std:
                values = values + self._rng.normal(0.0, self._noise_std[name], size=values.shape)
            measured[name] = values
        return Samples(first_index, MotorSignals(**measured), trajectory["rail_position_m"])

    def initial_sample(self) -> Samples:
        """The sample at index 0, before anything moves."""
        signals = self.plant.signals_at(self.state, self.faults, self.own)
        trajectory = {name: np.array([signals[name]]) for name in (*SIGNAL_NAMES, "rail_position_m")}
        return self._samples(trajectory, 0)

    def next_direction(self) -> str:
        return DIRECTIONS[self.throw_count % 2]

    @property
    def reference_end_s(self) -> float:
        return self.stroke_s + THROW_DURATION_S - STROKE_S

    def throw(self, direction: str | None = None, reference: Reference | None = None) -> Throw:
        """Power the motor for one throw (until end_s) and return its samples."""
        direction = direction or self.next_direction()
        reference = reference or throw_reference(direction, self.plant.params.drive, self.stroke_s, self.reference_end_s)
        trajectory = self.plant.run(self.plant.start_throw(self.state), self.end_s, self.rate_hz,
                                    self.faults, reference, self.own)
        start = self.sample_index
        throw = Throw(self.throw_count, direction, reference, start, self._samples(trajectory, start + 1))
        self.state = trajectory.states[:, -1]
        self.sample_index = throw.end_index
        self.throw_count += 1
        return throw

    def idle(self, duration_s: float) -> Samples:
        """Motor unpowered for `duration_s`; the rails stay where the last throw left them."""
        trajectory = self.plant.run(self.state, duration_s, self.rate_hz, self.faults, plant=self.own)
        samples = self._samples(trajectory, self.sample_index + 1)
        self.state = trajectory.states[:, -1]
        self.sample_index += len(samples)
        return samples

    def time_ns(self, sample_index: int) -> int:
        return sample_time_ns(self.start_ns, sample_index, self.rate_hz)


@dataclass(frozen=True)
class RecordedThrow:
    """The measured samples of one recorded throw, after its start sample, and its reference."""

    direction: str
    reference: Reference
    signals: MotorSignals


class ReplayedSwitch:
    """Stands in for SwitchSimulation with recorded throws instead of the plant, so a fleet of
    hundreds of switches costs only its messages; idle periods hold the last sample."""

    def __init__(self, throws: list[RecordedThrow], *, rate_hz: float = 50.0, start_ns: int = 0, first: int = 0):
        by_direction = {d: [t for t in throws if t.direction == d] for d in DIRECTIONS}
        missing = [d for d, recorded in by_direction.items() if not recorded]
        if missing:
            raise ValueError(f"no recorded throw {' or '.join(missing)}")
        self._throws = by_direction
        self.rate_hz = float(rate_hz)
        self.start_ns = int(start_ns)
        self.faults: dict[str, float] = {}
        self.own: dict[str, float] = {}
        self.sample_index = 0
        self.throw_count = 0
        self._first = first
        self._last = by_direction[DIRECTIONS[1]][0]  # the switch rests where a right-to-left throw ends

    def set_faults(self, faults: dict[str, float]) -> None:
        """Recorded throws cannot change; the faults are only reported."""
        self.faults = dict(faults)

    def set_own(self, own: dict[str, float]) -> None:
        """Recorded throws cannot change; the switch's parameters are only reported."""
        self.own = dict(own)

    def _hold(self, first_index: int, count: int) -> Samples:
        last = self._last.signals[-1:]
        values = MotorSignals(**{name: np.repeat(getattr(last, name), count) for name in last.names})
        return Samples(first_index, values, np.full(count, np.nan))

    def initial_sample(self) -> Samples:
        return self._hold(0, 1)

    @property
    def end_s(self) -> float:
        """The longest recorded throw's length: what an interval between throw starts must leave room for."""
        return max(len(t.signals) for recorded in self._throws.values() for t in recorded) / self.rate_hz

    def next_direction(self) -> str:
        return DIRECTIONS[self.throw_count % 2]

    def throw(self) -> Throw:
        direction = self.next_direction()
        recorded = self._throws[direction]
        chosen = recorded[(self._first + self.throw_count // 2) % len(recorded)]
        start = self.sample_index
        samples = Samples(start + 1, chosen.signals, np.full(len(chosen.signals), np.nan))
        throw = Throw(self.throw_count, direction, chosen.reference, start, samples)
        self._last = chosen
        self.sample_index = throw.end_index
        self.throw_count += 1
        return throw

    def idle(self, duration_s: float) -> Samples:
        samples = self._hold(self.sample_index + 1, max(1, round(duration_s * self.rate_hz)))
        self.sample_index += len(samples)
        return samples

    def time_ns(self, sample_index: int) -> int:
        return sample_time_ns(self.start_ns, sample_index, self.rate_hz)
