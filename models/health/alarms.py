"""A switch's alarms as an operator handles them: raised, escalated, cleared and acknowledged, latched until then.

Each throw names the conditions it sees (a present fault, an anomaly, a feature outside its band), each with a
severity. An alarm is raised the first time its condition is seen; a repeat only counts and moves its last throw; a
higher severity escalates it (and asks for a new acknowledgement). When CLEAR_AFTER throws in a row that could see the
condition no longer do, the alarm is cleared (one quiet throw does not flap it: a condition one direction shows more
than the other) but stays latched until acknowledged; acknowledged and cleared, it is closed, and the next
occurrence raises a new one. Only changes are returned, numbered per switch (`sequence`), so each is published once.
"""
from __future__ import annotations

from collections.abc import Collection
from dataclasses import asdict, dataclass, field

from railswitch.schemas.messages import SEVERITIES

CLEAR_AFTER = 2  # judged throws in a row without its condition that clear an alarm


@dataclass(frozen=True)
class Condition:
    """What a throw shows that deserves an alarm."""

    cause: str  # fault, anomaly or feature
    severity: str
    text: str
    parameters: dict[str, float] = field(default_factory=dict)


@dataclass
class AlarmState:
    alarm: str
    cause: str
    severity: str
    text: str
    parameters: dict[str, float]
    first_throw: int
    last_throw: int
    count: int = 1
    active: bool = True
    acknowledged: bool = False
    note: str | None = None
    quiet: int = 0  # judged throws in a row without its condition


@dataclass(frozen=True)
class Change:
    """One change of an alarm: the alarm as it is after it, its kind, the switch's change number and when."""

    change: str  # raised, escalated, cleared or acknowledged
    alarm: AlarmState
    sequence: int
    t_ns: int


def rank(severity: str) -> int:
    return SEVERITIES.index(severity)


@dataclass
class AlarmBook:
    """A switch's open alarms (active, or cleared and not yet acknowledged) and its count of changes."""

    alarms: dict[str, AlarmState] = field(default_factory=dict)
    sequence: int = 0

    def observe(self, throw: int, t_ns: int, conditions: dict[str, Condition], judged: Collection[str] | None = None
                ) -> list[Change]:
        """A throw that shows `conditions` (by alarm id). Active alarms it could judge and does not show are cleared:
        every one, or those `judged` says (a feature of the other direction is not judged by this throw)."""
        changes = []
        for alarm_id, condition in conditions.items():
            state = self.alarms.get(alarm_id)
            if state is None or not state.active:
                first = throw if state is None else state.first_throw
                count = 1 if state is None else state.count + 1
                self.alarms[alarm_id] = AlarmState(alarm_id, condition.cause, condition.severity, condition.text,
                                                   dict(condition.parameters), first, throw, count)
                changes.append(self._change("raised", alarm_id, t_ns))
                continue
            state.count += 1
            state.last_throw, state.quiet = throw, 0
            state.text, state.parameters = condition.text, dict(condition.parameters)
            if rank(condition.severity) > rank(state.severity):
                state.severity, state.acknowledged, state.note = condition.severity, False, None
                changes.append(self._change("escalated", alarm_id, t_ns))
        for alarm_id, state in list(self.alarms.items()):
            if state.active and alarm_id not in conditions and (judged is None or alarm_id in judged):
                state.quiet += 1
                if state.quiet < CLEAR_AFTER:
                    continue
                state.active = False
                changes.append(self._change("cleared", alarm_id, t_ns))
                if state.acknowledged:
                    del self.alarms[alarm_id]
        return changes

    def acknowledge(self, t_ns: int, alarm_id: str | None = None, note: str | None = None) -> list[Change]:
        """Acknowledge every unacknowledged alarm, or the one named; a cleared one is closed. Nothing to acknowledge:
        no change."""
        changes = []
        for key, state in list(self.alarms.items()):
            if state.acknowledged or (alarm_id is not None and key != alarm_id):
                continue
            state.acknowledged, state.note = True, note
            changes.append(self._change("acknowledged", key, t_ns))
            if not state.active:
                del self.alarms[key]
        return changes

    def _change(self, kind: str, alarm_id: str, t_ns: int) -> Change:
        self.sequence += 1
        state = self.alarms[alarm_id]
        return Change(kind, AlarmState(**asdict(state)), self.sequence, t_ns)

    def latched(self) -> list[AlarmState]:
        """The alarms an operator still has to see to: active ones and cleared ones not acknowledged."""
        return [state for state in self.alarms.values() if state.active or not state.acknowledged]

    def to_dict(self) -> dict:
        return {"alarms": [asdict(state) for state in self.alarms.values()], "sequence": self.sequence}

    @classmethod
    def from_dict(cls, data: dict | None) -> AlarmBook:
        if not data:
            return cls()
        alarms = {a["alarm"]: AlarmState(**{"quiet": 0, **a}) for a in data.get("alarms", [])}
        return cls(alarms, int(data.get("sequence", 0)))
