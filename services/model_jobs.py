"""Training, calibrating and describing the reduced rail models: the jobs around models/reduced/training.py and
services/core/calibration.py, reading and writing their documents through services/adapters/model_store.py (a
job wires both sides, as services/wiring.py does, so it lives beside it, not in the core)."""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from railswitch.models.reduced.rail_models import REPRESENTATIONS, Representation
from railswitch.models.reduced.hybrid import STATES, ReducedSwitch
from railswitch.models.reduced.training import STAGE_ITERATIONS, TRAIN_SEEDS, Trained, train
from railswitch.models.reduced.validation import quick_validation
from railswitch.services.adapters import model_store
from railswitch.services.adapters.compiled import MachineCode, compiled_plant
from railswitch.services.core.calibration import calibrate, healthy_check
from railswitch.services.wiring import Diagnoser


def train_and_save(name: str, *, seed: int = 0, iterations: int = STAGE_ITERATIONS, out_dir: str | None = None,
                   replace_shipped: bool = False, threads: int | None = None) -> tuple[Path, float]:
    """Train one representation with a live progress line, validate it quickly and store its document
    (model_store.save: the user directory unless told otherwise); its path and the training time. `threads`
    (default: one per core) share the data; the weights are the same on any number."""
    threads = threads or training_threads()
    representation = REPRESENTATIONS[name]
    start = time.perf_counter()
    with Progress(TextColumn(f"[bold]{name}[/] {{task.description}}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TextColumn("cost {task.fields[cost]}"), TimeElapsedColumn(), console=Console(stderr=True),
                  disable=not sys.stderr.isatty()) as progress:
        tasks: dict[str, int] = {}

        def report(stage: str, iteration: int, cost: float) -> None:
            if stage not in tasks:
                tasks[stage] = progress.add_task(stage, total=iterations, cost="")
            progress.update(tasks[stage], completed=iteration, cost=f"{cost:.4g}")

        trained = reproducible_training(representation, seed=seed, iterations=iterations, progress=report,
                                        threads=threads)
    seconds = time.perf_counter() - start
    provenance = {"seed": seed, "series_seeds": list(TRAIN_SEEDS), "series_seconds": 100.0, "sample_rate_hz": 50.0,
                  "iterations": iterations, "stages": trained.stages, "seconds": round(seconds, 1), "threads": threads}
    document = model_store.weights_document(representation, trained.weights, provenance)
    document["validation"] = quick_validation(ReducedSwitch(representation, trained.weights, compiler=MachineCode()),
                                              compiled_plant(exact=True))  # the data training was validated on
    return model_store.save(name, document, out_dir=out_dir, replace_shipped=replace_shipped), seconds


def reproducible_training(representation: Representation, **options) -> Trained:
    """models/reduced/training.py train as every machine runs it: its data's plant and its own functions in EXACT machine
    code (plain IEEE arithmetic, not this processor's instructions)."""
    return train(representation, compiled_plant(exact=True), compiler=MachineCode(exact=True), **options)


class CheckFailed(Exception):
    """A calibration whose held-out healthy switches raise too many false alarms, not written over the shipped
    model."""


def calibrate_and_save(name: str, *, replace_shipped: bool = False, check_only: bool = False) -> tuple[Path, dict]:
    """Calibrate a model against the plant over the population (services/core/calibration.py) and store
    the port and the calibration with its parameters (the user directory unless told). `check_only`: only its
    step 4 (false alarms on held-out healthy switches) on the calibration stored now, stored beside it. A
    calibration that fails the check is never written over the shipped model (CheckFailed)."""
    with Progress(TextColumn(f"[bold]{name}[/] {{task.description}}"), TimeElapsedColumn(), console=Console(stderr=True),
                  disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task("calibrating")

        def report(text: str) -> None:
            progress.update(task, description=text)

        document = model_store.read_document(name)
        if check_only:
            diagnoser = Diagnoser(name)
            check = healthy_check(diagnoser.switch, compiled_plant(), progress=report)
            found = {"calibration": {**document.get("calibration", {}), "healthy_check": check}}
        else:
            found = calibrate(name, compiled_plant(), model_store, MachineCode, progress=report)
    if replace_shipped and not found["calibration"]["healthy_check"]["passed"]:
        raise CheckFailed(check_summary(found["calibration"]["healthy_check"]) + "; the shipped model is left as it was")
    document.update(found)
    return model_store.save(name, document, replace_shipped=replace_shipped), found


def check_summary(check: dict) -> str:
    """One line on a held-out healthy check."""
    text = (f"{check['false_alarms']} false alarms in {check['throws']} throws of {check['switches']} held-out healthy "
            f"switches ({check['per_1000_throws']:g} per 1000, limit {check['limit_per_1000_throws']:g})")
    if check["uncommissioned"]:
        text += f", {check['uncommissioned']} never commissioned"
    return text + (": passed" if check["passed"] else ": FAILED")


def describe_reduced() -> dict:
    """States, parameters and equations of each reduced model (the paper's Tables 2 and 3), and where its
    parameters come from, how it was trained, its bearing port and its quick validation."""
    out = {}
    for name, representation in REPRESENTATIONS.items():
        stored = model_store.load(name)
        out[name] = {"rail_states": 2, "switch_states": len(STATES), "parameters": representation.size,
                     "equations": list(representation.equations),
                     "form": "acausal" if representation.acausal else "causal",
                     "parameters_file": str(stored.path), "shipped": stored.shipped, "trained": stored.training,
                     "bearing_port": stored.bearing_port, "validation": stored.validation,
                     "calibration": {"model_weight": stored.model_weight, "healthy_gains": stored.healthy_gains,
                                     "error_model": stored.error_model, "healthy_check": stored.healthy_check}}
    return out


def training_threads() -> int:
    """One per core this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
