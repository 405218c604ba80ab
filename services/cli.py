"""The `railswitch` command line (DESIGN.md section 6).

Every bad value ends in one line on stderr that names it and the accepted
range, and exit code 2; no traceback.
"""
from __future__ import annotations

import argparse
import json
import sys
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


def cmd_train(args) -> int:
    from services.reduced_models import train_and_save

    names = ["poly", "nn", "causal"] if args.model == "all" else [args.model]
    try:
        for name in names:
            path, seconds = train_and_save(name, seed=args.seed, iterations=args.iterations, out_dir=args.out)
            print(f"trained {name} in {seconds:.1f} s: {path}")
    except OSError as error:
        return _fail(f"cannot write the parameters: {error}")
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


def cmd_diagnose(args) -> int:
    from services.diagnose import diagnose_file

    return diagnose_file(args.recording, model=args.model, jsonl=args.jsonl)


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
