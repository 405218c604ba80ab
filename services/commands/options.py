"""What the commands share: converters that name a bad value and its accepted range, the bus options of
every live service, and the run loop of a service (logging, signals, one-line errors).

Every bad value ends in one line on stderr that names it and the accepted range, and exit code 2
(docs/contracts.md section 5).
"""
from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable

from pydantic import TypeAdapter, ValidationError

from railswitch.schemas import DEFAULT_ENDPOINT, RAIL_MODELS, check_fault_value, check_plant_value, check_switch_id

MODES = ("client", "peer", "router")  # Zenoh's session modes


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are a single line (no usage dump)."""

    def error(self, message: str):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message}\n")


def fail(message: str) -> int:
    print(f"railswitch: error: {message}", file=sys.stderr)
    return 2


def bounded(kind: type, low: float, high: float, unit: str = "") -> Callable[[str], float]:
    """Converter for a number in [low, high]; the error names the value and the range."""
    def convert(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{text} is outside the accepted range {low:g} … {high:g}{' ' + unit if unit else ''}")
        return value
    return convert


def fault_assignment(text: str) -> tuple[str, float]:
    """NAME=VALUE with NAME a fault parameter (docs/contracts.md section 2) and VALUE in its range."""
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=VALUE")
    try:
        return name, check_fault_value(name.strip(), value.strip())
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def plant_assignment(text: str) -> tuple[str, float]:
    """NAME=VALUE with NAME one of a switch's own parameters (group.field, schemas/plant.py) and VALUE in its range."""
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=VALUE")
    try:
        return name.strip(), check_plant_value(name.strip(), value.strip())
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_own_arguments(parser: argparse.ArgumentParser) -> None:
    """A switch's own build and weather: --plant NAME=VALUE and --vary SEED."""
    parser.add_argument("--plant", type=plant_assignment, action="append", default=[], metavar="NAME=VALUE",
                        help="a switch's own parameter, e.g. motor.supply_v=99 (repeatable; `railswitch describe` "
                             "lists them)")
    parser.add_argument("--vary", type=bounded(int, 0, 2**32 - 1), default=None, metavar="SEED",
                        help="draw each switch from the population of real switches (switch k: SEED + k)")
    parser.add_argument("--stroke", type=bounded(float, 2.0, 14.0, "s"), default=None, metavar="S",
                        help="the point machines' stroke time (default 6.4 s; other machine types are faster or slower)")
    parser.add_argument("--throw-length", type=bounded(float, 1.0, 30.0, "s"), default=None, metavar="S",
                        help="when each throw's end event comes (default: the stroke time + 0.6 s, where its "
                             "reference profile ends)")


def scenario_from_args(args: argparse.Namespace, default_throws: int = 1_000_000):
    """The --scenario file, or a scenario built from the simple options (`--vary S` draws switch k with seed S + k)."""
    from railswitch.schemas.scenario import STROKE_S, Scenario, ScenarioError, SwitchPlan, load_scenario

    simple = {"switches": getattr(args, "switches", None), "switch_id": args.switch_id or None, "throws": args.throws,
              "interval": getattr(args, "interval", None), "fault": args.fault or None, "noise": args.noise,
              "rate": args.rate, "plant": args.plant or None, "vary": args.vary, "stroke": args.stroke,
              "throw_length": args.throw_length}
    if args.scenario:
        given = [f"--{name.replace('_', '-')}" for name, value in simple.items() if value is not None]
        if given:
            raise ScenarioError(f"--scenario excludes {', '.join(given)} (the file says it)")
        return load_scenario(args.scenario)
    switches = getattr(args, "switches", None)
    if args.switch_id and switches is not None:
        raise ScenarioError("give --switches N or --switch-id ID (repeatable), not both")
    ids = args.switch_id or [f"sw{k + 1}" for k in range(switches or 1)]
    if len(set(ids)) != len(ids):
        raise ScenarioError(f"--switch-id repeats: {ids}")
    plans = [SwitchPlan(id=i, throws=args.throws or default_throws, faults=dict(args.fault), plant=dict(args.plant),
                        vary=None if args.vary is None else args.vary + k) for k, i in enumerate(ids)]
    return Scenario(interval_s=getattr(args, "interval", None) or 10.0, rate_hz=args.rate or 50.0,
                    noise=args.noise or 0.0, seed=args.seed, switches=plans, stroke_s=args.stroke or STROKE_S,
                    throw_s=args.throw_length)


def checked(annotated, accepted: str) -> Callable[[str], str]:
    """Converter for a string a schema's annotated type checks; the error names the value and what is accepted."""
    adapter = TypeAdapter(annotated)

    def convert(text: str) -> str:
        try:
            return adapter.validate_python(text)
        except ValidationError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {accepted}") from None
    return convert


def note(text: str) -> str:
    """A note or reason kept with a command: at most 500 characters."""
    if len(text) > 500:
        raise argparse.ArgumentTypeError(f"a note of {len(text)} characters is over the accepted 500")
    return text


def from_check(check: Callable[[str], object]) -> Callable[[str], object]:
    """An argparse converter from a check that raises ValueError with the one line to show."""
    def convert(text: str):
        try:
            return check(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
    return convert


def switch_id(text: str) -> str:
    return from_check(check_switch_id)(text)


def shard(text: str) -> tuple[int, int]:
    """--shard K/N: shard K of N of a fleet (services/core/shards.py)."""
    from railswitch.services.core.shards import parse_shard

    try:
        return parse_shard(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_model_argument(parser: argparse.ArgumentParser, *extra: str, default: str = "poly", help_text: str = "") -> None:
    """--model: one of the reduced rail models (and `extra` choices such as all or none)."""
    parser.add_argument("--model", choices=[*RAIL_MODELS, *extra], default=default,
                        help=help_text or "reduced rail model")


def models_named(choice: str) -> list[str]:
    """The reduced models a --model choice names ("all": every one)."""
    return list(RAIL_MODELS) if choice == "all" else [choice]


# -- live services ---------------------------------------------------------------------------
def add_service_arguments(parser: argparse.ArgumentParser, *, status: bool = False) -> None:
    """The session options every live service takes, -v, and (for those that report) --status-interval."""
    group = parser.add_argument_group("bus")
    group.add_argument("--mode", choices=MODES, default=None, help="Zenoh mode (default: client, or the config file's)")
    group.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                       help=f"endpoint to connect to, e.g. tcp/host:7447 (repeatable; default {DEFAULT_ENDPOINT})")
    group.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                       help="endpoint to listen on (repeatable)")
    group.add_argument("--zenoh-config", metavar="FILE", default=None,
                       help="Zenoh JSON5 config file for TLS, authentication, access control (or $ZENOH_CONFIG)")
    group.add_argument("--multicast-scouting", action="store_true", help="discover peers by multicast (off by default)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    if status:
        parser.add_argument("--status-interval", type=bounded(float, 0.1, 3600.0, "s"), default=5.0, metavar="S",
                            help="seconds between status messages on railswitch/@service/<name>/<instance>/status")


def bus_options(args: argparse.Namespace):
    """The BusOptions the arguments of add_service_arguments ask for."""
    from railswitch.services.adapters.zenoh_bus import BusOptions

    return BusOptions(mode=args.mode, connect=tuple(args.connect), listen=tuple(args.listen),
                      config_file=args.zenoh_config or os.environ.get("ZENOH_CONFIG") or None,
                      multicast_scouting=args.multicast_scouting)


def run_service(run: Callable, args: argparse.Namespace) -> int:
    """Run a live service `run(options, stop)` with logging, SIGINT/SIGTERM handling and one-line errors."""
    from railswitch.services.adapters.zenoh_bus import BusError, configure_logging, wait_for_stop_signals

    configure_logging(args.verbose)
    try:
        options = bus_options(args)
        with wait_for_stop_signals() as stop:
            run(options, stop)
    except (BusError, OSError, ValueError) as error:
        return fail(str(error))
    return 0
