"""The `railswitch` command line (docs/contracts.md section 5): one module per command in this folder.

Each command module has `add_arguments(parser)` and `run(args) -> exit code`. Only the module of the
command asked for is imported, so a typo or `--help` answers at once. The long-running services are
`railswitch serve NAME`; their own names (`railswitch diagnoser`, ...) stay as aliases, since deployments and
scripts use them.
"""
from __future__ import annotations

import importlib
import signal
import sys
from collections.abc import Iterable

from railswitch.services.commands.options import Parser

COMMANDS: dict[str, str] = {  # name (and module) -> help
    "simulate": "run the high-fidelity plant offline and write an MCAP recording",
    "describe": "model statistics (states, parameters, rail nodes)",
    "train": "regenerate the reduced rail models from high-fidelity plant data",
    "calibrate": "calibrate the reduced models' bearing-fault port on plant throws",
    "report": "PNG pictures of the throws in one or more recordings, or of each switch's health from a history store "
              "(an SQLite file or a PostgreSQL database)",
    "diagnose": "diagnose every throw of a recording offline",
    "recover": "copy what can be read from a damaged recording into a complete one",
    "router": "a Zenoh router (eclipse-zenoh in router mode) listening on --listen (default tcp/127.0.0.1:7447)",
    "simulator": "simulated switches publishing motor samples, throws and truth",
    "diagnoser": "diagnose every finished throw on the bus",
    "recorder": "record railswitch/** to an MCAP file",
    "replay": "republish a recording's motor, throw and truth messages",
    "watch": "live table of diagnoses and health",
    "commission": "restart a switch's commissioning after maintenance (its baseline is learnt again), or --accept it as it is",
    "ack": "acknowledge a switch's alarms (all, or --alarm ID), with an optional --note",
    "maintenance": "--start or --end a switch's maintenance: its throws raise no alarm and teach nothing meanwhile",
    "fleet": "every switch by urgency: latched alarms first, then the fewest throws to a limit (bus or --db)",
    "historian": "keep every diagnosis and health message in an SQLite file or a PostgreSQL database and answer "
                 "history queries",
    "history": "a switch's diagnoses and health over time, from the historians on the bus or a history store (an "
               "SQLite file or a PostgreSQL database)",
    "notify": "forward alarm changes to a webhook (JSON over HTTP POST, with retry)",
    "demo": "router, simulator, diagnoser, recorder and historian with a live table and summary",
}
SERVE = "serve"
SERVICES = ("router", "simulator", "diagnoser", "recorder", "historian", "notify")  # what `serve` runs
SERVE_HELP = "run a long-running service: " + ", ".join(SERVICES)


def build_parser(commands: Iterable[str] | None = None) -> Parser:
    """The parser; the arguments of `commands` only (default: every command's). A service's arguments are given
    to `serve NAME` and to its alias alike."""
    chosen = set(COMMANDS if commands is None else commands)
    parser = Parser(prog="railswitch", description="Online diagnosis of railway switches.")
    subparsers = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    serve = subparsers.add_parser(SERVE, help=SERVE_HELP, description=SERVE_HELP)
    services = serve.add_subparsers(dest="service", required=True, parser_class=Parser, metavar="SERVICE")
    for name in SERVICES:
        described(services.add_parser(name, help=COMMANDS[name]), name, name in chosen)
    for name, help_text in COMMANDS.items():
        alias = f" (the same as `railswitch serve {name}`)" if name in SERVICES else ""
        described(subparsers.add_parser(name, help=help_text + alias), name, name in chosen)
    return parser


def described(sub: Parser, name: str, chosen: bool) -> None:
    """A command's arguments and handler on its parser, when it is the one asked for."""
    if chosen:
        module = importlib.import_module(f"railswitch.services.commands.{name}")
        module.add_arguments(sub)
        sub.set_defaults(handler=module.run)


def named_command(argv: list[str]) -> list[str]:
    """The command `argv` asks for, as a list of at most one name: the first word that names one, or after
    `serve` the first that names a service."""
    words = [word for word in argv if word in COMMANDS or word == SERVE]
    if words[:1] == [SERVE]:
        return [word for word in argv[argv.index(SERVE) + 1:] if word in SERVICES][:1]
    return words[:1]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    named = named_command(argv)
    # Threads that importing a command starts (a BLAS pool) keep the signal mask they start with: blocked, they never
    # take a live service's stop signal from the thread that waits for it (zenoh_bus.wait_for_stop_signals).
    unblocked = signal.pthread_sigmask(signal.SIG_BLOCK, (signal.SIGINT, signal.SIGTERM))
    try:
        try:
            args = build_parser(named).parse_args(argv)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, unblocked)  # a signal taken meanwhile arrives here
        return args.handler(args)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `railswitch diagnose F --jsonl | head`: the reader left, nothing is wrong
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
