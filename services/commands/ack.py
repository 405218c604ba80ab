"""`railswitch ack SW`: acknowledge a switch's alarms, all of them or `--alarm ID`, with an optional note.

Publishes an AckCommand on railswitch/<SW>/ack; the diagnoser serving the switch marks its latched alarms
acknowledged (a cleared one is closed) and publishes each change on railswitch/<SW>/alarm. An acknowledgement for a
switch it does not know, or with nothing to acknowledge, changes nothing and is counted in its status.
"""
from __future__ import annotations

import argparse

from railswitch.schemas import AckCommand
from railswitch.schemas.messages import AlarmId
from railswitch.services.commands.commission import send_commands
from railswitch.services.commands.options import add_service_arguments, checked, note, run_service, switch_id


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser)
    parser.add_argument("switch_id", type=switch_id, nargs="+", metavar="SW", help="the switch (or switches)")
    parser.add_argument("--alarm", type=checked(AlarmId, "an alarm id such as left_bolt or anomaly:motor.resistance_ohm"),
                        default=None, metavar="ID", help="only this alarm (default: every unacknowledged one)")
    parser.add_argument("--note", type=note, default=None, help="what was done or seen, kept with the alarm")


def run(args: argparse.Namespace) -> int:
    commands = [AckCommand(switch_id=s, alarm=args.alarm, note=args.note) for s in args.switch_id]
    return run_service(lambda options, stop: send_commands(options, commands, stop), args)
