"""`railswitch history SW`: a switch's diagnoses and health over time, from the historians on the bus (a Zenoh
get gathering every historian's reply) or from a history store (`--db F.sqlite`, or `--db postgresql://…`).

A table by default, one row per throw; `--json` prints the messages as JSON lines, oldest first. `--db F
--salvage G` copies what a damaged history file (SQLite) still holds into a fresh one.
"""
from __future__ import annotations

import argparse
import sys

from rich.console import Console

from railswitch.schemas import HISTORY_KINDS, MAX_LIMIT, HistoryQuery, HistoryReply, history_key
from railswitch.schemas.history import parse_time
from railswitch.services.adapters.history_db import salvage
from railswitch.services.adapters.history_store import is_url, open_history
from railswitch.services.adapters.history_bus import ask_historians
from railswitch.services.adapters.zenoh_bus import BusError, BusOptions, open_session
from railswitch.services.commands import options
from railswitch.services.core.tables import alarm_table, history_table, messages_in_order
from railswitch.services.core.historian import HistoryAnswers, merge_replies

DEFAULT_LIMIT = 100  # throws shown unless --limit says otherwise


class HistoryError(RuntimeError):
    """No history could be had (the historians refused or did not answer); the message is one line."""


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
