"""`railswitch watch`: a live table of the latest Diagnosis of each switch.

On a terminal the table redraws in place; otherwise (or with --jsonl) every diagnosis
is printed as one line as it arrives, so the output can be piped or logged.
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

from railswitch.schemas import FAULT_PARAMETERS, Diagnosis, key_expr
from railswitch.services.adapters.zenoh_bus import BusOptions, Inbox, open_session
from railswitch.services.commands import options
from railswitch.services.core.intake import Intake

log = logging.getLogger("railswitch.watch")

DECISION_STYLE = {"nominal": "green", "unknown": "yellow"}


def key_estimates(diagnosis: Diagnosis) -> str:
    """The decided mode's estimates with their standard deviations, or the reason for unknown."""
    if diagnosis.decision == "unknown":
        return diagnosis.reason or ""
    estimate = diagnosis.estimate  # the decided fault over the throws that can see it
    if estimate is None:
        return ""
    parts = []
    for name, value in estimate.params.items():
        std = estimate.std.get(name)
        unit = FAULT_PARAMETERS[name].unit
        parts.append(f"{name} {value:.4g}" + (f" ± {std:.2g}" if std is not None else "") + f" {unit}")
    return ", ".join(parts) + (f" ({estimate.throws} throws)" if estimate.throws > 1 else "")


def diagnosis_line(diagnosis: Diagnosis) -> str:
    """One line of plain text for logs and pipes."""
    estimates = key_estimates(diagnosis)
    return (f"{diagnosis.switch_id} throw {diagnosis.throw_index} {diagnosis.direction}: {diagnosis.decision}"
            f"{' - ' + estimates if estimates else ''} ({diagnosis.latency_ms:.0f} ms)")


def diagnosis_table(latest: dict[str, Diagnosis], title: str = "railswitch diagnoses") -> Table:
    table = Table(title=title, expand=False)
    for column in ("switch", "throw", "direction", "decision", "key estimates", "latency ms"):
        table.add_column(column, justify="right" if column in ("throw", "latency ms") else "left")
    for switch_id in sorted(latest):
        d = latest[switch_id]
        style = DECISION_STYLE.get(d.decision, "bold red")
        table.add_row(switch_id, str(d.throw_index), d.direction, f"[{style}]{d.decision}[/]", key_estimates(d),
                      f"{d.latency_ms:.0f}")
    return table


def run_watch(options: BusOptions, *, switch_ids: list[str], count: int | None, duration_s: float | None,
              jsonl: bool, stop: threading.Event) -> int:
    """Show diagnoses until stop, `count` diagnoses or `duration_s`; returns how many arrived."""
    session = open_session(options, stop=stop)
    try:
        keys = [key_expr(s, "diagnosis") for s in switch_ids] or ["railswitch/*/diagnosis"]
        inbox = Inbox(session, keys)
        intake = Intake(log, kinds=("diagnosis",))  # junk is counted and logged once per kind
        console = Console(stderr=False)
        live_table = console.is_terminal and not jsonl
        latest: dict[str, Diagnosis] = {}
        received = 0
        deadline = None if duration_s is None else time.monotonic() + duration_s
        with Live(diagnosis_table(latest), console=console, auto_refresh=False) if live_table else nullcontext() as live:
            while not stop.is_set() and (count is None or received < count):
                if deadline is not None and time.monotonic() > deadline:
                    break
                item = inbox.get(0.2)
                diagnosis = None if item is None else intake.message(item)
                if diagnosis is None:
                    continue
                received += 1
                latest[diagnosis.switch_id] = diagnosis
                if live_table:
                    live.update(diagnosis_table(latest), refresh=True)
                else:
                    print(diagnosis.model_dump_json() if jsonl else diagnosis_line(diagnosis), flush=True)
        return received
    finally:
        session.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    options.add_service_arguments(parser)
    parser.add_argument("--switch-id", type=options.switch_id, action="append", default=[],
                        help="only this switch (repeatable)")
    parser.add_argument("--jsonl", action="store_true", help="one Diagnosis JSON object per line")
    parser.add_argument("--count", type=options.bounded(int, 1, 10**9), default=None, help="exit after N diagnoses")
    parser.add_argument("--duration", type=options.bounded(float, 0.1, 10**9, "s"), default=None,
                        help="exit after S seconds")


def run(args: argparse.Namespace) -> int:
    return options.run_service(lambda bus, stop: run_watch(bus, switch_ids=args.switch_id, count=args.count,
                                                           duration_s=args.duration, jsonl=args.jsonl, stop=stop), args)
