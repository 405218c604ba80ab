"""`railswitch notify --webhook URL`: every alarm change on the bus (railswitch/<id>/alarm) POSTed to a webhook as
the Alarm's JSON, each once, tried again with backoff while the receiver is down (services/core/notifier.py).

It subscribes with catch-up, as the historian does: the changes that alarm publishers kept while it was down come
when it starts. A bad URL or header stops it in one line before it joins the bus.
"""
from __future__ import annotations

import argparse
import logging
import threading

from railswitch.services.adapters.webhook import Webhook, check_header, check_url
from railswitch.services.adapters.zenoh_bus import (BusOptions, Inbox, Publishers, StatusReporter, declare_service,
                                                    open_session)
from railswitch.services.commands.options import add_service_arguments, bounded, from_check, run_service
from railswitch.services.core.intake import Intake
from railswitch.services.core.notifier import Notifier

log = logging.getLogger("railswitch.notify")


def run_notify(options: BusOptions, webhook: Webhook, *, stop: threading.Event, status_s: float = 5.0) -> int:
    """Forward alarm changes until stop; returns how many the webhook took."""
    session = open_session(options, stop=stop)
    try:
        inbox = Inbox(session, [], catch_up=("alarm",))
        intake = Intake(log, kinds=("alarm",))  # junk is counted and logged once per kind
        with Notifier(webhook.post) as notifier:
            token = declare_service(session, "notify")
            status = StatusReporter(Publishers(session), "notify", intake, status_s)
            log.info("forwarding alarm changes to the webhook at %s", webhook.where)
            for item in inbox.drain(stop):
                alarm = None if item is None else intake.message(item)
                if alarm is not None:
                    notifier.offer(alarm)
                status.maybe_publish(lambda: notifier.counters() | {"missed_samples": inbox.missed})
            status.maybe_publish(notifier.counters() | {"missed_samples": inbox.missed}, force=True)
            token.undeclare()
    finally:
        session.close()
    log.info("posted %d alarm change(s); %s", notifier.posted, notifier.counters())
    return notifier.posted


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser, status=True)
    parser.add_argument("--webhook", type=from_check(check_url), required=True, metavar="URL",
                        help="where each alarm change is POSTed as JSON (http:// or https://)")
    parser.add_argument("--header", type=from_check(check_header), action="append", default=[], metavar="'NAME: VALUE'",
                        help="an extra header of every POST, e.g. 'Authorization: Bearer TOKEN' (repeatable)")
    parser.add_argument("--timeout", type=bounded(float, 0.1, 300.0, "s"), default=10.0, metavar="S",
                        help="seconds an attempt may take before it counts as failed and is tried again")


def run(args: argparse.Namespace) -> int:
    webhook = Webhook(args.webhook, dict(args.header), args.timeout)
    return run_service(lambda options, stop: run_notify(options, webhook, stop=stop, status_s=args.status_interval),
                       args)
