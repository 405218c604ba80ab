"""`railswitch history SW`: a switch's diagnoses and health over time, from the historians on the bus (a Zenoh
get gathering every historian's reply) or from a history store (`--db F.sqlite`, or `--db postgresql://…`).

A table by default, one row per throw; `--json` prints the messages as JSON lines, oldest first. `--db F
--salvage G` copies what a damaged history file (SQLite) still holds into a fresh one.
"""
from __future__ import annotations

import argparse
import sys

import zenoh
from rich.console import Console
from rich.table import Table

from railswitch.schemas import (
    HISTORY_KINDS,
    MAX_LIMIT,
    Alarm,
    Diagnosis,
    HistoryQuery,
    HistoryReply,
    SwitchHealth,
    decode,
    history_key,
)
from railswitch.schemas.history import format_time, parse_time
from railswitch.services.adapters.history_db import salvage
from railswitch.services.adapters.history_store import is_url, open_history
from railswitch.services.adapters.zenoh_bus import BusError, BusOptions, open_session
from railswitch.services.commands import options
from railswitch.services.commands.watch import DECISION_STYLE, key_estimates, state_markup, to_limit
from railswitch.services.core.historian import HistoryAnswers, merge_replies

DEFAULT_LIMIT = 100  # throws shown unless --limit says otherwise


class HistoryError(RuntimeError):
    """No history could be had (the historians refused or did not answer); the message is one line."""


def ask_historians(session: zenoh.Session, key: str, query: HistoryQuery,
                   timeout_s: float) -> tuple[list[HistoryReply], list[str]]:
    """Every historian's replies to a query on key (consolidation off: every reply comes back), and the error
    replies' texts."""
    found, errors = [], []
    for reply in session.get(f"{key}?{query.parameters()}", target=zenoh.QueryTarget.ALL,
                             consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout_s):
        if reply.ok is not None:
            found.append(decode(HistoryReply, reply.ok.payload.to_bytes()))
        else:
            errors.append(reply.err.payload.to_string())
    return found, errors


def from_bus(bus: BusOptions, switch_id: str, query: HistoryQuery, timeout_s: float) -> HistoryReply:
    """Ask every historian and merge what they hold."""
    session = open_session(bus, wait_s=timeout_s)
    try:
        found, errors = ask_historians(session, history_key(switch_id), query, timeout_s)
    finally:
        session.close()
    if found:
        return merge_replies(found, query.limit)
    if errors:
        raise HistoryError(f"{history_key(switch_id)}: {errors[0]}")
    raise HistoryError(f"no historian answered for {history_key(switch_id)} within {timeout_s:g} s")


def from_file(path: str, switch_id: str, query: HistoryQuery) -> HistoryReply:
    """The same answer a historian would give, read from its file or database."""
    with open_history(path, create=False) as db:
        answer = HistoryAnswers(db, is_mine=lambda _: True, historian=db.name).answer_query(query, switch_id)
    if answer.error is not None:
        raise HistoryError(f"{db.name}: {answer.error}")
    return answer.decoded()[0]


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


def show(reply: HistoryReply, as_json: bool) -> None:
    if as_json:
        for message in messages_in_order(reply):
            print(message.model_dump_json())
        return
    console = Console()
    console.print(history_table(reply))
    if reply.alarms:
        console.print(alarm_table(reply))
    note = (f"{len(reply.diagnoses)} diagnoses, {len(reply.health)} health messages, {len(reply.alarms)} alarm changes "
            f"from {reply.historian}")
    if reply.truncated:
        note += "; older ones in the window were left out (--limit, --until)"
    console.print(note, highlight=False)


def time_argument(name: str):
    def convert(text: str) -> int:
        try:
            return parse_time(text, name)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
    return convert


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("switch", type=options.switch_id, nargs="?", metavar="SW", help="the switch id")
    parser.add_argument("--since", type=time_argument("since"), default=None, metavar="T",
                        help="from T: ISO-8601 (UTC unless it has an offset) or integer nanoseconds")
    parser.add_argument("--until", type=time_argument("until"), default=None, metavar="T", help="up to (before) T")
    parser.add_argument("--limit", type=options.bounded(int, 1, MAX_LIMIT), default=DEFAULT_LIMIT, metavar="N",
                        help=f"the latest N diagnoses, N health messages and N alarm changes (default {DEFAULT_LIMIT})")
    parser.add_argument("--kind", choices=HISTORY_KINDS, default=None, help="one kind of message only")
    parser.add_argument("--json", action="store_true", help="the messages as JSON lines, oldest first")
    parser.add_argument("--db", metavar="F.sqlite|URL", default=None,
                        help="read a history file, or a postgresql:// database, instead of the bus")
    parser.add_argument("--salvage", metavar="NEW.sqlite", default=None,
                        help="with --db: copy every row still readable in a damaged file into a new one")
    parser.add_argument("--timeout", type=options.bounded(float, 0.1, 600.0, "s"), default=10.0, metavar="S",
                        help="how long to wait for the historians")
    options.add_service_arguments(parser)


def run(args: argparse.Namespace) -> int:
    if args.salvage:
        return _salvage(args)
    if args.switch is None:
        return options.fail("give the switch id (railswitch history SW)")
    try:
        query = HistoryQuery.checked(since_ns=args.since, until_ns=args.until, limit=args.limit, kind=args.kind)
        reply = from_file(args.db, args.switch, query) if args.db else \
            from_bus(options.bus_options(args), args.switch, query, args.timeout)
    except (OSError, ValueError, BusError) as error:
        return options.fail(str(error))
    except HistoryError as error:
        print(f"railswitch: {error}", file=sys.stderr)
        return 1
    show(reply, args.json)
    return 0


def _salvage(args: argparse.Namespace) -> int:
    if not args.db:
        return options.fail("--salvage needs --db (the damaged file)")
    if is_url(args.db) or is_url(args.salvage):
        return options.fail("--salvage reads and writes SQLite files only (a PostgreSQL server keeps its own data "
                            "whole)")
    try:
        copied = salvage(args.db, args.salvage)
    except OSError as error:
        return options.fail(str(error))
    print(f"copied {copied} rows of {args.db} into {args.salvage}")
    return 0
