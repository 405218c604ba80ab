"""`railswitch historian --db F.sqlite|URL`: every diagnosis and health message of its switches into an SQLite
file or a PostgreSQL database, and the history of a switch to any Zenoh client that asks (a get on
railswitch/<id>/history).

Zenoh callbacks only queue; the main thread writes whatever is queued as one transaction, and a second
thread answers queries from its own connection to the store. Several historians split a fleet as diagnosers
do: by default elastic (each finds the others by their liveliness tokens and keeps the switches that rendezvous
hashing over the live set gives it, holding the others' rows for a while in case their owner dies), or `--shard
K/N` for good; historians sharing one PostgreSQL database write it at once, a row two of them write kept once. One
get with consolidation off gathers every historian's answer. A damaged file, or a database that cannot be reached,
stops the historian before it joins the bus, in one line.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import threading
import time
from collections.abc import Iterator
from pathlib import Path


from railswitch.schemas import HISTORY_KEYS, HISTORY_KINDS
from railswitch.services.adapters.history_bus import QueryServer
from railswitch.services.adapters.history_store import open_history
from railswitch.services.adapters.zenoh_bus import (
    ELASTIC_LEASE_MS,
    BusOptions,
    Inbox,
    LiveSet,
    Publishers,
    Received,
    StatusReporter,
    declare_service,
    instance_name,
    open_session,
)
from railswitch.services.commands.options import add_service_arguments, bounded, run_service, shard
from railswitch.services.core.historian import Historian, HistoryAnswers, Retention
from railswitch.services.core.membership import Membership
from railswitch.services.core.shards import FixedShard

log = logging.getLogger("railswitch.historian")

MAX_BATCH = 5000  # rows per transaction at most: a backlog is written in steps, queries are not held up long
POLL_S = 0.2


def batches(inbox: Inbox, stop: threading.Event) -> Iterator[list[Received]]:
    """Whatever is queued, as one batch: the first item waited for (an empty batch after POLL_S without one),
    the rest taken without waiting. After stop, what is still queued comes out before the iterator ends."""
    for item in inbox.drain(stop, POLL_S):
        batch = [] if item is None else [item]
        while batch and len(batch) < MAX_BATCH and (item := inbox.get(0.0)) is not None:
            batch.append(item)
        yield batch


def counters(historian: Historian, server: QueryServer, inbox: Inbox) -> dict[str, int]:
    return historian.counters() | server.answers.counters() | {"missed_samples": inbox.missed}


def run_historian(options: BusOptions, db_path: str | Path, *, shard: tuple[int, int] | None, stop: threading.Event,
                  keep_days: float | None = None, status_s: float = 5.0) -> int:
    """Keep history until stop is set (elastic without a shard); returns the rows written. The store (a file, or
    a postgresql:// URL) is checked before joining the bus."""
    with open_history(db_path) as db, open_history(db_path, check=False) as query_db:
        ownership = Membership(instance_name()) if shard is None else FixedShard(shard, instance_name())
        historian = Historian(db, ownership)
        retention = Retention(keep_days)
        session = open_session(dataclasses.replace(options, lease_ms=ELASTIC_LEASE_MS), stop=stop)
        try:
            # what the diagnosers kept of each switch's latest throws comes too, after an outage or a late start
            inbox = Inbox(session, [], catch_up=HISTORY_KINDS)
            members = LiveSet(session, "historian", ownership) if isinstance(ownership, Membership) else None
            with QueryServer(session, HistoryAnswers(query_db, ownership.is_mine, instance_name())) as server:
                token = declare_service(session, "historian")  # declared once queries are answered
                if members is not None:
                    members.joined()
                status = StatusReporter(Publishers(session), "historian", historian.intake, status_s)
                log.info("history in %s (%d rows); answering %s; %s", db.name, db.count(), HISTORY_KEYS,
                         "shard %d/%d" % shard if shard else f"elastic, {len(ownership.members) - 1} other "
                         "historian(s)")
                for batch in batches(inbox, stop):
                    if members is not None and members.poll():
                        historian.rebalance()
                    historian.write(batch)
                    if retention.due(time.monotonic()):
                        historian.prune(time.time_ns(), keep_days)
                    status.maybe_publish(lambda: counters(historian, server, inbox))
                status.maybe_publish(counters(historian, server, inbox), force=True)
                token.undeclare()
        finally:
            session.close()
        log.info("wrote %d rows; rejected %s", historian.written, dict(historian.intake.rejected) or "nothing")
        return historian.written


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser, status=True)
    parser.add_argument("--db", required=True, metavar="F.sqlite|URL",
                        help="the history file (created if missing; a restarted historian goes on with it), or a "
                             "postgresql://user@host:port/db URL: a database several historians share")
    parser.add_argument("--shard", type=shard, default=None, metavar="K/N",
                        help="keep only switches in shard K of N (stable hash of the switch id, as the diagnoser's), "
                             "for good; default: elastic, the live historians split the fleet between them")
    parser.add_argument("--keep-days", type=bounded(float, 0.01, 36_500.0, "days"), default=None, metavar="D",
                        help="delete rows older than D days (by each message's time), at start-up and hourly")


def run(args: argparse.Namespace) -> int:
    return run_service(lambda options, stop: run_historian(
        options, args.db, shard=args.shard, stop=stop, keep_days=args.keep_days, status_s=args.status_interval),
        args)
