"""Cut a switch's message stream into throws: samples between a start and an end event."""
from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from railswitch.models.plant.reference import Reference
from railswitch.models.plant.signals import SIGNAL_NAMES, MotorSignals, ThrowInput
from railswitch.schemas import FaultTruth, Message, MotorSample, ThrowEvent


@dataclass(frozen=True, kw_only=True)
class CutThrow(ThrowInput):
    """One throw as the cutter cut it: what the diagnosis takes (ThrowInput: samples relative to the start event,
    the reference, how long it took), with the switch, the events it was cut between and the simulator's truth."""

    switch_id: str
    start: ThrowEvent
    end: ThrowEvent | None  # None: the stream ended before the throw did
    truth: FaultTruth | None = None

    @classmethod
    def of(cls, start: ThrowEvent, end: ThrowEvent | None, t_s: np.ndarray, signals: MotorSignals,
           missing_samples: int = 0, truth: FaultTruth | None = None) -> CutThrow:
        """The throw between `start` and `end` (None: unfinished), its index, direction and reference from `start`."""
        reference = Reference(np.asarray(start.reference_t_s, dtype=float),
                              np.asarray(start.reference_velocity_rad_s, dtype=float))
        return cls(index=start.throw_index, direction=start.direction, reference=reference, t_s=t_s, signals=signals,
                   duration_s=None if end is None else (end.t_ns - start.t_ns) * 1e-9, missing_samples=missing_samples,
                   switch_id=start.switch_id, start=start, end=end, truth=truth)

    @property
    def complete(self) -> bool:
        return self.end is not None


@dataclass
class _OpenThrow:
    start: ThrowEvent
    samples: list[MotorSample] = field(default_factory=list)
    truth: FaultTruth | None = None


class ThrowCutter:
    """Feeds on messages of any number of switches and emits each throw once its end event arrives.

    The sample at the start event's time belongs to the throw (it is the last
    sample before the motor is powered), as does the one at the end event's time.
    A throw whose end never comes is emitted incomplete (and so diagnosed unknown)
    when the next throw starts or when it has run for OPEN_LIMIT_S, so a lost end
    event costs one throw and bounded memory. Events that make no sense in the
    stream are passed to `on_problem(switch_id, reason)` and otherwise ignored.
    """

    OPEN_LIMIT_S = 60.0  # several times any throw's length

    def __init__(self, on_problem: Callable[[str, str], None] | None = None) -> None:
        self._open: dict[str, _OpenThrow] = {}
        self._last_sample: dict[str, MotorSample] = {}
        self._truth: dict[str, FaultTruth] = {}
        self._on_problem = on_problem or (lambda switch_id, reason: None)

    def feed(self, message: Message) -> CutThrow | None:
        """Take one message; return the throw it completes (or abandons), if any."""
        if isinstance(message, FaultTruth):
            self._truth[message.switch_id] = message
        elif isinstance(message, MotorSample):
            self._last_sample[message.switch_id] = message
            current = self._open.get(message.switch_id)
            if current is not None and message.t_ns >= current.start.t_ns:
                if (message.t_ns - current.start.t_ns) * 1e-9 > self.OPEN_LIMIT_S:
                    self._on_problem(message.switch_id, f"throw: no end event within {self.OPEN_LIMIT_S:g} s")
                    del self._open[message.switch_id]
                    return _cut(current, None)
                current.samples.append(message)
        elif isinstance(message, ThrowEvent):
            return self._event(message)
        return None

    def _event(self, event: ThrowEvent) -> CutThrow | None:
        current = self._open.get(event.switch_id)
        if event.phase == "start":
            if current is not None and event.t_ns < current.start.t_ns:
                self._on_problem(event.switch_id, "throw: start before the open throw's start")
                return None
            opened = _OpenThrow(event, truth=self._truth.get(event.switch_id))
            last = self._last_sample.get(event.switch_id)
            if last is not None and last.t_ns == event.t_ns:
                opened.samples.append(last)
            self._open[event.switch_id] = opened
            if current is not None:
                self._on_problem(event.switch_id, "throw: started while the previous one had no end")
                return _cut(current, None)
            return None
        if current is None or current.start.throw_index != event.throw_index or event.t_ns < current.start.t_ns:
            self._on_problem(event.switch_id, "throw: end without its start")
            return None
        del self._open[event.switch_id]
        return _cut(current, event)

    def flush(self) -> Iterator[CutThrow]:
        """Throws that started but never ended (the stream stopped)."""
        for current in self._open.values():
            yield _cut(current, None)
        self._open.clear()


def _cut(current: _OpenThrow, end: ThrowEvent | None) -> CutThrow:
    samples = [s for s in current.samples if end is None or s.t_ns <= end.t_ns]
    seqs = np.array([s.seq for s in samples], dtype=np.int64)
    missing = int(np.sum(np.diff(seqs) - 1)) if len(seqs) > 1 else 0
    t0 = current.start.t_ns
    return CutThrow.of(current.start, end, np.array([(s.t_ns - t0) * 1e-9 for s in samples]), _signals(samples),
                       missing, current.truth)


def _signals(samples: list[MotorSample]) -> MotorSignals:
    """The throw's signals: the current, and angle and velocity where every sample carries them (a unit that
    logs them only now and then is taken as current-only rather than as one with gaps)."""
    logged = [name for name in SIGNAL_NAMES if all(getattr(s, name) is not None for s in samples)]
    return MotorSignals(**{name: np.array([getattr(s, name) for s in samples], dtype=float) for name in logged})


def cut_throws(messages: Iterable[Message]) -> Iterator[CutThrow]:
    """All throws of an ordered message stream, incomplete ones last."""
    cutter = ThrowCutter()
    for message in messages:
        throw = cutter.feed(message)
        if throw is not None:
            yield throw
    yield from cutter.flush()
