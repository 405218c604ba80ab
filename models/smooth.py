"""Smooth stand-ins for the plant's non-smooth laws, so reduced models have exact derivatives."""
from __future__ import annotations

import casadi as ca


def softplus(z, width: float):
    """width * log(1 + exp(z / width)), overflow-safe: a ramp max(z, 0) rounded over `width`."""
    return ca.fmax(z, 0.0) + width * ca.log1p(ca.exp(-ca.fabs(z) / width))


def smooth_clip(value, limit: float, width: float):
    """Clip to +-limit with corners rounded over `width`."""
    return value - softplus(value - limit, width) + softplus(-value - limit, width)
