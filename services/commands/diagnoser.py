"""`railswitch diagnoser`: diagnoses every finished throw on the bus and publishes a Diagnosis.

Zenoh callbacks only queue payloads; one worker thread decodes, cuts throws per switch
and runs the estimator. `--shard K/N` keeps the switches whose stable hash falls in
shard K, so several diagnoser processes split a fleet between them.
"""
from __future__ import annotations

import argparse
import logging
import threading
import time

from railswitch.services.adapters.baseline_store import BaselineStore
from railswitch.services.adapters.zenoh_bus import BusOptions, Inbox, Publishers, StatusReporter, declare_service, open_session
from railswitch.services.commands.options import add_model_argument, add_service_arguments, run_service
from railswitch.services.core.fleet_diagnoser import Diagnoser
from railswitch.services.core.live_diagnoser import LiveDiagnoser
from railswitch.services.core.shards import parse_shard

log = logging.getLogger("railswitch.diagnoser")


def run_diagnoser(options: BusOptions, *, model: str, shard: tuple[int, int], stop: threading.Event,
                  status_s: float = 5.0, state: str | None = None) -> int:
    """Diagnose until stop is set; returns the number of diagnoses published."""
    session = open_session(options, stop=stop)
    try:
        publishers = Publishers(session)
        inbox = Inbox(session, ["railswitch/*/*"])  # one subscription keeps samples and events in order
        baselines = BaselineStore(model, state)
        diagnoser = Diagnoser(model, on_state=baselines.save, stored_state=baselines.load)
        started = time.monotonic()
        diagnoser.warm_up()
        log.info("model %s ready in %.1f s; shard %d/%d; baselines in %s", model, time.monotonic() - started, *shard,
                 baselines.folder)
        live = LiveDiagnoser(diagnoser, publishers, shard, known=baselines.known)
        token = declare_service(session, "diagnoser")  # declared once ready: waiters know throws will be served
        status = StatusReporter(publishers, "diagnoser", live.intake, status_s)
        for item in inbox.drain(stop):
            if item is not None:
                live.handle(item)
            status.maybe_publish(live.counters())
        status.maybe_publish(live.counters(), force=True)
        token.undeclare()
        log.info("published %d diagnoses; rejected %s", live.diagnosed, dict(live.intake.rejected) or "nothing")
        return live.diagnosed
    finally:
        session.close()


def shard(text: str) -> tuple[int, int]:
    try:
        return parse_shard(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser, status=True)
    add_model_argument(parser)
    parser.add_argument("--shard", type=shard, default=(1, 1), metavar="K/N",
                        help="serve only switches in shard K of N (stable hash of the switch id)")
    parser.add_argument("--state", metavar="DIR", default=None,
                        help="where each switch's commissioned baseline is kept, so a restart resumes it "
                             "(default $RAILSWITCH_STATE, else ~/.local/state/railswitch/baselines)")


def run(args: argparse.Namespace) -> int:
    return run_service(lambda options, stop: run_diagnoser(options, model=args.model, shard=args.shard, stop=stop,
                                                           status_s=args.status_interval, state=args.state), args)
