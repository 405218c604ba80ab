"""Training, calibrating and describing the reduced rail models: the jobs around models/training.py,
reading and writing their documents through services/adapters/model_store.py."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from railswitch.models.plant import Plant
from railswitch.models.rail_models import REPRESENTATIONS
from railswitch.models.reduced import NEUTRAL_PORT, STATES, ReducedSwitch
from railswitch.models.reference import DIRECTIONS
from railswitch.models.switch import SwitchSimulation
from railswitch.models.training import TRAIN_SEEDS, train
from railswitch.models.validation import quick_validation
from railswitch.services.adapters import model_store
from railswitch.services.adapters.compiled import MachineCode


def train_and_save(name: str, *, seed: int = 0, iterations: int = 40, out_dir: str | None = None,
                   replace_shipped: bool = False) -> tuple[Path, float]:
    """Train one representation with a live progress line, validate it quickly and store its document
    (model_store.save: the user directory unless told otherwise); its path and the training time."""
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

        plant = Plant()
        trained = train(representation, plant, seed=seed, iterations=iterations, progress=report)
    seconds = time.perf_counter() - start
    provenance = {"seed": seed, "series_seeds": list(TRAIN_SEEDS), "series_seconds": 100.0, "sample_rate_hz": 50.0,
                  "iterations": iterations, "stages": trained.stages, "seconds": round(seconds, 1)}
    document = model_store.weights_document(representation, trained.weights, provenance)
    document["validation"] = quick_validation(ReducedSwitch(representation, trained.weights, compiler=MachineCode()),
                                              plant)
    return model_store.save(name, document, out_dir=out_dir, replace_shipped=replace_shipped), seconds


CALIBRATION_BEARINGS = (2000.0, 3500.0, 8000.0)  # N·s/m; the paper's 5000 stays out, to validate on


def calibrate_bearing_port(name: str, plant: Plant | None = None) -> dict:
    """Fit the bearing port of a model, per direction of motion: plant throws with known bearing
    friction, estimated through the neutral port, give estimate = gain * friction + offset by least
    squares; the diagnosis then uses that port, so its estimates come back in the plant's terms."""
    from railswitch.services.core.fleet_diagnoser import Diagnoser, diagnose_simulation

    plant = plant or Plant()
    diagnoser = Diagnoser(name, port=NEUTRAL_PORT)
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


def calibrate_and_save(name: str, *, replace_shipped: bool = False) -> tuple[Path, dict]:
    """Calibrate a model's bearing port and store its document with the port (the user directory unless told)."""
    port = calibrate_bearing_port(name)
    document = model_store.read_document(name)
    document["bearing_port"] = port
    return model_store.save(name, document, replace_shipped=replace_shipped), port


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
                     "bearing_port": stored.bearing_port, "validation": stored.validation}
    return out
