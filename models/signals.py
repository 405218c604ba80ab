"""The measured signals of a point machine: one value type from the plant or the bus to the estimator."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SIGNAL_NAMES = ("current_a", "angle_rad", "velocity_rad_s")


@dataclass(frozen=True)
class MotorSignals:
    """Motor current, angle and angular velocity at consecutive samples (arrays of one length)."""

    current_a: np.ndarray
    angle_rad: np.ndarray
    velocity_rad_s: np.ndarray

    def __post_init__(self) -> None:
        lengths = {len(getattr(self, name)) for name in SIGNAL_NAMES}
        if len(lengths) != 1:
            raise ValueError(f"signals of different lengths: {sorted(lengths)}")

    def __len__(self) -> int:
        return len(self.current_a)

    def __getitem__(self, index) -> MotorSignals:
        """The samples at `index` (a slice or a boolean or integer array), as signals."""
        return MotorSignals(*(np.atleast_1d(getattr(self, name)[index]) for name in SIGNAL_NAMES))

    def matrix(self) -> np.ndarray:
        """N x 3, one column per signal in SIGNAL_NAMES order."""
        return np.column_stack([getattr(self, name) for name in SIGNAL_NAMES])

    def all_finite(self) -> bool:
        return all(bool(np.all(np.isfinite(getattr(self, name)))) for name in SIGNAL_NAMES)

    @classmethod
    def concatenate(cls, parts: list[MotorSignals]) -> MotorSignals:
        return cls(*(np.concatenate([getattr(p, name) for p in parts]) for name in SIGNAL_NAMES))
