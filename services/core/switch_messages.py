"""Turn a simulated switch's samples and throws into bus messages (schemas/)."""
from __future__ import annotations

from collections.abc import Iterator

from railswitch.models.plant.simulation import Samples, SwitchSimulation, Throw
from railswitch.schemas import PLANT_PARAMETERS, FaultTruth, Message, MotorSample, ThrowEvent, key_expr


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
    """The faults currently injected in the simulated plant, and its own parameters where not nominal."""
    nominal = PLANT_PARAMETERS
    own = {name: value for name, value in sim.own.items() if value != nominal[name].nominal}
    return key_expr(switch_id, "truth"), FaultTruth(switch_id=switch_id, t_ns=t_ns, plant=own, **sim.faults)


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


class SimulatedThrows:
    """A simulated switch throw by throw, each cut as the diagnoser would cut it off the bus: change its
    faults or its own parameters between throws (sim.set_faults, sim.set_own)."""

    def __init__(self, switch_id: str, sim: SwitchSimulation):
        from railswitch.services.core.throw_cutter import ThrowCutter

        self.switch_id, self.sim = switch_id, sim
        self.cutter = ThrowCutter()
        self.cutter.feed(truth_message(switch_id, sim, 0)[1])
        for _, message in motor_messages(switch_id, sim, sim.initial_sample()):
            self.cutter.feed(message)

    def next(self):
        """The next throw, cut (a CutThrow)."""
        for _, message in throw_messages(self.switch_id, self.sim, self.sim.throw()):
            throw = self.cutter.feed(message)
            if throw is not None:
                return throw
        raise RuntimeError("a simulated throw ended without its end event")
