"""`railswitch maintenance SW --start|--end [--recommission]`: a team is working on the switch.

Publishes a MaintenanceCommand on railswitch/<SW>/maintenance. Meanwhile the diagnoser serving the switch diagnoses
and publishes its throws tagged `maintenance`: they raise no alarm and teach no baseline, trend or fault. At the end
the switch resumes from where it was, or with --recommission learns its baseline again from its next healthy throws.
"""
from __future__ import annotations

import argparse
import sys

from railswitch.schemas import MaintenanceCommand
from railswitch.services.commands.commission import send_commands
from railswitch.services.commands.options import add_service_arguments, note, run_service, switch_id


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser)
    parser.add_argument("switch_id", type=switch_id, nargs="+", metavar="SW", help="the switch (or switches)")
    action = parser.add_mutually_exclusive_group(required=True)
    action.add_argument("--start", dest="action", action="store_const", const="start", help="maintenance begins")
    action.add_argument("--end", dest="action", action="store_const", const="end", help="maintenance is over")
    parser.add_argument("--recommission", action="store_true",
                        help="with --end: learn the switch's baseline again (parts were changed or adjusted)")
    parser.add_argument("--note", type=note, default=None, help="what is being done, for the diagnoser's log")


def run(args: argparse.Namespace) -> int:
    if args.recommission and args.action != "end":
        print("railswitch maintenance: error: --recommission goes with --end", file=sys.stderr)
        return 2
    commands = [MaintenanceCommand(switch_id=s, action=args.action, recommission=args.recommission, note=args.note)
                for s in args.switch_id]
    return run_service(lambda options, stop: send_commands(options, commands, stop), args)
