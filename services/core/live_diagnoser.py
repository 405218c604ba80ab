"""A live diagnoser's core: received samples, events and records through the intake and throw cutter into the
fleet diagnoser; each Diagnosis, SwitchHealth and SwitchState published on the switch's channels.

Which throws it diagnoses is up to its ownership: a fixed shard (services/core/shards.py FixedShard) or the
elastic membership of the live diagnosers (services/core/membership.py Membership). Elastic, every diagnoser
cuts every switch's throws, the owner at a throw's end diagnoses it and the others hold it until its Diagnosis is
seen, taking it over if the owner leaves first (services/core/handover.py). A switch's state goes on the bus after
every throw, so its next owner resumes it.
"""
from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable

from railswitch.schemas import (
    AckCommand,
    CommissionCommand,
    MaintenanceCommand,
    Diagnosis,
    Message,
    SwitchState,
    ThrowEvent,
    ThrowRecord,
    key_expr,
)
from railswitch.services.ports import Publisher, Received
from railswitch.services.core.fleet_diagnoser import DiagnosedThrow, Diagnoser, throw_end_ns
from railswitch.services.core.handover import HeldThrow, HeldThrows, StateCache, diagnosis_key
from railswitch.services.core.intake import Intake
from railswitch.services.core.records import throw_of_record
from railswitch.services.core.shards import FixedShard, Ownership
from railswitch.services.core.throw_cutter import CutThrow, ThrowCutter

log = logging.getLogger("railswitch.diagnoser")

INPUT_KINDS = ("motor", "throw", "record", "commission", "ack", "maintenance", "diagnosis", "state")
EXPIRE_EVERY_S = 1.0
# in every status, zeros too; `already_diagnosed`: throws a switch's state had seen (a cache's replay after a restart),
# `missed`: throws lost for good (older than the publishers' caches when this diagnoser came back), by index gaps
# `recovered`: throws of a sample stream this one had not heard, fetched from the recorders (Recover)
COUNTERS = ("diagnosed", "taken_over", "held_expired", "failed", "commissions", "already_diagnosed", "missed",
            "recovered", "alarm_changes", "acknowledged", "maintenance")
# What the recorders keep of a switch's sample stream that ended after a time (ns), as received records
# (services/adapters/zenoh_bus.py recent_throws; docs/contracts.md section 3, Catching up).
Recover = Callable[[str, int], list[Received]]


class LiveDiagnoser:
    """Feeds received samples, events and records through the throw cutter into the diagnoser."""

    def __init__(self, diagnoser: Diagnoser, publishers: Publisher | None, ownership: Ownership | None = None,
                 known: Callable[[str], bool] | None = None, clock: Callable[[], float] = time.monotonic,
                 recover: Recover | None = None):
        """The diagnoser's states go on the bus as well as to its own on_state (a BaselineStore on disk), and a
        switch met for the first time resumes from the latest state on the bus before its own stored_state.
        `known(switch_id)`: whether a switch has a stored state (a commission command for a switch neither seen nor
        stored is refused). `recover`: where the throws a switch's state skips are asked for before they are
        reported missed. Without publishers nothing is published; without ownership every switch is served."""
        self.diagnoser = diagnoser
        self._save, self._load = diagnoser.on_state, diagnoser.stored_state
        diagnoser.on_state, diagnoser.stored_state = self._on_state, self._stored_state
        self.publishers = publishers
        self.ownership = ownership or FixedShard((1, 1), "this diagnoser")
        self.known = known or (lambda switch_id: False)
        self.clock = clock
        self.intake = Intake(log, INPUT_KINDS, self.ownership.serves)
        self.cutter = ThrowCutter(on_problem=lambda switch_id, reason: self.intake.reject(
            reason, key_expr(switch_id, "throw")))
        self.states = StateCache(diagnoser.model)
        self.held = HeldThrows()
        self.counts: Counter[str] = Counter()  # COUNTERS
        self.failures: Counter[str] = Counter()  # per exception type
        self._seen: set[str] = set()  # switches whose throws have been on the bus
        self._started: dict[str, float] = {}  # arrival of each switch's latest start event
        self._latest: dict[str, tuple[int, int]] = {}  # per switch: (throw index, end ns) this one last diagnosed
        self._unpublished: dict[str, dict] = {}  # states handed over by the diagnoser, not yet on the bus
        self.recover = recover
        self._recovering = False
        self._next_expiry = clock() + EXPIRE_EVERY_S

    @property
    def diagnosed(self) -> int:
        return self.counts["diagnosed"]

    @property
    def commissions(self) -> int:
        return self.counts["commissions"]

    def handle(self, item: Received) -> None:
        message = self.intake.message(item)
        if isinstance(message, Diagnosis):
            if message.model == self.diagnoser.model:
                self.held.seen(diagnosis_key(message), self.clock())
        elif isinstance(message, SwitchState):
            self._state_seen(message)
        elif isinstance(message, CommissionCommand):
            self._commission(message, item.key)
        elif isinstance(message, AckCommand):
            self._acknowledge(message, item.key)
        elif isinstance(message, MaintenanceCommand):
            self._maintenance(message, item.key)
        elif isinstance(message, ThrowRecord):
            self._seen.add(message.switch_id)
            self._completed(throw_of_record(message), item.arrived_s, item.arrived_s)
        elif message is not None:
            self._cut(message, item.arrived_s)

    def _cut(self, message: Message, arrived_s: float) -> None:
        switch_id = message.switch_id
        self._seen.add(switch_id)
        started_s = self._started.get(switch_id, arrived_s)  # of the throw this message may complete
        if isinstance(message, ThrowEvent) and message.phase == "start":
            self._started[switch_id] = arrived_s
        throw = self.cutter.feed(message)
        if throw is not None:
            self._completed(throw, started_s, arrived_s)

    def _completed(self, throw: CutThrow, started_s: float, arrived_s: float) -> None:
        """A throw's end: its owner (among the diagnosers there when it started) diagnoses it, the others hold it."""
        owner = self.ownership.owner(throw.switch_id, started_s)
        if owner == self.ownership.me:
            self._diagnose(throw, arrived_s)
        elif owner is not None:
            self.held.hold(HeldThrow(throw, owner, started_s, arrived_s))

    def rebalance(self) -> None:
        """After the live set changed: forget the switches no longer this one's (when one comes back it resumes
        from the latest state on the bus) and take over the held throws whose owner left."""
        for switch_id in [s for s in self.diagnoser.switches if not self.ownership.is_mine(s)]:
            self.diagnoser.forget(switch_id)
        for held in self.held.orphaned(self.ownership.members):
            owner = self.ownership.owner(held.throw.switch_id, held.started_s)
            if owner == self.ownership.me:
                self.counts["taken_over"] += 1
                log.info("%s throw %d: taken over from %s", held.throw.switch_id, held.throw.start.throw_index,
                         held.owner)
                self._diagnose(held.throw, held.arrived_s)
            elif owner is not None:
                self.held.hold(HeldThrow(held.throw, owner, held.started_s, held.arrived_s))

    def _diagnose(self, throw: CutThrow, arrived_s: float) -> None:
        if not self._new(throw):
            return
        diagnosed = self._diagnosed(throw, arrived_s)
        diagnosis = diagnosed.diagnosis
        self._put(key_expr(throw.switch_id, "diagnosis"), diagnosis)
        if diagnosed.health is not None:
            self._put(key_expr(throw.switch_id, "health"), diagnosed.health)
        self._alarms(diagnosed.alarms)
        self._latest[throw.switch_id] = (diagnosis.throw_index, diagnosis.t_end_ns)
        self._publish_state(throw.switch_id, diagnosis.throw_index, diagnosis.t_end_ns)
        self.counts["diagnosed"] += 1
        log.info("%s throw %d %s: %s (%.0f ms)%s", throw.switch_id, diagnosis.throw_index, diagnosis.direction,
                 diagnosis.decision, diagnosis.latency_ms, f" - {diagnosis.reason}" if diagnosis.reason else "")

    def _new(self, throw: CutThrow) -> bool:
        """Whether the switch's state has not seen this throw yet (a publisher's cache replays the throws it kept to a
        diagnoser that comes back, those diagnosed before it went down among them). Throws skipped between the
        state's latest and this one are counted and logged as missed, with their indices."""
        switch_id, index = throw.switch_id, throw.start.throw_index
        try:
            self.diagnoser.switch(switch_id)  # resumed from the latest state on the bus or on disk
        except Exception:  # noqa: BLE001 - a state that cannot be resumed: _diagnosed says why and starts afresh
            return True
        last = self.diagnoser.last_throws.get(switch_id)
        if last is None:
            return True
        if throw_end_ns(throw) <= last[1]:
            self.counts["already_diagnosed"] += 1
            return False
        if index > last[0] + 1 and self.recover is not None and not self._recovering:
            self._catch_up(switch_id, last[1], throw_end_ns(throw))
            last = self.diagnoser.last_throws.get(switch_id, last)
            if throw_end_ns(throw) <= last[1]:  # the recorders had it too
                self.counts["already_diagnosed"] += 1
                return False
        if index > last[0] + 1:
            self.counts["missed"] += index - last[0] - 1
            log.warning("%s throws %s missed: they ended while no diagnoser was listening, longer ago than the "
                        "publisher keeps throws (and no recorder kept them)", switch_id,
                        last[0] + 1 if index == last[0] + 2 else f"{last[0] + 1} to {index - 1}")
        return True

    def catch_up(self) -> None:
        """Diagnose what the recorders kept of the switches' sample streams that this one has not seen (a diagnoser
        starting after all were down): each owned switch's throws newer than its state, in order."""
        if self.recover is not None:
            before = self.counts["diagnosed"]
            self._recovering = True  # what a gap among these lacks, the recorders do not hold either: no second query
            try:
                for item in self.recover("*", 0):
                    self.handle(item)
            finally:
                self._recovering = False
            self.counts["recovered"] += self.counts["diagnosed"] - before

    def _catch_up(self, switch_id: str, after_ns: int, before_ns: int) -> None:
        """Diagnose, in order, the throws of a switch that ended after its state's latest and before the throw at
        hand, as far as the recorders kept them (a sample stream this one did not hear)."""
        self._recovering = True
        try:
            for item in self.recover(switch_id, after_ns):
                message = self.intake.message(item)
                if isinstance(message, ThrowRecord) and message.switch_id == switch_id and message.t_end_ns < before_ns:
                    self.counts["recovered"] += 1
                    log.info("%s throw %d: recovered from the recorders", switch_id, message.throw_index)
                    self._diagnose(throw_of_record(message), item.arrived_s)
        finally:
            self._recovering = False

    def _diagnosed(self, throw: CutThrow, arrived_s: float) -> DiagnosedThrow:
        """The diagnosis, or an unknown one saying why it failed: one throw must not stop a fleet's diagnoser. A
        switch that could not even be resumed drops the state it was resumed from, so its next throw starts afresh.
        Either one's latency runs from the throw's end arriving (`arrived_s`, on the diagnoser's clock)."""
        try:
            return self.diagnoser.diagnose(throw, waited_s=self.clock() - arrived_s)
        except Exception as error:  # noqa: BLE001 - whatever the estimator or a foreign state raises
            name = type(error).__name__
            self.failures[name] += 1
            self.counts["failed"] += 1
            if self.failures[name] == 1:
                log.exception("%s throw %d: diagnosis failed (further %s failures are counted)", throw.switch_id,
                              throw.start.throw_index, name)
            if throw.switch_id not in self.diagnoser.switches:
                self.states.forget(throw.switch_id)
            latency_ms = (self.clock() - arrived_s) * 1e3
            return DiagnosedThrow(throw, failed_diagnosis(self.diagnoser.model, throw, f"{name}: {error}", latency_ms),
                                  None)

    def _put(self, key: str, message: Message) -> None:
        if self.publishers is not None:
            self.publishers.put(key, message)

    def _on_state(self, switch_id: str, state: dict) -> None:
        self._unpublished[switch_id] = state  # saved once the throw's diagnosis is out (_publish_state)

    def _stored_state(self, switch_id: str) -> dict | None:
        cached = self.states.get(switch_id)
        if cached is not None:
            return cached.state
        return self._load(switch_id) if self._load is not None else None

    def _publish_state(self, switch_id: str, index: int, t_ns: int) -> None:
        """The state the diagnoser handed over, after throw `index` that ended at t_ns, saved and on the bus. Saved only
        now: a diagnoser killed between saving a state and publishing its throw's diagnosis would, restarted, take
        the throw for diagnosed (its state has seen it) and it would never be published."""
        state = self._unpublished.pop(switch_id, None)
        if state is None:
            return
        if self._save is not None:
            self._save(switch_id, state)
        message = SwitchState(switch_id=switch_id, model=self.diagnoser.model, throw_index=index, t_ns=t_ns,
                              state=state)
        self.states.put(message)
        self._put(key_expr(switch_id, "state"), message)

    def _state_seen(self, state: SwitchState) -> None:
        """Cache it; a switch held here that another diagnoser has since diagnosed later is dropped, to resume from
        that state at its next throw. This one's own state after its latest throw, back from the bus (a session hears
        its own publications), was cached when published: not encoded and compressed again."""
        latest = self._latest.get(state.switch_id)
        if latest is not None and state.t_ns == latest[1] == self.states.t_ns(state.switch_id):
            return
        if not self.states.put(state):
            return
        self._seen.add(state.switch_id)
        if state.switch_id in self.diagnoser.switches and (latest is None or state.t_ns > latest[1]):
            self.diagnoser.forget(state.switch_id)

    def _alarms(self, alarms) -> None:
        for alarm in alarms:
            self._put(key_expr(alarm.switch_id, "alarm"), alarm)
            self.counts["alarm_changes"] += 1
            log.info("%s alarm %s %s (%s): %s", alarm.switch_id, alarm.alarm, alarm.change, alarm.severity, alarm.text)

    def _commanded(self, switch_id: str, kind: str, key: str) -> bool:
        """Whether this one carries out a command for the switch: it owns it and knows it (a command for a switch
        neither seen nor stored is refused, counted as `<kind>: unknown switch`)."""
        if not self.ownership.is_mine(switch_id):
            return False  # its owner does it
        if not (switch_id in self.diagnoser.switches or switch_id in self.states or self.known(switch_id)):
            self.intake.reject(f"{kind}: unknown switch", key)
            return False
        return True

    def _publish_after_command(self, switch_id: str) -> None:
        """The switch's state after a command, on the bus as following its latest throw."""
        cached = self.states.get(switch_id)  # a switch resumed from the bus: its latest throw is the cached state's
        after = max([self._latest.get(switch_id, (0, 0)), (cached.throw_index, cached.t_ns) if cached else (0, 0)],
                    key=lambda throw: throw[1])
        self._publish_state(switch_id, *after)

    def _acknowledge(self, command: AckCommand, key: str) -> None:
        switch_id = command.switch_id
        if not self._commanded(switch_id, "ack", key):
            return
        alarms = self.diagnoser.acknowledge(switch_id, time.time_ns(), command.alarm, command.note)
        if not alarms:
            self.intake.reject("ack: no such unacknowledged alarm", key)
            return
        self._alarms(alarms)
        self._publish_after_command(switch_id)
        self.counts["acknowledged"] += len(alarms)

    def _maintenance(self, command: MaintenanceCommand, key: str) -> None:
        switch_id = command.switch_id
        if not self._commanded(switch_id, "maintenance", key):
            return
        start = command.action == "start"
        if not self.diagnoser.set_maintenance(switch_id, start, time.time_ns(), command.recommission, command.note):
            self.intake.reject(f"maintenance: already {'in' if start else 'out of'} maintenance", key)
            return
        self._publish_after_command(switch_id)
        self.counts["maintenance"] += 1
        why = f" ({command.note})" if command.note else ""
        log.info("%s: maintenance %s%s%s", switch_id, "started" if start else "ended",
                 ", commissioning restarted" if command.recommission else "", why)

    def _commission(self, command: CommissionCommand, key: str) -> None:
        switch_id = command.switch_id
        if not self._commanded(switch_id, "commission", key):
            return
        accepted = self.diagnoser.commission(switch_id, accept=command.accept)
        self._publish_after_command(switch_id)
        self.counts["commissions"] += 1
        why = f" ({command.reason})" if command.reason else ""
        if command.accept:
            log.info("%s: accepted as it is%s: %s", switch_id, why, accepted or "no present fault to accept")
        else:
            log.info("%s: commissioning restarted%s", switch_id, why)

    def expire(self) -> None:
        """Forget held throws and seen diagnoses older than the grace period (at most once a second)."""
        now = self.clock()
        if now >= self._next_expiry:
            self._next_expiry = now + EXPIRE_EVERY_S
            self.counts["held_expired"] += self.held.expire(now)

    def state_replies(self) -> list[tuple[str, bytes]]:
        """The cached states of the switches this one owns, as (key, payload): its answer to a diagnoser starting
        up (services/commands/diagnoser.py)."""
        return [(key_expr(switch_id, "state"), self.states.payload(switch_id)) for switch_id in self.states.switch_ids()
                if self.ownership.is_mine(switch_id)]

    def counters(self) -> dict[str, int]:
        owned = sum(1 for switch_id in self._seen if self.ownership.is_mine(switch_id))
        counts = {name: self.counts[name] for name in COUNTERS}
        return {**counts, "switches": owned, "held": len(self.held), "members": len(self.ownership.members)}


def failed_diagnosis(model: str, throw: CutThrow, why: str, latency_ms: float) -> Diagnosis:
    """An unknown Diagnosis for a throw whose diagnosis raised, `latency_ms` after its end arrived."""
    end_ns = throw.end.t_ns if throw.end is not None else throw.start.t_ns
    return Diagnosis(switch_id=throw.switch_id, throw_index=throw.start.throw_index, direction=throw.start.direction,
                     t_start_ns=throw.start.t_ns, t_end_ns=end_ns, model=model, decision="unknown",
                     reason=f"diagnosis failed: {why}"[:500], latency_ms=latency_ms)
