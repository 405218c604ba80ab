"""Diagnosis and health messages as an operator reads them: one line of text each (logs and pipes), and the
live table of each switch's latest diagnosis and health (watch, demo), with the estimates, decisions, states and
throws to a limit that history and fleet show too."""
from __future__ import annotations

from rich.table import Table

from railswitch.schemas import FAULT_PARAMETERS, Alarm, Diagnosis, HistoryReply, SwitchHealth
from railswitch.schemas.history import format_time

DECISION_STYLE = {"nominal": "green", "unknown": "yellow"}
STATE_STYLE = {"ok": "green", "watch": "yellow", "alarm": "bold red"}


def key_estimates(diagnosis: Diagnosis) -> str:
    """Each present fault's estimates with their standard deviations (the decided one's, from a diagnoser that names
    one fault), or the reason for unknown."""
    if diagnosis.decision == "unknown":
        return diagnosis.reason or ""
    estimates = diagnosis.estimates or ([diagnosis.estimate] if diagnosis.estimate is not None else [])
    several = len(estimates) > 1
    out = []
    for estimate in estimates:  # each present fault over the throws since it was confirmed that can see it
        parts = []
        for name, value in estimate.params.items():
            std = estimate.std.get(name)
            unit = FAULT_PARAMETERS[name].unit
            parts.append(f"{name} {value:.4g}" + (f" ± {std:.2g}" if std is not None else "") + f" {unit}")
        out.append(", ".join(parts) + (f" ({estimate.throws} throws)" if estimate.throws > 1 else ""))
    return "; ".join(out) if several else "".join(out)


def decision_text(diagnosis: Diagnosis) -> str:
    """The present faults (several joined by '+'), else the decision."""
    return " + ".join(diagnosis.faults) if diagnosis.faults else diagnosis.decision


def diagnosis_line(diagnosis: Diagnosis) -> str:
    """One line of plain text for logs and pipes."""
    estimates = key_estimates(diagnosis)
    return (f"{diagnosis.switch_id} throw {diagnosis.throw_index} {diagnosis.direction}: {decision_text(diagnosis)}"
            f"{' - ' + estimates if estimates else ''} ({diagnosis.latency_ms:.0f} ms)")


def to_limit(health: SwitchHealth) -> str:
    """The worst parameter and the throws left until its limit, with the 5 %-95 % interval."""
    if health.worst is None:
        return ""
    if health.throws_to_limit is None:
        return f"{health.worst}: not heading for its limit"
    worst = next((p for p in health.parameters if p.name == health.worst), None)
    interval = ""
    if worst is not None and worst.throws_to_limit_low is not None and worst.throws_to_limit_high is not None:
        interval = f" ({worst.throws_to_limit_low:.0f}–{worst.throws_to_limit_high:.0f})"
    return f"{health.worst}: {health.throws_to_limit:.0f} throws{interval}"


def state_markup(state: str) -> str:
    return f"[{STATE_STYLE[state]}]{state}[/]"


def health_line(health: SwitchHealth) -> str:
    """One line of plain text for logs and pipes."""
    worst = to_limit(health)
    return f"{health.switch_id} health after throw {health.throw_index}: {health.state}{' - ' + worst if worst else ''}"


def diagnosis_table(latest: dict[str, Diagnosis], health: dict[str, SwitchHealth] | None = None,
                    title: str = "railswitch diagnoses") -> Table:
    """The latest diagnosis of each switch, and its health (state, worst parameter's throws to its limit)."""
    health = health or {}
    table = Table(title=title, expand=False)
    for column in ("switch", "throw", "direction", "decision", "key estimates", "latency ms", "health",
                   "worst: throws to limit"):
        table.add_column(column, justify="right" if column in ("throw", "latency ms") else "left")
    for switch_id in sorted(latest.keys() | health.keys()):
        d, h = latest.get(switch_id), health.get(switch_id)
        cells = ["", "", "", "", ""] if d is None else [
            str(d.throw_index), d.direction, f"[{DECISION_STYLE.get(d.decision, 'bold red')}]{decision_text(d)}[/]",
            key_estimates(d), f"{d.latency_ms:.0f}"]
        table.add_row(switch_id, *cells, "" if h is None else state_markup(h.state), "" if h is None else to_limit(h))
    return table


def messages_in_order(reply: HistoryReply) -> list[Diagnosis | SwitchHealth | Alarm]:
    """Diagnoses, health messages and alarm changes by time; a throw's diagnosis before its health, then the alarm
    changes it made in their order."""
    keyed = [((d.t_end_ns, d.throw_index, 0), d) for d in reply.diagnoses]
    keyed += [((h.t_ns, h.throw_index, 1), h) for h in reply.health]
    keyed += [((a.t_ns, a.last_throw, 2, a.sequence), a) for a in reply.alarms]
    return [message for _, message in sorted(keyed, key=lambda pair: pair[0])]


def history_table(reply: HistoryReply) -> Table:
    """One row per throw: its end, decision and estimates, and the switch's health after it."""
    table = Table(title=f"history of {reply.switch_id}", expand=False)
    for column in ("end (UTC)", "throw", "direction", "decision", "key estimates", "health", "worst: throws to limit"):
        table.add_column(column, justify="right" if column == "throw" else "left")
    rows: dict[tuple[int, int], list[str]] = {}
    for message in messages_in_order(reply):
        if isinstance(message, Alarm):
            continue  # in their own table
        if isinstance(message, Diagnosis):
            style = DECISION_STYLE.get(message.decision, "bold red")
            rows[message.t_end_ns, message.throw_index] = [
                format_time(message.t_end_ns), str(message.throw_index), message.direction,
                f"[{style}]{message.decision}[/]", key_estimates(message), "", ""]
        else:
            row = rows.setdefault((message.t_ns, message.throw_index),
                                  [format_time(message.t_ns), str(message.throw_index), "", "", "", "", ""])
            row[5:] = [state_markup(message.state), to_limit(message)]
    for row in rows.values():
        table.add_row(*row)
    return table


def alarm_table(reply: HistoryReply) -> Table:
    """One row per alarm change: when, which alarm, what changed, its severity, throws and text."""
    table = Table(title=f"alarm changes of {reply.switch_id}", expand=False)
    for column in ("time (UTC)", "alarm", "change", "severity", "throws", "text"):
        table.add_column(column)
    for alarm in reply.alarms:
        note = f" ({alarm.note})" if alarm.note else ""
        table.add_row(format_time(alarm.t_ns), alarm.alarm, alarm.change, alarm.severity,
                      f"{alarm.first_throw}–{alarm.last_throw} ({alarm.count})", alarm.text + note)
    return table
