"""The control room's view of a fleet (`railswitch fleet`): every switch by urgency, from its history.

A switch's open alarms are its alarms' latest changes that are still active or not yet acknowledged. Switches with
unacknowledged alarms come first, then those whose alarms were acknowledged and are still active, the more severe
first; then the fewest throws to a maintenance limit.
"""
from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from railswitch.schemas import SEVERITIES, Alarm, Diagnosis, HistoryReply, SwitchHealth


@dataclass(frozen=True)
class FleetRow:
    switch_id: str
    state: str  # the health state after its latest throw: ok, watch, alarm (unknown without health)
    alarms: tuple[Alarm, ...]  # open, most severe first
    worst: str  # the worst cause: the most severe open alarm's text, else the parameter closest to its limit
    throws_to_limit: float | None
    last_throw: int | None
    last_t_ns: int | None
    faults: str  # the latest diagnosis's present faults, nominal or unknown
    maintenance: bool  # its latest throw was thrown in maintenance

    @property
    def acknowledged(self) -> bool:
        """Every open alarm acknowledged (true without any)."""
        return all(alarm.acknowledged for alarm in self.alarms)

    def urgency(self) -> tuple:
        severity = max((SEVERITIES.index(a.severity) for a in self.alarms), default=-1)
        group = 0 if self.alarms and not self.acknowledged else 1 if self.alarms else 2
        to_limit = self.throws_to_limit if self.throws_to_limit is not None else math.inf
        return group, -severity, to_limit, self.switch_id

    def to_dict(self) -> dict:
        return {"switch_id": self.switch_id, "state": self.state, "worst": self.worst,
                "throws_to_limit": self.throws_to_limit, "last_throw": self.last_throw, "last_t_ns": self.last_t_ns,
                "faults": self.faults, "maintenance": self.maintenance, "acknowledged": self.acknowledged,
                "alarms": [alarm.model_dump(mode="json") for alarm in self.alarms]}


def open_alarms(changes: Iterable[Alarm]) -> list[Alarm]:
    """Each alarm's latest change, where the alarm is still open; the most severe first."""
    latest: dict[str, Alarm] = {}
    for change in sorted(changes, key=lambda a: a.sequence):
        latest[change.alarm] = change
    opened = [a for a in latest.values() if a.active or not a.acknowledged]
    return sorted(opened, key=lambda a: (-SEVERITIES.index(a.severity), a.alarm))


def fleet_row(reply: HistoryReply) -> FleetRow:
    diagnosis: Diagnosis | None = reply.diagnoses[-1] if reply.diagnoses else None
    health: SwitchHealth | None = reply.health[-1] if reply.health else None
    alarms = tuple(open_alarms(reply.alarms))
    if alarms:
        worst = alarms[0].text
    elif health is not None and health.worst is not None:
        worst = health.worst
    else:
        worst = ""
    last = diagnosis or health
    return FleetRow(
        switch_id=reply.switch_id, state=health.state if health is not None else "unknown", alarms=alarms, worst=worst,
        throws_to_limit=health.throws_to_limit if health is not None else None,
        last_throw=last.throw_index if last is not None else None,
        last_t_ns=(diagnosis.t_end_ns if diagnosis is not None else health.t_ns) if last is not None else None,
        faults=diagnosis.named() if diagnosis is not None else "", maintenance=diagnosis is not None and
        diagnosis.tag == "maintenance")


def fleet_rows(replies: Iterable[HistoryReply]) -> list[FleetRow]:
    """One row per switch, the most urgent first."""
    return sorted((fleet_row(reply) for reply in replies), key=FleetRow.urgency)
