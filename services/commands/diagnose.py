"""`railswitch diagnose F.mcap|F.csv`: every throw of a recording or a CSV file, as a table or as JSON lines."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from railswitch.schemas import ThrowEvent, ThrowRecord, encode
from railswitch.services.core.fleet_diagnoser import DiagnosedThrow, diagnose_messages
from railswitch.services.wiring import Diagnoser
from railswitch.services.adapters.csv_throws import CsvInputError, load_throws
from railswitch.services.commands.options import add_model_argument


def key_estimate(item: DiagnosedThrow) -> str:
    """The decided fault's size over the throws that see it, with standard deviations."""
    estimate = item.diagnosis.estimate
    if estimate is None:
        return ""
    return ", ".join(f"{name}={value:.4g}±{estimate.std[name]:.2g}" for name, value in estimate.params.items())


def read_messages(path: str) -> list | None:
    """A recording's messages, with one line on its damage, what was skipped and what this version does not know
    (a newer writer's fields, counted per name); None when the file is not there or is a CSV file that cannot be
    read (one line says where)."""
    if not Path(path).is_file():
        print(f"railswitch diagnose: {path}: no such file", file=sys.stderr)
        return None
    try:
        recording = load_throws(path)
    except CsvInputError as error:
        print(f"railswitch diagnose: {error}", file=sys.stderr)
        return None
    note = recording.note()
    if note:
        print(f"railswitch diagnose: {path}: {note}", file=sys.stderr)  # one line, never wrapped
    return recording.messages


def commission_from(diagnoser: Diagnoser, messages: list, switches: set[str]) -> None:
    """Learn the baselines of a recording of healthy throws, for the switches of the same ids; a recording of
    one switch commissions every switch."""
    for _ in diagnose_messages(messages, diagnoser):
        pass
    learnt = dict(diagnoser.switches)
    if len(learnt) == 1:
        (state,) = (switch.state() for switch in learnt.values())
        for switch_id in switches:
            diagnoser.switch(switch_id).resume(state)
    for switch_id in set(learnt) - switches:
        del diagnoser.switches[switch_id]
    for switch_id in switches & set(learnt):
        diagnoser.switches[switch_id].latest.clear()  # the baseline stays; the recording's own throws start afresh
        diagnoser.switches[switch_id].rail_m = None


def diagnose_file(path: str, model: str = "poly", jsonl: bool = False, baseline: str | None = None) -> int:
    """Diagnose a recording (after commissioning from `baseline`, a recording of the healthy switch);
    1 when nothing could be read, else 0."""
    stderr = Console(stderr=True)
    messages = read_messages(path)
    if messages is None:
        return 2
    if not messages:
        return 1
    healthy = read_messages(baseline) if baseline else []
    if healthy is None:
        return 2
    throws = sum((isinstance(m, ThrowEvent) and m.phase == "start") or isinstance(m, ThrowRecord) for m in messages)
    diagnoser = Diagnoser(model)
    if healthy:
        commission_from(diagnoser, healthy, {m.switch_id for m in messages if hasattr(m, "switch_id")})
    table = Table("switch", "throw", "direction", "decision", "estimate ± std", "MSE", "ms", "truth", "reason",
                  title=f"{Path(path).name} ({model})")
    with Progress(console=stderr, transient=True, disable=not stderr.is_terminal) as progress:
        task = progress.add_task("preparing the estimator", total=throws)
        diagnoser.warm_up()
        progress.update(task, description="diagnosing throws")
        for item in diagnose_messages(messages, diagnoser):
            progress.advance(task)
            d = item.diagnosis
            if jsonl:
                sys.stdout.write(encode(d).decode() + "\n")
                sys.stdout.flush()
                continue
            decided = next((h for h in d.hypotheses if h.mode == (d.decision if d.estimate else "nominal")), None)
            truth = item.throw.truth
            truth_text = "" if truth is None else (", ".join(truth.active_modes()) or "nominal")
            table.add_row(d.switch_id, str(d.throw_index), "L→R" if d.direction == "left_to_right" else "R→L",
                          d.decision, key_estimate(item), f"{decided.mse:.2e}" if decided else "",
                          f"{d.latency_ms:.0f}", truth_text, d.reason or "")
    if not jsonl:
        console = Console()
        if not console.is_terminal:
            console = Console(width=180)  # a file or pipe gets whole rows
        console.print(table)
    return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="F.mcap|F.csv",
                        help="a recording, or a CSV file of one row per sample (docs/contracts.md section 4)")
    add_model_argument(parser)
    parser.add_argument("--jsonl", action="store_true", help="one Diagnosis JSON object per throw on stdout")
    parser.add_argument("--baseline", metavar="G.mcap", default=None,
                        help="commission first from a recording of the healthy switch (one switch: every switch)")


def run(args: argparse.Namespace) -> int:
    return diagnose_file(args.recording, model=args.model, jsonl=args.jsonl, baseline=args.baseline)
