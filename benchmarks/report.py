"""docs/results.md from the benchmarks: runs each (or reads the JSON it printed before) and rewrites the file.

`python -m benchmarks.report` runs every benchmark of RUNS in turn (an hour or two on 2 cores), keeps each one's last
JSON line in docs/results/<name>.json with the command, the commit and the day it ran (committed with the project, so
a fresh clone can rerun some and keep the rest), and writes docs/results.md: one table per benchmark, a column per
representation where it runs per representation, each under the commit its figures come from. `--only NAME` reruns
those and reuses the others' kept JSON; `--from DIR` reruns nothing; `--db URL` hands a PostgreSQL server to the
benchmarks that measure one beside SQLite (historian, soak). Every figure in the file comes from one of these
JSON objects; nothing is typed in.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from railswitch.schemas import RAIL_MODELS

ROOT = Path(__file__).resolve().parent.parent
DEPTH = 3  # nested dicts flattened this deep; lists (per case, per series) stay in the kept JSON


@dataclass(frozen=True)
class Run:
    """One benchmark invocation; `per_model` runs it once per representation (with --model)."""

    benchmark: str
    args: tuple[str, ...] = ()
    per_model: bool = False
    title: str = ""
    whole_machine: bool = False  # it runs worker processes of its own: alone, on every core
    name: str = ""  # what --only and the kept JSON call it, where one benchmark runs twice (default: benchmark)
    database: bool = False  # it takes --db URL: given the report's --db where one is given

    @property
    def key(self) -> str:
        return self.name or self.benchmark

    def names(self) -> list[str]:
        return [f"{self.key}-{model}" for model in RAIL_MODELS] if self.per_model else [self.key]

    def command(self, name: str, db: str | None = None) -> list[str]:
        model = name.removeprefix(f"{self.key}-") if self.per_model else None
        return [sys.executable, "-m", f"benchmarks.{self.benchmark}", "--json", *self.args,
                *(("--model", model) if model else ()), *(("--db", db) if db and self.database else ())]


RUNS = (
    Run("reduced", title="Reduced rail models against the plant (speed-up, validation, training)"),
    Run("plant", title="High-fidelity plant (real-time factor)"),
    Run("diagnosis", ("--seed", "11"), per_model=True, title="Diagnosis per throw (quality, latency, the paper's DE)"),
    Run("profile", per_model=True, title="Where one throw's diagnosis spends its time (per phase, per hypothesis)"),
    Run("fleet", ("--seed", "1"), per_model=True, title="A fleet of switches unlike the model, with anomalies"),
    Run("coverage", per_model=True, title="Coverage of the uncertainty on held-out switches"),
    Run("aging", title="Switches as they age (several faults, standing conditions, growth, repairs)",
        whole_machine=True),
    Run("prognosis", per_model=True, title="Prognosis (throws to a limit)", whole_machine=True),
    Run("memory", title="Diagnoser memory per switch"),
    Run("historian", title="History store (SQLite; with --db, PostgreSQL beside it)", whole_machine=True,
        database=True),
    Run("bus", ("--records",), name="bus-capacity",
        title="Bus: switches per core at 100 throws a day, and a paced fleet (records, elastic diagnosers)",
        whole_machine=True),
    Run("bus", ("--records", "--outage", "600"), title="Bus: a fleet through an outage of every diagnoser",
        whole_machine=True),
    Run("soak", ("--records", "--minutes", "10"),
        title="Soak: 200 switches as records at 10x for 10 minutes (elastic diagnosers, two historians)",
        whole_machine=True, database=True),
)


def flatten(value: object, prefix: str = "", depth: int = DEPTH) -> dict[str, object]:
    """Scalars of a JSON object under dotted keys; lists and deeper objects are left out."""
    if isinstance(value, dict):
        if depth == 0:
            return {}
        out: dict[str, object] = {}
        for key, inner in value.items():
            out.update(flatten(inner, f"{prefix}.{key}" if prefix else str(key), depth - 1))
        return out
    if isinstance(value, (list, tuple)):
        return {}
    return {prefix: value}


def cell(value: object) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value).replace("|", "\\|")


def columns(run: Run, results: dict[str, dict]) -> dict[str, dict[str, object]]:
    """Column name -> flattened figures: one per representation (its own run, or its key in one run's object)."""
    if run.per_model:
        return {name.removeprefix(f"{run.key}-"): flatten(results[name]) for name in run.names()
                if name in results}
    result = results.get(run.key)
    if result is None:
        return {}
    models = [model for model in RAIL_MODELS if isinstance(result.get(model), dict)]
    if not models:
        return {"value": flatten(result)}
    shared = {key: value for key, value in result.items() if key not in models}
    out = {model: flatten(result[model]) for model in models}
    if flatten(shared):
        out["run"] = flatten(shared)
    return out


def table(cols: dict[str, dict[str, object]]) -> list[str]:
    keys: list[str] = []
    for figures in cols.values():
        keys.extend(key for key in figures if key not in keys)
    lines = ["| figure | " + " | ".join(cols) + " |", "| --- |" + " --- |" * len(cols)]
    lines += [f"| `{key}` | " + " | ".join(cell(figures.get(key)) for figures in cols.values()) + " |" for key in keys]
    return lines


def machine() -> str:
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor()) if Path("/proc/cpuinfo").exists() else ""
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}"


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def render(results: dict[str, dict], sources: dict[str, str], ran: dict[str, str] | None = None) -> str:
    """The file: per benchmark its commands, each with the commit and day it ran (`ran`), and its table."""
    ran = ran or {}
    lines = ["# Results", "",
             "Written by `python -m benchmarks.report` from the JSON each benchmark printed last; do not edit by hand.",
             "Code comments and docstrings point here rather than quote a figure. Speed figures are ratios measured in",
             "one run, since machines of one kind differ by 2x; the targets are in each benchmark's docstring and in",
             "the issues they serve.", "",
             "Each benchmark's figures come from the commit named after its command; a change that touches what a",
             "benchmark measures reruns it (`--only NAME`).", "",
             f"- machine: {machine()}", f"- written at commit: {commit()}",
             f"- written: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC", ""]
    for run in RUNS:
        cols = columns(run, results)
        lines += [f"## `benchmarks.{run.benchmark}`: {run.title}", ""]
        if not cols:
            lines += ["Not run for this file.", ""]
            continue
        lines += ["Command: " + "; ".join(f"`{sources[name]}`" + (f" ({ran[name]})" if ran.get(name) else "")
                                          for name in run.names() if name in sources), ""]
        lines += [*table(cols), ""]
    return "\n".join(lines)


class Cores:
    """The machine's cores, handed to benchmarks as they start: one each, or all to one that runs workers."""

    def __init__(self) -> None:
        self.free = sorted(os.sched_getaffinity(0))
        self.all = tuple(self.free)
        self.changed = threading.Condition()

    def take(self, whole_machine: bool) -> list[int]:
        with self.changed:
            wanted = len(self.all) if whole_machine else 1
            self.changed.wait_for(lambda: len(self.free) >= wanted)
            taken, self.free = self.free[:wanted], self.free[wanted:]
            return taken

    def give(self, cores: list[int]) -> None:
        with self.changed:
            self.free = sorted(self.free + cores)
            self.changed.notify_all()


def run_benchmark(run: Run, name: str, cores: Cores, kept: Path, db: str | None = None) -> None:
    """Run one benchmark on the cores it needs and keep its command and last JSON line in kept/<name>.json."""
    command = run.command(name, db)
    taken = cores.take(run.whole_machine)
    try:
        print("running", " ".join(command[1:]), "on cores", taken, file=sys.stderr, flush=True)
        started = time.monotonic()
        done = subprocess.run(["taskset", "-c", ",".join(map(str, taken)), *command], cwd=ROOT,
                              capture_output=True, text=True)
    finally:
        cores.give(taken)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command[1:])} exited with {done.returncode}:\n{done.stderr[-2000:]}")
    (kept / f"{name}.json").write_text(json.dumps({
        "command": command[1:], "wall_s": round(time.monotonic() - started), "commit": commit(),
        "machine": machine(), "ran": f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d}",
        "result": json.loads(done.stdout.strip().splitlines()[-1])}, indent=1) + "\n")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--from", dest="source", type=Path, default=None, metavar="DIR",
                   help="render from the <name>.json files kept in DIR; run nothing")
    p.add_argument("--only", action="append", default=[], choices=[run.key for run in RUNS],
                   help="run these benchmarks; reuse the others' kept JSON")
    p.add_argument("--db", default=None, metavar="URL",
                   help="a PostgreSQL server for the benchmarks that also measure one (historian, soak): "
                        "postgresql://user@host:port/db; without it they measure SQLite only")
    p.add_argument("--kept", type=Path, default=ROOT / "docs" / "results", help="where each run's JSON is kept")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "results.md")
    p.add_argument("--jobs", type=int, default=1, help="benchmarks run at once, each on a core of its own (those that "
                                                       "run workers of their own have the machine to themselves)")
    args = p.parse_args()
    kept = args.source or args.kept
    kept.mkdir(parents=True, exist_ok=True)
    if args.source is None:
        chosen = [(run, name) for run in RUNS if not args.only or run.key in args.only for name in run.names()]
        cores = Cores()
        with ThreadPoolExecutor(max(1, min(args.jobs, len(cores.all)))) as pool:
            failed = [error for error in pool.map(lambda job: attempt(*job, cores, kept, args.db), chosen) if error]
        for error in failed:
            print(error, file=sys.stderr)
    results, sources, ran = kept_runs(kept)
    args.out.write_text(render(results, sources, ran))
    print(f"wrote {args.out} from {len(results)} runs", file=sys.stderr)
    return 1 if args.source is None and failed else 0


def kept_runs(kept: Path) -> tuple[dict[str, dict], dict[str, str], dict[str, str]]:
    """The runs kept in `kept`, by name: each one's JSON object, its command, and the commit and day it ran."""
    results: dict[str, dict] = {}
    sources: dict[str, str] = {}
    ran: dict[str, str] = {}
    for run in RUNS:
        for name in run.names():
            path = kept / f"{name}.json"
            if path.exists():
                kept_run = json.loads(path.read_text())
                results[name] = kept_run["result"]
                sources[name] = "python " + " ".join(kept_run["command"])
                ran[name] = ", ".join(kept_run[k] for k in ("commit", "ran") if kept_run.get(k))
    return results, sources, ran


def attempt(run: Run, name: str, cores: Cores, kept: Path, db: str | None = None) -> str | None:
    """None, or why the run failed (the others go on; the file keeps that run's earlier JSON, if any)."""
    try:
        run_benchmark(run, name, cores, kept, db)
    except RuntimeError as error:
        return str(error)
    return None


if __name__ == "__main__":
    sys.exit(main())
