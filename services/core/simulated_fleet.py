"""Simulated switches on the bus: each computes a whole throw (or idle period) ahead, with the plant or
from recorded throws, and hands out its messages as their time comes; fault schedules and commands
act from the next throw on."""
from __future__ import annotations

import logging
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from railswitch.models.plant.reference import Reference
from railswitch.models.plant.signals import MotorSignals
from railswitch.models.plant.simulation import RecordedThrow, ReplayedSwitch, Samples, SwitchSimulation
from railswitch.schemas import FaultCommand, Message, ThrowRecord
from railswitch.models.plant.high_fidelity import Plant
from railswitch.models.plant.population import draw_switch
from railswitch.schemas.scenario import Scenario, SwitchPlan, is_plant_name
from railswitch.services.core.records import record_messages
from railswitch.services.core.switch_messages import motor_messages, throw_messages, truth_message
from railswitch.services.core.throw_cutter import cut_throws

log = logging.getLogger("railswitch.simulator")


@dataclass
class SwitchStream:
    """One simulated switch: its plant simulation, fault schedule and the messages computed ahead."""

    plan: SwitchPlan
    sim: SwitchSimulation | ReplayedSwitch
    idle_s: float
    settings: dict[str, float]  # faults and the switch's own parameters in force (scenario names)
    pending: deque[tuple[int, str, Message]] = field(default_factory=deque)
    throws_done: int = 0
    idle_next: bool = False
    finished: bool = False
    as_records: bool = False  # each throw as one ThrowRecord at its end instead of samples and events
    rest: MotorSignals | None = None  # the latest sample between throws

    @classmethod
    def start(cls, plan: SwitchPlan, sim: SwitchSimulation | ReplayedSwitch, *, interval_s: float, offset_s: float,
              as_records: bool = False) -> SwitchStream:
        stream = cls(plan, sim, interval_s - sim.end_s, {**plan.faults, **sim.own}, as_records=as_records)
        stream._push([truth_message(plan.id, sim, sim.time_ns(0))])
        stream._at_rest(sim.initial_sample())
        if offset_s > 0:
            stream._at_rest(sim.idle(offset_s))
        return stream

    def _push(self, messages: Iterable[tuple[str, Message]]) -> None:
        for key, message in messages:
            self.pending.append((message.t_end_ns if isinstance(message, ThrowRecord) else message.t_ns, key, message))

    def _at_rest(self, samples: Samples) -> None:
        """Samples between throws: streamed, or (records) only the last kept, as the next record's first."""
        self.rest = samples.signals[[-1]]  # a copy: a view would keep the whole idle period in memory
        if not self.as_records:
            self._push(motor_messages(self.plan.id, self.sim, samples))

    @property
    def done(self) -> bool:
        return self.finished and not self.pending

    def next_ns(self) -> int | None:
        """When this switch's next message is due (computing ahead when needed); None once it is done."""
        while not self.finished and not self.pending:
            self._extend()
        return self.pending[0][0] if self.pending else None

    def due(self, t_ns: int) -> list[tuple[str, Message]]:
        """Messages with a time up to t_ns, computing the next throw or idle period when needed."""
        while not self.finished and (not self.pending or self.pending[-1][0] < t_ns):
            self._extend()
        out = []
        while self.pending and self.pending[0][0] <= t_ns:
            _, key, message = self.pending.popleft()
            out.append((key, message))
        return out

    def _extend(self) -> None:
        if self.idle_next:
            self.idle_next = False
            self._at_rest(self.sim.idle(self.idle_s))
        elif self.throws_done < self.plan.throws:
            try:
                self.settings = self.plan.settings_before(self.throws_done, self.settings, self.sim.own)
            except ValueError as error:
                log.warning("%s; keeping the settings in force", error)
            faults, own = split_settings(self.settings)
            self.sim.set_faults(faults)
            self.sim.set_own(own)
            throw = self.sim.throw()
            log.info("%s throw %d %s, faults %s", self.plan.id, throw.index, throw.direction, faults or "none")
            self._push(record_messages(self.plan.id, self.sim, throw, self.rest) if self.as_records
                       else throw_messages(self.plan.id, self.sim, throw))
            self.throws_done += 1
            self.idle_next = self.throws_done < self.plan.throws
        else:
            self.finished = True

    def command(self, command: FaultCommand) -> None:
        """Apply a FaultCommand from the next throw on."""
        faults, own = split_settings(self.settings)
        faults = {} if command.reset else faults
        faults.update(command.params)
        self.settings = {**faults, **own}
        log.info("%s: faults set to %s from throw %d on", self.plan.id, faults or "none", self.throws_done)


def split_settings(settings: dict[str, float]) -> tuple[dict[str, float], dict[str, float]]:
    """Scenario settings as (faults, the switch's own parameters)."""
    return ({n: v for n, v in settings.items() if not is_plant_name(n)},
            {n: v for n, v in settings.items() if is_plant_name(n)})


def own_parameters(plan: SwitchPlan) -> dict[str, float]:
    """A planned switch's own parameters: drawn from the population (`vary`), then those the plan sets."""
    drawn = draw_switch(plan.vary).plant if plan.vary is not None else {}
    return {**drawn, **plan.plant}


def simulation(plant: Plant, plan: SwitchPlan, scenario: Scenario, k: int, start_ns: int = 0) -> SwitchSimulation:
    """The plant simulation of the k-th switch of a scenario."""
    return SwitchSimulation(plant, rate_hz=scenario.rate_hz, faults=plan.faults, noise_rel=scenario.noise,
                            seed=scenario.seed + k, start_ns=start_ns, own=own_parameters(plan),
                            stroke_s=scenario.stroke_s, end_s=scenario.throw_s)


def recorded_throws(messages: Iterable[Message]) -> list[RecordedThrow]:
    """The complete throws of a recording, as material for ReplayedSwitch."""
    out = []
    for throw in cut_throws(messages):
        if throw.end is None or throw.missing_samples:
            continue
        after = throw.t_s > 0  # the sample at the start event belongs to the rest before the throw
        reference = Reference(np.asarray(throw.start.reference_t_s), np.asarray(throw.start.reference_velocity_rad_s))
        out.append(RecordedThrow(throw.start.direction, reference, throw.signals[after]))
    return out
