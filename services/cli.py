"""The `railswitch` command line (DESIGN.md section 6).

Every bad value ends in one line on stderr that names it and the accepted
range, and exit code 2; no traceback.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
from collections.abc import Callable

from schemas import check_fault_value, check_switch_id


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are a single line (no usage dump)."""

    def error(self, message: str):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message}\n")


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
    """NAME=VALUE with NAME a fault parameter of DESIGN.md section 3 and VALUE in its range."""
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=VALUE")
    try:
        return name, check_fault_value(name.strip(), value.strip())
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def switch_id(text: str) -> str:
    try:
        return check_switch_id(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _fail(message: str) -> int:
    print(f"railswitch: error: {message}", file=sys.stderr)
    return 2


# -- commands -------------------------------------------------------------------------------
def cmd_simulate(args) -> int:
    from rich.progress import Progress

    from services.mcap_io import RecordingPathError
    from services.simulate import simulate_to_mcap

    faults = dict(args.fault)
    try:
        with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
            task = progress.add_task("simulating throws", total=args.throws)
            summary = simulate_to_mcap(args.out, switch_id=args.switch_id, throws=args.throws, faults=faults,
                                       noise_rel=args.noise, seed=args.seed, rate_hz=args.rate,
                                       progress=lambda: progress.advance(task))
    except RecordingPathError as error:
        return _fail(str(error))
    print(f"wrote {summary.path} ({summary.throws} throws, {summary.messages} messages, {summary.bytes} bytes)")
    return 0


def cmd_describe(args) -> int:
    from models.plant import Plant
    from services.reduced_models import describe_reduced

    description = {"plant": Plant().describe(), "reduced": describe_reduced()}
    if args.json:
        print(json.dumps(description, indent=2, default=float))
    else:
        print("plant")
        for key, value in description["plant"].items():
            print(f"  {key:24s} {value}")
        for name, stats in description["reduced"].items():
            print(f"reduced {name}")
            for key, value in stats.items():
                print(f"  {key:24s} {value}")
    return 0


def _models(choice: str) -> list[str]:
    """The reduced models a --model choice names ("all": every one)."""
    from services.diagnosis import MODELS

    return list(MODELS) if choice == "all" else [choice]


def cmd_train(args) -> int:
    from services.reduced_models import train_and_save

    names = _models(args.model)
    try:
        for name in names:
            path, seconds = train_and_save(name, seed=args.seed, iterations=args.iterations, out_dir=args.out)
            print(f"trained {name} in {seconds:.1f} s: {path} (then `railswitch calibrate --model {name}`)")
    except OSError as error:
        return _fail(f"cannot write the parameters: {error}")
    return 0


def cmd_calibrate(args) -> int:
    from models.reference import DIRECTIONS
    from services.reduced_models import calibrate_and_save

    names = _models(args.model)
    try:
        for name in names:
            path, port = calibrate_and_save(name)
            ports = ", ".join(f"{d.replace('_', ' ')}: gain {port[d]['gain']:.4f}, offset {port[d]['offset_s_m']:.1f} N·s/m"
                              for d in DIRECTIONS)
            print(f"{name}: bearing port {ports} -> {path}")
    except OSError as error:
        return _fail(f"cannot write the calibration: {error}")
    return 0


def cmd_report(args) -> int:
    from services.report import write_report

    try:
        written = write_report(args.recordings, args.out, None if args.model == "none" else args.model)
    except (OSError, ValueError) as error:
        return _fail(str(error))
    for path in written:
        print(path)
    return 0


def cmd_recover(args) -> int:
    from pathlib import Path

    from services.mcap_io import recover_recording

    if Path(args.output).resolve() == Path(args.recording).resolve():
        return _fail("the recovered file must not replace the damaged one")
    try:
        recording = recover_recording(args.recording, args.output)
    except OSError as error:
        return _fail(str(error) if error.strerror is None else f"cannot recover {args.recording}: {error.strerror}")
    note = recording.note() or "the file was intact"
    if not recording.records:
        print(f"railswitch recover: {args.recording}: {note}; nothing to recover", file=sys.stderr)
        return 1
    times = [record.log_time_ns for record in recording.records]
    print(f"recovered {len(recording.records)} messages spanning {(max(times) - min(times)) * 1e-9:.1f} s "
          f"into {args.output}: {note}")
    return 0


def cmd_diagnose(args) -> int:
    from services.diagnose import diagnose_file

    return diagnose_file(args.recording, model=args.model, jsonl=args.jsonl)


# -- live services (DESIGN.md section 4) ----------------------------------------------------
def _live(run: Callable[[object, threading.Event], int | None], args) -> int:
    """Run a service with logging, SIGINT/SIGTERM handling and one-line errors."""
    from services.bus import BusError, BusOptions, configure_logging, stop_on_signals

    configure_logging(args.verbose)
    try:
        options = BusOptions.from_args(args)
        with stop_on_signals() as stop:
            run(options, stop)
    except (BusError, OSError, ValueError) as error:
        return _fail(str(error))
    return 0


def cmd_router(args) -> int:
    from dataclasses import replace

    from services.bus import DEFAULT_ENDPOINT
    from services.router import run_router

    def run(options, stop):
        if not options.listen and not options.config_file:
            options = replace(options, listen=(DEFAULT_ENDPOINT,))
        run_router(replace(options, mode="router"), stop=stop)
    return _live(run, args)


def _scenario_from_args(args):
    """The --scenario file, or a scenario built from the simple options."""
    from schemas.scenario import Scenario, ScenarioError, SwitchPlan, load_scenario

    simple = {"switches": args.switches, "switch_id": args.switch_id or None, "throws": args.throws,
              "interval": args.interval, "fault": args.fault or None, "noise": args.noise, "rate": args.rate}
    if args.scenario:
        given = [f"--{name.replace('_', '-')}" for name, value in simple.items() if value is not None]
        if given:
            raise ScenarioError(f"--scenario excludes {', '.join(given)} (the file says it)")
        return load_scenario(args.scenario)
    if args.switch_id and args.switches is not None:
        raise ScenarioError("give --switches N or --switch-id ID (repeatable), not both")
    ids = args.switch_id or [f"sw{k + 1}" for k in range(args.switches or 1)]
    if len(set(ids)) != len(ids):
        raise ScenarioError(f"--switch-id repeats: {ids}")
    plans = [SwitchPlan(id=i, throws=args.throws or 1_000_000, faults=dict(args.fault)) for i in ids]
    return Scenario(interval_s=args.interval or 10.0, rate_hz=args.rate or 50.0, noise=args.noise or 0.0,
                    seed=args.seed, switches=plans)


def cmd_simulator(args) -> int:
    from models.switch import ReplayedSwitch
    from services.mcap_io import load_recording
    from services.simulator import recorded_throws, run_simulator

    library = None
    if args.throws_from:
        try:
            library = recorded_throws(load_recording(args.throws_from).messages)
            ReplayedSwitch(library)  # its own check (a complete throw each way), before connecting
        except OSError as error:
            return _fail(f"cannot read {args.throws_from}: {error.strerror}")
        except ValueError as error:
            return _fail(f"{args.throws_from}: {error}")
    return _live(lambda options, stop: run_simulator(options, _scenario_from_args(args), speed=args.speed,
                                                     stop=stop, library=library, status_s=args.status_interval), args)


def cmd_diagnoser(args) -> int:
    from services.diagnoser import run_diagnoser

    return _live(lambda options, stop: run_diagnoser(options, model=args.model, shard=args.shard, stop=stop,
                                                     status_s=args.status_interval), args)


def cmd_recorder(args) -> int:
    from services.recorder import run_recorder

    return _live(lambda options, stop: run_recorder(options, args.out, stop=stop, status_s=args.status_interval),
                 args)


def cmd_replay(args) -> int:
    from services.mcap_io import load_recording
    from services.replay import PLANT_KINDS, ReplayPlan, run_replay

    try:
        recording = load_recording(args.recording)
    except OSError as error:
        return _fail(f"cannot read {args.recording}: {error.strerror}")
    kinds = PLANT_KINDS + (("diagnosis",) if args.with_diagnosis else ())
    plan = ReplayPlan.of(recording.records, kinds)
    note = recording.note()
    if not plan.records:
        print(f"railswitch replay: {args.recording}: {note + '; ' if note else ''}nothing to replay", file=sys.stderr)
        return 1
    if note:
        print(f"railswitch replay: {args.recording}: {note}", file=sys.stderr)
    speed = None if args.fast else args.speed
    return _live(lambda options, stop: run_replay(options, plan, speed=speed, loops=args.loop, stop=stop), args)


def cmd_watch(args) -> int:
    from services.watch import run_watch

    return _live(lambda options, stop: run_watch(options, switch_ids=args.switch_id, count=args.count,
                                                 duration_s=args.duration, jsonl=args.jsonl, stop=stop), args)


def cmd_demo(args) -> int:
    from services.demo import run_demo

    return run_demo(args)


def shard(text: str) -> tuple[int, int]:
    from services.diagnoser import parse_shard

    try:
        return parse_shard(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _service(commands, name: str, help_text: str, handler, *, default_mode: str | None = None, status: bool = False):
    from services.bus import add_bus_arguments

    parser = commands.add_parser(name, help=help_text)
    add_bus_arguments(parser, default_mode=default_mode)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    if status:
        parser.add_argument("--status-interval", type=bounded(float, 0.1, 3600.0, "s"), default=5.0, metavar="S",
                            help="seconds between status messages on railswitch/service/<name>/<instance>/status")
    parser.set_defaults(handler=handler)
    return parser


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="railswitch", description="Online diagnosis of railway switches.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    sim = commands.add_parser("simulate", help="run the high-fidelity plant offline and write an MCAP recording")
    sim.add_argument("--out", required=True, help="MCAP file to write")
    sim.add_argument("--switch-id", type=switch_id, default="sw1")
    sim.add_argument("--throws", type=bounded(int, 1, 10_000), default=2, help="alternating, left to right first")
    sim.add_argument("--fault", type=fault_assignment, action="append", default=[], metavar="NAME=VALUE",
                     help="inject a fault, e.g. left_bolt_offset=0.05 (repeatable)")
    sim.add_argument("--noise", type=bounded(float, 0.0, 0.5), default=0.0, metavar="REL",
                     help="Gaussian noise, std = REL x the signal's nominal peak")
    sim.add_argument("--seed", type=bounded(int, 0, 2**32 - 1), default=0)
    sim.add_argument("--rate", type=bounded(float, 1.0, 1000.0, "samples/s"), default=50.0, help="samples per second")
    sim.set_defaults(handler=cmd_simulate)

    describe = commands.add_parser("describe", help="model statistics (states, parameters, rail nodes)")
    describe.add_argument("--json", action="store_true")
    describe.set_defaults(handler=cmd_describe)

    train = commands.add_parser("train", help="regenerate the reduced rail models from high-fidelity plant data")
    train.add_argument("--model", choices=["poly", "nn", "causal", "all"], default="all")
    train.add_argument("--seed", type=bounded(int, 0, 2**32 - 1), default=0)
    train.add_argument("--iterations", type=bounded(int, 1, 1000), default=40,
                       help="Levenberg-Marquardt iterations per fitting stage")
    train.add_argument("--out", default=None, metavar="DIR", help="where to write <model>.json (default: the shipped models/params)")
    train.set_defaults(handler=cmd_train)

    calibrate = commands.add_parser("calibrate", help="calibrate the shipped models' bearing-fault port on plant throws")
    calibrate.add_argument("--model", choices=["poly", "nn", "causal", "all"], default="all")
    calibrate.set_defaults(handler=cmd_calibrate)

    report = commands.add_parser("report", help="PNG pictures of the throws in one or more recordings")
    report.add_argument("recordings", nargs="+", metavar="F.mcap")
    report.add_argument("--out", required=True, metavar="DIR")
    report.add_argument("--model", choices=["poly", "nn", "causal", "none"], default="poly",
                        help="reduced model whose fits and estimates are drawn (one recording); none: data only")
    report.set_defaults(handler=cmd_report)

    diagnose = commands.add_parser("diagnose", help="diagnose every throw of a recording offline")
    diagnose.add_argument("recording", metavar="F.mcap")
    diagnose.add_argument("--model", choices=["poly", "nn", "causal"], default="poly", help="reduced rail model")
    diagnose.add_argument("--jsonl", action="store_true", help="one Diagnosis JSON object per throw on stdout")
    diagnose.set_defaults(handler=cmd_diagnose)

    recover = commands.add_parser("recover", help="copy what can be read from a damaged recording into a complete one")
    recover.add_argument("recording", metavar="F.mcap")
    recover.add_argument("-o", "--output", required=True, metavar="G.mcap")
    recover.set_defaults(handler=cmd_recover)

    _service(commands, "router", "a Zenoh router (eclipse-zenoh in router mode) listening on --listen "
             "(default tcp/127.0.0.1:7447)", cmd_router)

    simulator = _service(commands, "simulator", "simulated switches publishing motor samples, throws and truth",
                         cmd_simulator, status=True)
    simulator.add_argument("--scenario", metavar="F.toml", help="schedule of switches, throws and fault changes")
    simulator.add_argument("--switches", type=bounded(int, 1, 10_000), default=None, help="switches sw1 … swN")
    simulator.add_argument("--switch-id", type=switch_id, action="append", default=[], help="a switch (repeatable)")
    simulator.add_argument("--throws", type=bounded(int, 1, 1_000_000), default=None,
                           help="throws per switch (default: until stopped)")
    simulator.add_argument("--interval", type=bounded(float, 7.5, 86_400.0, "s"), default=None,
                           help="simulated seconds between a switch's throw starts (default 10)")
    simulator.add_argument("--fault", type=fault_assignment, action="append", default=[], metavar="NAME=VALUE",
                           help="fault injected in every switch from the start (repeatable)")
    simulator.add_argument("--noise", type=bounded(float, 0.0, 0.5), default=None, metavar="REL")
    simulator.add_argument("--seed", type=bounded(int, 0, 2**32 - 1), default=0)
    simulator.add_argument("--rate", type=bounded(float, 1.0, 1000.0, "samples/s"), default=None,
                           help="samples per second (default 50)")
    simulator.add_argument("--speed", type=bounded(float, 0.01, 10_000.0, "x real time"), default=1.0)
    simulator.add_argument("--throws-from", metavar="F.mcap", default=None,
                           help="stream the recorded throws of F (both directions) instead of running the plant: "
                                "hundreds of switches on one core")

    diagnoser = _service(commands, "diagnoser", "diagnose every finished throw on the bus", cmd_diagnoser, status=True)
    diagnoser.add_argument("--model", choices=["poly", "nn", "causal"], default="poly", help="reduced rail model")
    diagnoser.add_argument("--shard", type=shard, default=(1, 1), metavar="K/N",
                           help="serve only switches in shard K of N (stable hash of the switch id)")

    recorder = _service(commands, "recorder", "record railswitch/** to an MCAP file", cmd_recorder, status=True)
    recorder.add_argument("--out", required=True, metavar="F.mcap",
                          help="file to write; {time} in the name becomes the UTC start time")

    replay = _service(commands, "replay", "republish a recording's motor, throw and truth messages", cmd_replay)
    replay.add_argument("recording", metavar="F.mcap")
    pace = replay.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=bounded(float, 0.01, 10_000.0, "x real time"), default=1.0)
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    replay.add_argument("--loop", type=bounded(int, 0, 1_000_000), default=1, metavar="N",
                        help="passes over the recording (0: until stopped)")
    replay.add_argument("--with-diagnosis", action="store_true", help="also republish recorded diagnoses")

    watch = _service(commands, "watch", "live table of diagnoses", cmd_watch)
    watch.add_argument("--switch-id", type=switch_id, action="append", default=[], help="only this switch (repeatable)")
    watch.add_argument("--jsonl", action="store_true", help="one Diagnosis JSON object per line")
    watch.add_argument("--count", type=bounded(int, 1, 10**9), default=None, help="exit after N diagnoses")
    watch.add_argument("--duration", type=bounded(float, 0.1, 10**9, "s"), default=None, help="exit after S seconds")

    demo = commands.add_parser("demo", help="router, simulator, diagnoser and recorder with a live table and summary")
    demo.add_argument("--switches", type=bounded(int, 1, 50), default=4)
    demo.add_argument("--throws", type=bounded(int, 2, 1000), default=4, help="throws per switch")
    demo.add_argument("--speed", type=bounded(float, 0.1, 1000.0, "x real time"), default=1.0)
    demo.add_argument("--out", default="demo.mcap", metavar="F.mcap")
    demo.add_argument("--listen", default=None, metavar="ENDPOINT",
                      help="endpoint of the embedded router (default: a free loopback port)")
    demo.add_argument("--model", choices=["poly", "nn", "causal"], default="poly")
    demo.set_defaults(handler=cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.handler(args)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `railswitch diagnose F --jsonl | head`: the reader left, nothing is wrong
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
