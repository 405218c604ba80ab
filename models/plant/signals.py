"""The measured signals of a point machine, and one throw of them: the value types from the plant or the bus to the
estimator.

The motor current is always measured. Many installed monitoring units log nothing else, so angle
and angular velocity may be absent (None): the estimator then fits the current alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from railswitch.models.plant.reference import Reference

SIGNAL_NAMES = ("current_a", "angle_rad", "velocity_rad_s")


@dataclass(frozen=True)
class MotorSignals:
    """Motor current and, where logged, angle and angular velocity at consecutive samples (arrays of one length)."""

    current_a: np.ndarray
    angle_rad: np.ndarray | None = None
    velocity_rad_s: np.ndarray | None = None

    def __post_init__(self) -> None:
        lengths = {len(getattr(self, name)) for name in self.names}
        if len(lengths) != 1:
            raise ValueError(f"signals of different lengths: {sorted(lengths)}")

    @property
    def names(self) -> tuple[str, ...]:
        """The signals present, in SIGNAL_NAMES order (the current always first)."""
        return tuple(name for name in SIGNAL_NAMES if getattr(self, name) is not None)

    def __len__(self) -> int:
        return len(self.current_a)

    def __getitem__(self, index) -> MotorSignals:
        """The samples at `index` (a slice or a boolean or integer array), as signals."""
        return MotorSignals(**{name: np.atleast_1d(getattr(self, name)[index]) for name in self.names})

    def matrix(self) -> np.ndarray:
        """N x (signals present), one column per signal in `names` order."""
        return np.column_stack([getattr(self, name) for name in self.names])

    def all_finite(self) -> bool:
        return all(bool(np.all(np.isfinite(getattr(self, name)))) for name in self.names)

    def only(self, names: tuple[str, ...]) -> MotorSignals:
        """These signals alone (the current is always kept): what a unit logging fewer would have sent."""
        return MotorSignals(**{name: getattr(self, name) for name in self.names if name in names or name == "current_a"})

    @classmethod
    def concatenate(cls, parts: list[MotorSignals]) -> MotorSignals:
        names = {p.names for p in parts}
        if len(names) != 1:
            raise ValueError(f"cannot join signals logged differently: {sorted(names)}")
        return cls(**{name: np.concatenate([getattr(p, name) for p in parts]) for name in names.pop()})


@dataclass(frozen=True)
class ThrowInput:
    """One throw as the diagnosis takes it: samples relative to the start event, the reference the drive followed,
    and how long the throw took. The throw cutter's throws are these (services/core/throw_cutter.py CutThrow adds the
    switch, the events and the simulator's truth); the estimator fits the samples after the start
    (models/diagnosis/switch_diagnoser.py measurement)."""

    index: int
    direction: str
    reference: Reference
    t_s: np.ndarray  # first sample at the start event (t = 0)
    signals: MotorSignals
    duration_s: float | None  # start to end event; None when no end event came
    missing_samples: int = 0  # sequence numbers skipped inside the throw
