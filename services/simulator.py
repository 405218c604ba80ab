"""`railswitch simulator`: simulated switches on the bus, paced in real time or faster.

Each switch computes a whole throw (or idle period) ahead with the high-fidelity plant
and then streams its samples at the sample rate, so the cost scales with throws, not
samples. Switches' throws are staggered evenly over the interval. FaultCommands on
railswitch/<id>/inject act from the next throw on.
"""
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from models.plant import Plant
from models.reference import THROW_DURATION_S
from models.reference import Reference
from models.switch import RecordedThrow, ReplayedSwitch, SwitchSimulation
from schemas import FaultCommand, Message
from schemas.scenario import Scenario, SwitchPlan
from services.bus import BusOptions, Inbox, Publishers, StatusReporter, declare_service, open_session
from services.intake import Intake
from services.switch_messages import motor_messages, throw_messages, truth_message
from services.throw_cutter import cut_throws

log = logging.getLogger("railswitch.simulator")

LEAD_S = 1.0  # samples at rest before the first throw, so subscribers see the switch settled


@dataclass
class SwitchStream:
    """One simulated switch: its plant simulation, fault schedule and the messages computed ahead."""

    plan: SwitchPlan
    sim: SwitchSimulation | ReplayedSwitch
    idle_s: float
    faults: dict[str, float]
    pending: deque[tuple[int, str, Message]] = field(default_factory=deque)
    throws_done: int = 0
    idle_next: bool = False
    finished: bool = False

    @classmethod
    def start(cls, plan: SwitchPlan, sim: SwitchSimulation | ReplayedSwitch, *, interval_s: float, offset_s: float) -> SwitchStream:
        stream = cls(plan, sim, interval_s - THROW_DURATION_S, dict(plan.faults))
        stream._push([truth_message(plan.id, sim, sim.time_ns(0))])
        stream._push(motor_messages(plan.id, sim, sim.initial_sample()))
        if offset_s > 0:
            stream._push(motor_messages(plan.id, sim, sim.idle(offset_s)))
        return stream

    def _push(self, messages: Iterable[tuple[str, Message]]) -> None:
        for key, message in messages:
            self.pending.append((message.t_ns, key, message))

    @property
    def done(self) -> bool:
        return self.finished and not self.pending

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
            self._push(motor_messages(self.plan.id, self.sim, self.sim.idle(self.idle_s)))
        elif self.throws_done < self.plan.throws:
            try:
                self.faults = self.plan.faults_before(self.throws_done, self.faults)
            except ValueError as error:
                log.warning("%s; keeping the faults in force", error)
            self.sim.set_faults(self.faults)
            throw = self.sim.throw()
            log.info("%s throw %d %s, faults %s", self.plan.id, throw.index, throw.direction, self.faults or "none")
            self._push(throw_messages(self.plan.id, self.sim, throw))
            self.throws_done += 1
            self.idle_next = self.throws_done < self.plan.throws
        else:
            self.finished = True

    def command(self, command: FaultCommand) -> None:
        """Apply a FaultCommand from the next throw on."""
        faults = {} if command.reset else dict(self.faults)
        faults.update(command.params)
        self.faults = faults
        log.info("%s: faults set to %s from throw %d on", self.plan.id, faults or "none", self.throws_done)


def recorded_throws(messages: Iterable[Message]) -> list[RecordedThrow]:
    """The complete throws of a recording, as material for ReplayedSwitch."""
    out = []
    for throw in cut_throws(messages):
        if throw.end is None or throw.missing_samples:
            continue
        after = throw.t_s > 0  # the sample at the start event belongs to the rest before the throw
        reference = Reference(np.asarray(throw.start.reference_t_s), np.asarray(throw.start.reference_velocity_rad_s))
        out.append(RecordedThrow(throw.start.direction, reference, throw.current_a[after], throw.angle_rad[after],
                                 throw.velocity_rad_s[after]))
    return out


def run_simulator(options: BusOptions, scenario: Scenario, *, speed: float, stop: threading.Event,
                  library: list[RecordedThrow] | None = None, status_s: float = 5.0) -> int:
    """Stream the scenario's switches until every plan is done or stop is set; returns messages published.

    With a library of recorded throws the switches replay those instead of running the plant.
    """
    session = open_session(options, stop=stop)
    try:
        publishers = Publishers(session)
        inbox = Inbox(session, ["railswitch/*/inject"])
        intake = Intake(log, kinds=("inject",))
        status = StatusReporter(publishers, "simulator", intake, status_s)
        token = declare_service(session, "simulator")
        plant = Plant() if library is None else None
        start_ns = time.time_ns()
        count = len(scenario.switches)
        streams = {}
        for k, plan in enumerate(scenario.switches):
            if plant is None:
                sim = ReplayedSwitch(library, rate_hz=scenario.rate_hz, start_ns=start_ns, first=k)
            else:
                sim = SwitchSimulation(plant, rate_hz=scenario.rate_hz, faults=plan.faults, noise_rel=scenario.noise,
                                       seed=scenario.seed + k, start_ns=start_ns)
            streams[plan.id] = SwitchStream.start(plan, sim, interval_s=scenario.interval_s,
                                                  offset_s=LEAD_S + k * scenario.interval_s / count)
        log.info("simulating %d switch(es) at %g samples/s, %gx real time", count, scenario.rate_hz, speed)
        clock = next(iter(streams.values())).sim
        wall0, tick = time.monotonic(), 0
        while not stop.is_set() and not all(s.done for s in streams.values()):
            t_ns = clock.time_ns(tick)
            for stream in streams.values():
                for key, message in stream.due(t_ns):
                    publishers.put(key, message)
            _apply_commands(inbox, intake, streams)
            status.maybe_publish({"published": publishers.published})
            tick += 1
            delay = wall0 + tick / (scenario.rate_hz * speed) - time.monotonic()
            if delay > 0:
                stop.wait(delay)
        token.undeclare()
        log.info("published %d messages", publishers.published)
        return publishers.published
    finally:
        session.close()


def _apply_commands(inbox: Inbox, intake: Intake, streams: dict[str, SwitchStream]) -> None:
    while (item := inbox.get(0.0)) is not None:
        command = intake.message(item)
        if isinstance(command, FaultCommand) and command.switch_id in streams:
            streams[command.switch_id].command(command)
