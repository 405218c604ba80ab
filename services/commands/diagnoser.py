"""`railswitch diagnoser`: diagnoses every finished throw on the bus and publishes a Diagnosis.

Zenoh callbacks only queue payloads; one worker thread decodes, cuts throws per switch and runs the estimator.

Several diagnosers split a fleet between them. By default they are elastic: each finds the others by their
liveliness tokens and serves the switches that rendezvous hashing over the live set gives it, so one more started
takes its share and the switches of one that dies (and their throws in flight) go to the others within seconds,
each switch's state following it on the bus (docs/contracts.md, "Elastic shards"). A lone diagnoser serves every
switch, as before. `--shard K/N` instead keeps the switches whose stable hash falls in shard K for good, for fixed
deployments; the two do not share a bus (an elastic diagnoser counts every diagnoser as a member).
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import threading
import time

import zenoh

from railswitch.services.adapters.baseline_store import BaselineStore
from railswitch.services.adapters.zenoh_bus import (
    ELASTIC_LEASE_MS,
    BusOptions,
    Inbox,
    LiveSet,
    Publishers,
    QueryInbox,
    StatusReporter,
    declare_service,
    instance_name,
    open_session,
    query_all,
    recent_throws,
)
from railswitch.services.commands.options import add_model_argument, add_service_arguments, bounded, run_service, shard
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.live_diagnoser import LiveDiagnoser
from railswitch.services.core.membership import Membership
from railswitch.services.core.shards import FixedShard

log = logging.getLogger("railswitch.diagnoser")

STATE_QUERY_S = 5.0  # how long a starting diagnoser waits for the others' switch states
STATE_KEY = "railswitch/*/state"
INPUT_KEYS = ["railswitch/*/*"]
CATCH_UP = ("record",)  # throws a diagnoser that was down asks the publishers' caches for (docs/contracts.md)
KEPT_ALARM_CHANGES = 32  # each switch's latest alarm changes kept for notifiers and historians that were down
KEPT_THROWS = 4  # each switch's latest diagnoses and health kept for historians that were down: 10 minutes at 500 a day


class ElasticPeers:
    """The bus side of elastic shards: the live diagnosers, the states they hold when this one starts, and this
    one's answer when the next one starts."""

    def __init__(self, session: zenoh.Session, live: LiveDiagnoser, membership: Membership):
        self.live = live
        self.members = LiveSet(session, "diagnoser", membership)
        for item in query_all(session, STATE_KEY, STATE_QUERY_S):
            live.handle(item)
        self.queries = QueryInbox(session, STATE_KEY)

    def joined(self) -> None:
        """This one's token is on the bus: it serves the throws that start from now on."""
        self.members.joined()

    def poll(self) -> None:
        """Apply joins and leaves (rebalancing once if the live set changed) and answer waiting state queries."""
        if self.members.poll():
            self.live.rebalance()
        self.queries.answer(lambda key, parameters: self.live.state_replies())


def run_diagnoser(options: BusOptions, *, model: str, shard: tuple[int, int] | None, stop: threading.Event,
                  status_s: float = 5.0, state: str | None = None, kept_throws: int = KEPT_THROWS,
                  lean: bool = False) -> int:
    """Diagnose until stop is set (elastic without a shard); returns the number of diagnoses published."""
    session = open_session(dataclasses.replace(options, lease_ms=ELASTIC_LEASE_MS), stop=stop)
    try:
        publishers = Publishers(session, cached={"diagnosis": kept_throws, "health": kept_throws,
                                                 "alarm": KEPT_ALARM_CHANGES})
        # One subscription keeps samples and events in order. A fixed shard queues what arrives while its model
        # warms up; an elastic diagnoser subscribes once ready, since the live ones serve everything until it joins.
        inbox = Inbox(session, INPUT_KEYS, CATCH_UP) if shard is not None else None
        baselines = BaselineStore(model, state)
        diagnoser = Diagnoser(model, on_state=baselines.save, stored_state=baselines.load, lean=lean)
        started = time.monotonic()
        diagnoser.warm_up()
        inbox = inbox or Inbox(session, INPUT_KEYS, CATCH_UP)  # before the state query: no state falls in between
        ownership = Membership(instance_name()) if shard is None else FixedShard(shard, instance_name())
        live = LiveDiagnoser(diagnoser, publishers, ownership, known=baselines.known,
                             recover=lambda switch_id, after_ns: recent_throws(session, switch_id, after_ns))
        peers = ElasticPeers(session, live, ownership) if isinstance(ownership, Membership) else None
        log.info("model %s ready in %.1f s; %s; baselines in %s", model, time.monotonic() - started,
                 "shard %d/%d" % shard if shard else f"elastic, {len(ownership.members)} other diagnoser(s)",
                 baselines.folder)
        token = declare_service(session, "diagnoser")  # declared once ready: waiters know throws will be served
        if peers is not None:
            peers.joined()
        status = StatusReporter(publishers, "diagnoser", live.intake, status_s)
        live.catch_up()  # the sample streams' throws that ended while no diagnoser listened, from the recorders
        for item in inbox.drain(stop):
            if peers is not None:
                peers.poll()
            if item is not None:
                live.handle(item)
            live.expire()
            status.maybe_publish(lambda: {**live.counters(), "missed_samples": inbox.missed})
        status.maybe_publish({**live.counters(), "missed_samples": inbox.missed}, force=True)
        token.undeclare()
        log.info("published %d diagnoses; rejected %s", live.diagnosed, dict(live.intake.rejected) or "nothing")
        return live.diagnosed
    finally:
        session.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser, status=True)
    add_model_argument(parser)
    parser.add_argument("--shard", type=shard, default=None, metavar="K/N",
                        help="serve only switches in shard K of N (stable hash of the switch id), for good; default: "
                             "elastic, the live diagnosers split the fleet between them")
    parser.add_argument("--state", metavar="DIR", default=None,
                        help="where each switch's commissioned baseline is kept, so a restart resumes it "
                             "(default $RAILSWITCH_STATE, else ~/.local/state/railswitch/baselines)")
    parser.add_argument("--keep-throws", type=bounded(int, 1, 10_000), default=KEPT_THROWS, metavar="N",
                        help="each switch's latest N diagnoses and health messages kept for historians that were "
                             f"down or start late (default {KEPT_THROWS})")
    parser.add_argument("--lean", action="store_true",
                        help="keep about half as much per switch, for a little more time per throw: for a "
                             "diagnoser that serves many switches (docs/results.md, benchmarks.memory)")


def run(args: argparse.Namespace) -> int:
    return run_service(lambda options, stop: run_diagnoser(options, model=args.model, shard=args.shard, stop=stop,
                                                           status_s=args.status_interval, state=args.state,
                                                           kept_throws=args.keep_throws, lean=args.lean), args)
