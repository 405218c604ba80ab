"""`railswitch fleet`: every switch by urgency, for the control room.

Latched alarms first (unacknowledged before acknowledged, the more severe first), then the fewest throws to a limit;
with each switch's health state, worst cause, latest throw and faults, whether its alarms are acknowledged and whether
it is in maintenance. From the historians on the bus, or from a history file or database (--db).
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from collections.abc import Iterable

from rich.console import Console
from rich.table import Table

from railswitch.schemas import HISTORY_KEYS, HistoryQuery, HistoryReply
from railswitch.schemas.history import format_time
from railswitch.services.adapters.history_store import open_history
from railswitch.services.adapters.zenoh_bus import BusError, BusOptions, open_session
from railswitch.services.commands import options
from railswitch.services.adapters.history_bus import ask_historians
from railswitch.services.core.tables import state_markup
from railswitch.services.core.fleet_view import FleetRow, fleet_rows
from railswitch.services.core.historian import HistoryAnswers, merge_replies

ALARM_CHANGES = 1000  # of each switch: enough to know which of its alarms are open
QUERIES = (HistoryQuery(kind="diagnosis", limit=1), HistoryQuery(kind="health", limit=1),
           HistoryQuery(kind="alarm", limit=ALARM_CHANGES))
PIPE_WIDTH = 200  # columns when the table goes to a file or pipe: one line per switch, not wrapped at 80
SEVERITY_STYLE = {"info": "dim", "low": "cyan", "medium": "yellow", "high": "bold red", "critical": "bold white on red"}


def from_bus(bus: BusOptions, timeout_s: float) -> list[HistoryReply]:
    """Every switch's latest diagnosis and health and its alarm changes, from every historian, merged per switch."""
    session = open_session(bus, wait_s=timeout_s)
    try:
        return per_switch(r for query in QUERIES for r in ask_historians(session, HISTORY_KEYS, query, timeout_s)[0])
    finally:
        session.close()


def from_db(path: str) -> list[HistoryReply]:
    with open_history(path, create=False) as db:
        answers = HistoryAnswers(db, is_mine=lambda _: True, historian=db.name)
        return per_switch(r for query in QUERIES for r in answers.answer_query(query, None).decoded())


def per_switch(replies: Iterable[HistoryReply]) -> list[HistoryReply]:
    """The replies of each switch (one per query and historian) merged into one."""
    by_switch: dict[str, list[HistoryReply]] = defaultdict(list)
    for reply in replies:
        by_switch[reply.switch_id].append(reply)
    return [merge_replies(found, ALARM_CHANGES) for found in by_switch.values()]


def fleet_table(rows: list[FleetRow]) -> Table:
    table = Table(title="railswitch fleet, most urgent first", expand=False)
    for column in ("switch", "state", "alarms", "worst cause", "throws to limit", "latest throw", "faults", ""):
        table.add_column(column, justify="right" if column == "throws to limit" else "left")
    for row in rows:
        alarms = ", ".join(f"[{SEVERITY_STYLE[a.severity]}]{a.alarm}[/]" + ("" if a.acknowledged else " (new)")
                           for a in row.alarms)
        to_limit = f"{row.throws_to_limit:.0f}" if row.throws_to_limit is not None else ""
        latest = (f"{row.last_throw} at {format_time(row.last_t_ns)}" if row.last_throw is not None else "")
        flags = ", ".join([*(["maintenance"] if row.maintenance else []),
                           *(["acknowledged"] if row.alarms and row.acknowledged else [])])
        table.add_row(row.switch_id, state_markup(row.state) if row.state != "unknown" else "unknown", alarms,
                      row.worst, to_limit, latest, row.faults, flags)
    return table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--db", metavar="F.sqlite|URL", default=None,
                        help="read a history file, or a postgresql:// database, instead of asking the historians")
    parser.add_argument("--json", action="store_true", help="one JSON object per switch, most urgent first")
    parser.add_argument("--timeout", type=options.bounded(float, 0.1, 600.0, "s"), default=10.0, metavar="S",
                        help="how long to wait for the historians")
    options.add_service_arguments(parser)


def run(args: argparse.Namespace) -> int:
    try:
        replies = from_db(args.db) if args.db else from_bus(options.bus_options(args), args.timeout)
    except (OSError, ValueError, BusError) as error:
        return options.fail(str(error))
    rows = fleet_rows(replies)
    if args.json:
        for row in rows:
            print(json.dumps(row.to_dict()))
        return 0
    if not rows:
        print("no switch in the history", file=sys.stderr)
        return 1
    Console(width=None if sys.stdout.isatty() else PIPE_WIDTH).print(fleet_table(rows))
    return 0
