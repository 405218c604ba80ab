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

from railswitch.schemas import Diagnosis, SwitchHealth, key_expr
from railswitch.services.adapters.zenoh_bus import BusError, BusOptions, Inbox, open_session
from railswitch.services.commands import options
from railswitch.services.core.intake import Intake
from railswitch.services.core.tables import diagnosis_line, diagnosis_table, health_line

log = logging.getLogger("railswitch.watch")

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
