"""Smooth stand-ins for the plant's non-smooth laws, so reduced models have exact derivatives.

Algebraic (square-root) forms rather than exp/log/tanh: just as smooth, and a
fraction of the cost in the inner loop of every reduced-model step.
"""
from __future__ import annotations

import casadi as ca


def softplus(z, width: float):
    """Ramp max(z, 0) rounded over `width`: (z + sqrt(z^2 + width^2)) / 2."""
    return 0.5 * (z + ca.sqrt(z * z + width * width))


def smooth_step(z, width: float):
    """Switch from 0 (z << -width) to 1 (z >> width): (1 + z / sqrt(z^2 + width^2)) / 2."""
    return 0.5 * (1.0 + z / ca.sqrt(z * z + width * width))


def smooth_clip(value, limit: float, width: float):
    """Clip to +-limit with corners rounded over `width`."""
    return value - softplus(value - limit, width) + softplus(-value - limit, width)
