"""`railswitch simulate`: run the high-fidelity plant offline and write an MCAP recording.

Either one switch throwing back to back (`--switch-id`, `--throws`, `--fault`, `--plant`, `--vary`) or
a scenario file's switches, throws, idle periods and changes (`--scenario`), as the live simulator
would publish them, at no cost in waiting.
"""
from __future__ import annotations

import argparse
import heapq
import sys
from dataclasses import dataclass
from pathlib import Path

from rich.progress import Progress

from railswitch.models.plant.high_fidelity import Plant
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.schemas.scenario import STROKE_S, Scenario, ScenarioError, load_scenario
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.adapters.recordings import RecordingPathError, RecordingWriter, check_writable
from railswitch.services.commands.options import add_own_arguments, bounded, fail, fault_assignment, switch_id
from railswitch.services.core.simulated_fleet import SwitchStream, own_parameters, simulation
from railswitch.services.core.switch_messages import switch_messages

LEAD_S = 1.0  # samples at rest before a scenario's first throw, as the live simulator has them
# The options of one switch, which a scenario file replaces (all but --out): given beside --scenario, they are refused.
SCENARIO_REPLACES = ("switch_id", "throws", "fault", "plant", "vary", "stroke", "throw_length", "noise", "seed", "rate")


@dataclass(frozen=True)
class SimulationSummary:
    path: Path
    throws: int
    messages: int
    bytes: int


def simulate_to_mcap(out: str | Path, *, switch_id: str = "sw1", throws: int = 2, faults: dict[str, float] | None = None,
                     noise_rel: float = 0.0, seed: int = 0, rate_hz: float = 50.0, plant: Plant | None = None,
                     own: dict[str, float] | None = None, stroke_s: float = STROKE_S, end_s: float | None = None,
                     progress=None) -> SimulationSummary:
    """Simulate `throws` alternating throws back to back and record motor, throw and truth channels.

    The file appears only when complete (written beside it, then renamed).
    """
    check_writable(out)
    sim = SwitchSimulation(plant or compiled_plant(), rate_hz=rate_hz, faults=faults, noise_rel=noise_rel, seed=seed,
                           own=own, stroke_s=stroke_s, end_s=end_s)
    with RecordingWriter(out) as writer:
        for key, message in switch_messages(switch_id, sim, throws, progress):
            writer.write(key, message)
        count = writer.message_count
    path = Path(out)
    return SimulationSummary(path, throws, count, path.stat().st_size)


def scenario_to_mcap(out: str | Path, scenario: Scenario, plant: Plant | None = None, progress=None) -> SimulationSummary:
    """Every switch of a scenario, with its idle periods, staggered as the live simulator staggers them,
    recorded in time order."""
    check_writable(out)
    plant = plant or compiled_plant()
    count = len(scenario.switches)
    streams = [SwitchStream.start(plan, simulation(plant, plan, scenario, k), interval_s=scenario.interval_s,
                                  offset_s=LEAD_S + k * scenario.interval_s / count)
               for k, plan in enumerate(scenario.switches)]
    with RecordingWriter(out) as writer:
        merged = heapq.merge(*(_messages(stream, progress) for stream in streams), key=lambda item: item[0])
        for _, key, message in merged:
            writer.write(key, message)
        written = writer.message_count
    path = Path(out)
    return SimulationSummary(path, sum(plan.throws for plan in scenario.switches), written, path.stat().st_size)


def _messages(stream: SwitchStream, progress):
    """A stream's messages in time order, throw after throw, until its plan is done."""
    throws = 0
    while not stream.done:
        horizon = stream.pending[-1][0] if stream.pending else 0
        for key, message in stream.due(horizon):
            yield message.t_ns, key, message
        if progress is not None and stream.throws_done > throws:
            throws = stream.throws_done
            progress()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="MCAP file to write")
    parser.add_argument("--scenario", metavar="F.toml", default=None,
                        help="a schedule of switches, throws and changes (docs/contracts.md), instead of the options below")
    # Their defaults are None (applied in run) so that run can tell which were given beside --scenario.
    parser.add_argument("--switch-id", type=switch_id, default=None, help="the switch (default sw1)")
    parser.add_argument("--throws", type=bounded(int, 1, 10_000), default=None,
                        help="alternating, left to right first (default 2)")
    parser.add_argument("--fault", type=fault_assignment, action="append", default=[], metavar="NAME=VALUE",
                        help="inject a fault, e.g. left_bolt_offset=0.05 (repeatable)")
    add_own_arguments(parser)
    parser.add_argument("--noise", type=bounded(float, 0.0, 0.5), default=None, metavar="REL",
                        help="Gaussian noise, std = REL x the signal's nominal peak (default 0)")
    parser.add_argument("--seed", type=bounded(int, 0, 2**32 - 1), default=None, help="the noise's seed (default 0)")
    parser.add_argument("--rate", type=bounded(float, 1.0, 1000.0, "samples/s"), default=None,
                        help="samples per second (default 50)")


def options_beside_scenario(args: argparse.Namespace) -> list[str]:
    """The options given on the command line that a scenario file replaces (each of them is refused with it)."""
    return [f"--{name.replace('_', '-')}" for name in SCENARIO_REPLACES if getattr(args, name) not in (None, [])]


def run(args: argparse.Namespace) -> int:
    if args.scenario and (given := options_beside_scenario(args)):
        return fail(f"--scenario excludes {', '.join(given)} (the file says it)")
    try:
        scenario = load_scenario(args.scenario) if args.scenario else None
    except ScenarioError as error:
        return fail(str(error))
    switch, throws = args.switch_id or "sw1", args.throws or 2
    total = sum(plan.throws for plan in scenario.switches) if scenario else throws
    try:
        with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
            task = progress.add_task("simulating throws", total=total)
            advance = lambda: progress.advance(task)  # noqa: E731
            if scenario is not None:
                summary = scenario_to_mcap(args.out, scenario, progress=advance)
            else:
                from railswitch.schemas.scenario import SwitchPlan

                own = own_parameters(SwitchPlan(id=switch, throws=1, plant=dict(args.plant), vary=args.vary))
                summary = simulate_to_mcap(args.out, switch_id=switch, throws=throws, faults=dict(args.fault),
                                           noise_rel=args.noise or 0.0, seed=args.seed or 0, rate_hz=args.rate or 50.0,
                                           own=own, stroke_s=args.stroke or STROKE_S, end_s=args.throw_length,
                                           progress=advance)
    except RecordingPathError as error:
        return fail(str(error))
    print(f"wrote {summary.path} ({summary.throws} throws, {summary.messages} messages, {summary.bytes} bytes)")
    return 0
