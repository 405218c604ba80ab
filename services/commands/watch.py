"""`railswitch watch`: a live table of the latest Diagnosis and SwitchHealth of each switch.

On a terminal the table redraws in place; otherwise every diagnosis and health message is printed
as one line as it arrives, so the output can be piped or logged (--jsonl: each Diagnosis as JSON).
"""
from __future__ import annotations

import argparse
import logging
import threading
import time
from contextlib import nullcontext

from rich.console import Console
from rich.live import Live
from rich.table import Table

from railswitch.schemas import FAULT_PARAMETERS, Diagnosis, SwitchHealth, key_expr
from railswitch.services.adapters.zenoh_bus import BusError, BusOptions, Inbox, open_session
from railswitch.services.commands import options
from railswitch.services.core.intake import Intake

log = logging.getLogger("railswitch.watch")

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


def run_watch(options: BusOptions, *, switch_ids: list[str], count: int | None, duration_s: float | None,
              jsonl: bool, stop: threading.Event) -> int:
    """Show diagnoses and health until stop, `count` diagnoses or `duration_s`; returns how many diagnoses arrived.

    The duration counts from the start, connecting included: with no bus by then it gives up (BusError), at most one
    retry and one connection attempt (about 3 s) later."""
    deadline = None if duration_s is None else time.monotonic() + duration_s
    try:
        session = open_session(options, stop=stop, wait_s=duration_s)
    except BusError as error:
        if deadline is None or stop.is_set() or time.monotonic() < deadline:
            raise
        raise BusError(f"no bus within --duration {duration_s:g} s: {error}") from None
    try:
        keys = [key_expr(s, kind) for s in switch_ids for kind in ("diagnosis", "health")] or [
            "railswitch/*/diagnosis", "railswitch/*/health"]
        inbox = Inbox(session, keys)
        intake = Intake(log, kinds=("diagnosis", "health"))  # junk is counted and logged once per kind
        console = Console(stderr=False)
        live_table = console.is_terminal and not jsonl
        latest: dict[str, Diagnosis] = {}
        health: dict[str, SwitchHealth] = {}
        received = 0
        table = Live(diagnosis_table(latest), console=console, auto_refresh=False) if live_table else nullcontext()
        with table as live:
            while not stop.is_set() and (count is None or received < count):
                if deadline is not None and time.monotonic() > deadline:
                    break
                item = inbox.get(0.2)
                message = None if item is None else intake.message(item)
                if message is None:
                    continue
                if isinstance(message, SwitchHealth):
                    health[message.switch_id] = message
                else:
                    received += 1
                    latest[message.switch_id] = message
                if live_table:
                    live.update(diagnosis_table(latest, health), refresh=True)
                else:
                    _print_line(message, jsonl)
        return received
    finally:
        session.close()


def _print_line(message: Diagnosis | SwitchHealth, jsonl: bool) -> None:
    """A diagnosis as JSON (--jsonl) or text; a health message as text (not with --jsonl, whose lines are
    Diagnosis objects only)."""
    if isinstance(message, SwitchHealth):
        if not jsonl:
            print(health_line(message), flush=True)
    else:
        print(message.model_dump_json() if jsonl else diagnosis_line(message), flush=True)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    options.add_service_arguments(parser)
    parser.add_argument("--switch-id", type=options.switch_id, action="append", default=[],
                        help="only this switch (repeatable)")
    parser.add_argument("--jsonl", action="store_true", help="one Diagnosis JSON object per line")
    parser.add_argument("--count", type=options.bounded(int, 1, 10**9), default=None, help="exit after N diagnoses")
    parser.add_argument("--duration", type=options.bounded(float, 0.1, 10**9, "s"), default=None,
                        help="exit after S seconds, counted from the start (connecting included)")


def run(args: argparse.Namespace) -> int:
    return options.run_service(lambda bus, stop: run_watch(bus, switch_ids=args.switch_id, count=args.count,
                                                           duration_s=args.duration, jsonl=args.jsonl, stop=stop), args)
