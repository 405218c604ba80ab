"""What a replay publishes: a recording's records in time order, each loop shifted in time, sample
numbers and throw numbers past the previous pass, so subscribers see one continuous switch."""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from railswitch.schemas import Message, MotorSample
from railswitch.services.ports import RecordedMessage

PLANT_KINDS = ("motor", "throw", "truth", "record")  # what the plant's side (or its trackside unit) sends


@dataclass(frozen=True)
class ReplayPlan:
    """The records to publish in time order, and how far each loop shifts them."""

    records: list[RecordedMessage]
    span_ns: int
    seq_step: int
    throw_step: int

    @classmethod
    def of(cls, records: list[RecordedMessage], kinds: tuple[str, ...]) -> ReplayPlan:
        chosen = sorted((r for r in records if r.kind in kinds), key=lambda r: r.log_time_ns)  # stable: file order ties
        if not chosen:
            return cls([], 0, 0, 0)
        motor_times = np.array([r.log_time_ns for r in chosen if isinstance(r.message, MotorSample)], dtype=np.int64)
        period_ns = int(np.median(np.diff(motor_times))) if len(motor_times) > 1 else 1_000_000_000
        span_ns = chosen[-1].log_time_ns - chosen[0].log_time_ns + max(period_ns, 1)
        seq_step = 1 + max((getattr(r.message, "seq", 0) for r in chosen), default=0)
        throw_step = 1 + max((getattr(r.message, "throw_index", 0) for r in chosen), default=0)
        return cls(chosen, span_ns, seq_step, throw_step)

    def passes(self, loops: int) -> Iterator[tuple[int, str, Message]]:
        """(log time, key, message) of every pass; loops=0 repeats forever."""
        n = 0
        while loops == 0 or n < loops:
            for record in self.records:
                yield record.log_time_ns + n * self.span_ns, record.key, self._shift(record.message, n)
            n += 1

    def _shift(self, message: Message, n: int) -> Message:
        if n == 0:
            return message
        steps = {"t_ns": self.span_ns, "t_start_ns": self.span_ns, "t_end_ns": self.span_ns,
                 "seq": self.seq_step, "throw_index": self.throw_step}
        fields = type(message).model_fields
        return message.model_copy(update={name: getattr(message, name) + n * step
                                          for name, step in steps.items() if name in fields})
