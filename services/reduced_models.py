"""Training, saving and describing the reduced rail models (the I/O around models/training.py)."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

import models.params as shipped
from models.plant import Plant
from models.rail_models import REPRESENTATIONS
from models.reduced import STATES, ReducedSwitch
from models.reference import DIRECTIONS
from models.training import TRAIN_SEEDS, train
from models.validation import quick_validation


def train_and_save(name: str, *, seed: int = 0, iterations: int = 40, out_dir: str | None = None) -> tuple[Path, float]:
    """Train one representation with a live progress line; write <name>.json; return its path and the time taken."""
    representation = REPRESENTATIONS[name]
    target = Path(out_dir) if out_dir else Path(shipped.__file__).parent
    if not target.is_dir():
        raise OSError(f"{target} is not a directory")
    start = time.perf_counter()
    console = Console(stderr=True)
    with Progress(TextColumn(f"[bold]{name}[/] {{task.description}}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TextColumn("cost {task.fields[cost]}"), TimeElapsedColumn(), console=console,
                  disable=not sys.stderr.isatty()) as progress:
        tasks: dict[str, int] = {}

        def report(stage: str, iteration: int, cost: float) -> None:
            if stage not in tasks:
                tasks[stage] = progress.add_task(stage, total=iterations, cost="")
            progress.update(tasks[stage], completed=iteration, cost=f"{cost:.4g}")

        plant = Plant()
        trained = train(representation, plant, seed=seed, iterations=iterations, progress=report)
    seconds = time.perf_counter() - start
    provenance = {"seed": seed, "series_seeds": list(TRAIN_SEEDS), "series_seconds": 100.0, "sample_rate_hz": 50.0,
                  "iterations": iterations, "stages": trained.stages, "seconds": round(seconds, 1)}
    path = target / f"{name}.json"
    document = shipped.weights_document(representation, trained.weights, provenance)
    document["validation"] = quick_validation(ReducedSwitch(representation, trained.weights, compiled=True), plant)
    path.write_text(json.dumps(document, indent=1) + "\n")
    return path, seconds


CALIBRATION_BEARINGS = (2000.0, 3500.0, 8000.0)  # N·s/m; the paper's 5000 stays out, to validate on


def calibrate_bearing_port(name: str, plant: Plant | None = None) -> dict:
    """Fit the bearing port of a shipped model, per direction of motion: plant throws with known bearing
    friction, estimated through the neutral port, give estimate = gain * friction + offset by least
    squares; the diagnosis then uses that port, so its estimates come back in the plant's terms."""
    from models.switch import SwitchSimulation
    from services.diagnosis import Diagnoser, diagnose_simulation

    plant = plant or Plant()
    diagnoser = Diagnoser(name, port=shipped.NEUTRAL_PORT)
    estimates: dict[str, list[float]] = {direction: [] for direction in DIRECTIONS}
    for value in CALIBRATION_BEARINGS:
        sim = SwitchSimulation(plant, faults={"bearing_friction": value})
        for item in diagnose_simulation(diagnoser, f"calibration{int(value)}", sim, len(DIRECTIONS)):
            if item.verdict is None:
                raise RuntimeError(f"calibration throw at {value:g} N·s/m was not diagnosed: {item.diagnosis.reason}")
            estimates[item.verdict.direction].append(item.verdict.estimates["missing_bearing"].params["bearing_friction"])
    port: dict = {}
    for direction, values in estimates.items():
        gain, offset = np.polyfit(CALIBRATION_BEARINGS, values, 1)
        port[direction] = {"gain": round(float(gain), 5), "offset_s_m": round(float(offset), 2)}
    return {**port, "calibrated_on_n_s_m": list(CALIBRATION_BEARINGS), "estimates_through_neutral_port": estimates}


def calibrate_and_save(name: str) -> tuple[Path, dict]:
    """Calibrate a shipped model's bearing port and store it in its JSON."""
    path = Path(shipped.__file__).parent / f"{name}.json"
    port = calibrate_bearing_port(name)
    document = json.loads(path.read_text())
    document["bearing_port"] = port
    path.write_text(json.dumps(document, indent=1) + "\n")
    return path, port


def describe_reduced() -> dict:
    """States, parameters and equations of each reduced model (the paper's Tables 2 and 3)."""
    out = {}
    for name, representation in REPRESENTATIONS.items():
        entry = {"rail_states": 2, "switch_states": len(STATES), "parameters": representation.size,
                 "equations": list(representation.equations),
                 "form": "acausal" if representation.acausal else "causal"}
        try:
            entry["trained"] = shipped.load(name)[2]
            entry["bearing_port"] = shipped.bearing_port(name)
            entry["validation"] = shipped.validation(name)
        except FileNotFoundError:
            entry["trained"] = None
        out[name] = entry
    return out
