"""A switch's life as series over its throws: each fault parameter's level and spread after every throw, its
limit and where the latest trend says it will reach it, from the switch's SwitchHealth messages.

What `railswitch report` draws, one figure per switch; the drawing itself stays in the command.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from railswitch.schemas import FAULT_PARAMETERS, SwitchHealth


@dataclass(frozen=True)
class Crossing:
    """The throw at which a parameter is predicted to reach its limit: median and 5 %-95 % interval."""

    throw: float
    low: float | None
    high: float | None


@dataclass(frozen=True)
class ParameterSeries:
    """One parameter over the throws that reported it: throws (whole numbers), level and its standard deviation
    (nan where the health message gave none), the latest limit and crossing."""

    name: str
    throws: np.ndarray
    level: np.ndarray
    level_std: np.ndarray
    limit: float
    crossing: Crossing | None


@dataclass(frozen=True)
class SwitchSeries:
    """A switch's parameters over its throws, and its state after the latest one."""

    switch_id: str
    state: str
    last_throw: int
    parameters: dict[str, ParameterSeries]


def health_series(messages: Iterable[SwitchHealth]) -> dict[str, SwitchSeries]:
    """Per switch, in throw order; a throw reported twice (a replay, a restarted diagnoser) counts once, the
    later message winning."""
    by_switch: dict[str, dict[int, SwitchHealth]] = {}
    for message in sorted(messages, key=lambda m: m.t_ns):
        by_switch.setdefault(message.switch_id, {})[message.throw_index] = message
    return {switch_id: _switch_series(switch_id, [throws[k] for k in sorted(throws)])
            for switch_id, throws in sorted(by_switch.items())}


def _switch_series(switch_id: str, healths: list[SwitchHealth]) -> SwitchSeries:
    reported = {p.name for h in healths for p in h.parameters}  # a bolt only once a throw it drives was seen
    names = [name for name in FAULT_PARAMETERS if name in reported]  # the contract's order, figure after figure
    return SwitchSeries(switch_id, healths[-1].state, healths[-1].throw_index,
                        {name: _parameter_series(name, healths) for name in names})


def _parameter_series(name: str, healths: list[SwitchHealth]) -> ParameterSeries:
    points = [(h.throw_index, p) for h in healths for p in h.parameters if p.name == name]
    throw, latest = points[-1]
    crossing = None
    if latest.throws_to_limit is not None:
        low, high = latest.throws_to_limit_low, latest.throws_to_limit_high
        crossing = Crossing(throw + latest.throws_to_limit, None if low is None else throw + low,
                            None if high is None else throw + high)
    return ParameterSeries(
        name, np.array([k for k, _ in points], dtype=int), np.array([p.level for _, p in points]),
        np.array([np.nan if p.level_std is None else p.level_std for _, p in points]), latest.limit, crossing)
