"""`railswitch simulate`: run the high-fidelity plant offline and write an MCAP recording."""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

from rich.progress import Progress

from railswitch.models.plant import Plant
from railswitch.models.switch import SwitchSimulation
from railswitch.services.adapters.recordings import RecordingPathError, RecordingWriter, check_writable
from railswitch.services.commands.options import bounded, fail, fault_assignment, switch_id
from railswitch.services.core.switch_messages import switch_messages


@dataclass(frozen=True)
class SimulationSummary:
    path: Path
    throws: int
    messages: int
    bytes: int


def simulate_to_mcap(out: str | Path, *, switch_id: str = "sw1", throws: int = 2, faults: dict[str, float] | None = None,
                     noise_rel: float = 0.0, seed: int = 0, rate_hz: float = 50.0, plant: Plant | None = None,
                     progress=None) -> SimulationSummary:
    """Simulate `throws` alternating throws and record motor, throw and truth channels.

    The file appears only when complete (written beside it, then renamed).
    """
    check_writable(out)
    sim = SwitchSimulation(plant or Plant(), rate_hz=rate_hz, faults=faults, noise_rel=noise_rel, seed=seed)
    with RecordingWriter(out) as writer:
        for key, message in switch_messages(switch_id, sim, throws, progress):
            writer.write(key, message)
        count = writer.message_count
    path = Path(out)
    return SimulationSummary(path, throws, count, path.stat().st_size)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="MCAP file to write")
    parser.add_argument("--switch-id", type=switch_id, default="sw1")
    parser.add_argument("--throws", type=bounded(int, 1, 10_000), default=2, help="alternating, left to right first")
    parser.add_argument("--fault", type=fault_assignment, action="append", default=[], metavar="NAME=VALUE",
                        help="inject a fault, e.g. left_bolt_offset=0.05 (repeatable)")
    parser.add_argument("--noise", type=bounded(float, 0.0, 0.5), default=0.0, metavar="REL",
                        help="Gaussian noise, std = REL x the signal's nominal peak")
    parser.add_argument("--seed", type=bounded(int, 0, 2**32 - 1), default=0)
    parser.add_argument("--rate", type=bounded(float, 1.0, 1000.0, "samples/s"), default=50.0, help="samples per second")


def run(args: argparse.Namespace) -> int:
    try:
        with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
            task = progress.add_task("simulating throws", total=args.throws)
            summary = simulate_to_mcap(args.out, switch_id=args.switch_id, throws=args.throws, faults=dict(args.fault),
                                       noise_rel=args.noise, seed=args.seed, rate_hz=args.rate,
                                       progress=lambda: progress.advance(task))
    except RecordingPathError as error:
        return fail(str(error))
    print(f"wrote {summary.path} ({summary.throws} throws, {summary.messages} messages, {summary.bytes} bytes)")
    return 0
