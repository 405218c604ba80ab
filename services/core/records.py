"""A whole throw as one message (ThrowRecord on railswitch/<id>/record), as a trackside unit uploads it, and the
same throw as the diagnoser's CutThrow: a record and the sample stream of the same throw are diagnosed alike.

The sample at offset 0 is the last one at rest, as the sample at a start event's time is in the stream
(services/core/throw_cutter.py); the record's end is the throw's end event.
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from railswitch.models.plant.reference import Reference
from railswitch.models.plant.signals import SIGNAL_NAMES, MotorSignals
from railswitch.models.plant.simulation import SwitchSimulation, Throw
from railswitch.schemas import FaultTruth, Message, ThrowEvent, ThrowRecord, key_expr
from railswitch.services.core.switch_messages import truth_message
from railswitch.services.core.throw_cutter import CutThrow, ThrowCutter


def throw_of_record(record: ThrowRecord, truth: FaultTruth | None = None) -> CutThrow:
    """The record as the throw cutter would have cut it from the stream: start and end events, times from the
    start in seconds, the signals it carries (angle and velocity None where the unit logs the current alone)."""
    start = ThrowEvent(switch_id=record.switch_id, throw_index=record.throw_index, direction=record.direction,
                       phase="start", t_ns=record.t_start_ns, reference_t_s=record.reference_t_s,
                       reference_velocity_rad_s=record.reference_velocity_rad_s)
    end = start.model_copy(update={"phase": "end", "t_ns": record.t_end_ns})
    signals = MotorSignals(**{name: np.asarray(values, dtype=float) for name in SIGNAL_NAMES
                              if (values := getattr(record, name)) is not None})
    t_s = np.asarray(record.t_offset_ns, dtype=np.int64) * 1e-9  # as the cutter's (t_ns - t_start_ns) * 1e-9
    return CutThrow.of(start, end, t_s, signals, truth=truth)


def every_throw(messages: Iterable[Message]) -> Iterator[CutThrow]:
    """Every throw of an ordered message stream, whether streamed as samples or sent as records (with the switch's
    latest truth), in the order the throws end; unfinished streamed ones last."""
    cutter = ThrowCutter()
    truth: dict[str, FaultTruth] = {}
    for message in messages:
        if isinstance(message, ThrowRecord):
            yield throw_of_record(message, truth.get(message.switch_id))
            continue
        if isinstance(message, FaultTruth):
            truth[message.switch_id] = message
        throw = cutter.feed(message)
        if throw is not None:
            yield throw
    yield from cutter.flush()


def record_of_throw(throw: CutThrow) -> ThrowRecord:
    """A complete cut throw as one record (what a unit that cuts its own throws would upload)."""
    if throw.end is None:
        raise ValueError(f"{throw.switch_id} throw {throw.start.throw_index} has no end: a record is a whole throw")
    start = throw.start
    reference = Reference(np.asarray(start.reference_t_s), np.asarray(start.reference_velocity_rad_s))
    offsets = np.rint(throw.t_s * 1e9).astype(np.int64)  # exact: the cutter's times are whole nanoseconds
    return _record(throw.switch_id, start.throw_index, start.direction, reference, start.t_ns, throw.end.t_ns,
                   offsets, throw.signals)


def simulated_record(switch_id: str, sim: SwitchSimulation, throw: Throw, rest: MotorSignals) -> ThrowRecord:
    """A simulated throw as one record; `rest` is the sample at its start (the last of the idle period before)."""
    t_start_ns = sim.time_ns(throw.start_index)
    offsets = np.array([sim.time_ns(k) - t_start_ns for k in range(throw.start_index, throw.end_index + 1)])
    return _record(switch_id, throw.index, throw.direction, throw.reference, t_start_ns, t_start_ns + int(offsets[-1]),
                   offsets, MotorSignals.concatenate([rest, throw.samples.signals]))


def record_messages(switch_id: str, sim: SwitchSimulation, throw: Throw,
                    rest: MotorSignals) -> Iterator[tuple[str, Message]]:
    """What a simulator publishing records sends for a throw: the truth at its start, the record at its end."""
    yield truth_message(switch_id, sim, sim.time_ns(throw.start_index))
    yield key_expr(switch_id, "record"), simulated_record(switch_id, sim, throw, rest)


def _record(switch_id: str, index: int, direction: str, reference: Reference, t_start_ns: int, t_end_ns: int,
            offsets: np.ndarray, signals: MotorSignals) -> ThrowRecord:
    return ThrowRecord(switch_id=switch_id, throw_index=index, direction=direction, t_start_ns=t_start_ns,
                       t_end_ns=t_end_ns, reference_t_s=reference.t_s.tolist(),
                       reference_velocity_rad_s=reference.velocity_rad_s.tolist(), t_offset_ns=offsets.tolist(),
                       **{name: getattr(signals, name).tolist() for name in signals.names})

