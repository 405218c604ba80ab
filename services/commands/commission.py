"""`railswitch commission SW`: restart a switch's commissioning after maintenance, or (`--accept`) take the
switch as it now is as its own.

Publishes a CommissionCommand on railswitch/<SW>/commission; the diagnoser serving the switch forgets
its baseline and learns it again from the next healthy throws, or with `--accept` makes its present faults
(a standing condition it was installed with) part of its baseline (docs/contracts.md section 6). A switch it
does not know is refused and counted in its status.
"""
from __future__ import annotations

import argparse
import threading
import time

from railswitch.schemas import CHANNEL_MODELS, CommissionCommand, Message, key_expr
from railswitch.services.adapters.zenoh_bus import BusOptions, Publishers, open_session
from railswitch.services.commands.options import add_service_arguments, run_service, switch_id

SETTLE_S = 0.5  # lets the publication leave before the session closes


def send_commands(options: BusOptions, commands: list[Message], stop: threading.Event) -> int:
    """Publish each command on its switch's channel of its kind (railswitch/<SW>/commission, ack, maintenance)."""
    kinds = {type_: kind for kind, type_ in CHANNEL_MODELS.items()}
    session = open_session(options, stop=stop, wait_s=30.0)
    try:
        publishers = Publishers(session)
        time.sleep(SETTLE_S)  # subscribers' routes are in place
        for command in commands:
            publishers.put(key_expr(command.switch_id, kinds[type(command)]), command)
        time.sleep(SETTLE_S)
        return publishers.published
    finally:
        session.close()


def send_commission(options: BusOptions, switches: list[str], reason: str | None, stop: threading.Event,
                    accept: bool = False) -> int:
    return send_commands(options, [CommissionCommand(switch_id=s, reason=reason, accept=accept) for s in switches],
                         stop)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser)
    parser.add_argument("switch_id", type=switch_id, nargs="+", metavar="SW", help="the switch (or switches)")
    parser.add_argument("--reason", default=None, help="why, for the diagnoser's log (e.g. 'bolts reset')")
    parser.add_argument("--accept", action="store_true",
                        help="take the switch as it now is as its own: its present faults (a condition it was installed "
                             "with) become its baseline, and faults are judged from there")


def run(args: argparse.Namespace) -> int:
    return run_service(lambda options, stop: send_commission(options, args.switch_id, args.reason, stop, args.accept),
                       args)
