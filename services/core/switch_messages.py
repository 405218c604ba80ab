"""Turn a simulated switch's samples and throws into bus messages (schemas/)."""
from __future__ import annotations

from collections.abc import Iterator

from railswitch.models.switch import Samples, SwitchSimulation, Throw
from railswitch.schemas import FaultTruth, Message, MotorSample, ThrowEvent, key_expr


def motor_messages(switch_id: str, sim: SwitchSimulation, samples: Samples) -> Iterator[tuple[str, Message]]:
    """One MotorSample per sample; `seq` is the sample index, so gaps show as missing numbers."""
    key = key_expr(switch_id, "motor")
    signals = samples.signals
    for k in range(len(samples)):
        seq = samples.first_index + k
        yield key, MotorSample(switch_id=switch_id, seq=seq, t_ns=sim.time_ns(seq),
                               current_a=float(signals.current_a[k]), angle_rad=float(signals.angle_rad[k]),
                               velocity_rad_s=float(signals.velocity_rad_s[k]))


def throw_event(switch_id: str, sim: SwitchSimulation, throw: Throw, phase: str) -> tuple[str, ThrowEvent]:
    """The start or end event of a throw, both carrying its reference profile."""
    index = throw.start_index if phase == "start" else throw.end_index
    return key_expr(switch_id, "throw"), ThrowEvent(
        switch_id=switch_id, throw_index=throw.index, direction=throw.direction, phase=phase,
        t_ns=sim.time_ns(index), reference_t_s=throw.reference.t_s.tolist(),
        reference_velocity_rad_s=throw.reference.velocity_rad_s.tolist())


def truth_message(switch_id: str, sim: SwitchSimulation, t_ns: int) -> tuple[str, FaultTruth]:
    """The faults currently injected in the simulated plant."""
    return key_expr(switch_id, "truth"), FaultTruth(switch_id=switch_id, t_ns=t_ns, **sim.faults)


def throw_messages(switch_id: str, sim: SwitchSimulation, throw: Throw) -> Iterator[tuple[str, Message]]:
    """Truth and start event at the throw's start, its samples, then the end event, in time order."""
    t_start = sim.time_ns(throw.start_index)
    yield truth_message(switch_id, sim, t_start)
    yield throw_event(switch_id, sim, throw, "start")
    yield from motor_messages(switch_id, sim, throw.samples)
    yield throw_event(switch_id, sim, throw, "end")


def switch_messages(switch_id: str, sim: SwitchSimulation, throws: int, progress=None) -> Iterator[tuple[str, Message]]:
    """A simulated switch from the start: truth and the sample at rest, then `throws` throws."""
    yield truth_message(switch_id, sim, 0)
    yield from motor_messages(switch_id, sim, sim.initial_sample())
    for _ in range(throws):
        yield from throw_messages(switch_id, sim, sim.throw())
        if progress is not None:
            progress()
