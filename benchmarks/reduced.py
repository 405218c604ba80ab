"""Reduced rail models against the plant: speed-up, training time, validation errors, divergence.

For each representation: trains it (timed, deterministic, one thread per core, as `railswitch train`;
`weights_difference` is how far its weights are from those the diagnosis loads, shipped or the user's, in the
solver's order-one parameters, and `same_as_loaded_model` says whether that is within what training promises across
machines, models/reduced/training.py REPRODUCIBLE_WEIGHTS), times the plant and
the reduced switch model over the same two throws (14 s) in the same run, and
validates on 25 random-push series of 100 s never used in training (MSE of rail
position, velocity and force per series, written as JSON and a box plot; the
worst series's position RMSE is printed beside the mean), and sweeps a bolt in
quarter millimetres at the diagnosis's model rate: the current's peak as the blades
start, against the plant's, and how far it strays from smooth (models/reduced/validation.py
contact_peaks). `--stress N` also rolls
each reduced switch over N stress pushes of 30 s and every fault at the ends of its
range, at 10, 25, 50 and 100 samples/s, with one step per sample and with the
diagnosis's substeps, and counts the rollouts that diverge.
"""
from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.common import emit, parser, pin_to_one_core  # noqa: E402
from railswitch.models.numerics.buffers import InPlace  # noqa: E402
from railswitch.models.plant.high_fidelity import Plant  # noqa: E402
from railswitch.models.reduced.rail_models import REPRESENTATIONS  # noqa: E402
from railswitch.models.reduced.hybrid import ReducedSwitch  # noqa: E402
from railswitch.models.plant.reference import THROW_DURATION_S, throw_reference  # noqa: E402
from railswitch.models.plant.simulation import SwitchSimulation  # noqa: E402
from railswitch.models.reduced.hybrid import ReducedParams  # noqa: E402
from railswitch.models.reduced.training import (  # noqa: E402
    RATE_HZ, REPRODUCIBLE_WEIGHTS, VALIDATION_SEEDS, weights_difference)
from railswitch.models.diagnosis.estimation import MODEL_RATE_HZ  # noqa: E402
from railswitch.models.reduced.validation import (  # noqa: E402
    contact_peaks, divergence, plant_contact_peaks, plant_series, roughness, validate)
from railswitch.schemas import RAIL_MODELS  # noqa: E402
from railswitch.services.adapters import model_store  # noqa: E402
from railswitch.services.adapters.compiled import MachineCode, compiled_plant  # noqa: E402
from railswitch.services.model_jobs import reproducible_training  # noqa: E402

SAMPLES = int(THROW_DURATION_S * RATE_HZ)


def plant_two_throws_seconds(plant: Plant, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        sim = SwitchSimulation(plant)
        start = time.perf_counter()
        sim.throw(), sim.throw()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def reduced_two_throws_seconds(reduced: ReducedSwitch, repeats: int = 30) -> float:
    """The same two throws: one rollout per throw, each from the end of the previous, evaluated on its own
    buffers as the diagnosis evaluates it (models/numerics/buffers.py InPlace: no CasADi matrix made per call)."""
    references = [reduced.reference_columns(throw_reference(d), SAMPLES) for d in ("left_to_right", "right_to_left")]
    rollout = InPlace(reduced.rollout(SAMPLES))
    fault = reduced.vector()
    s0 = reduced.initial_state(1.0, 0.0)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        state = s0
        for refs in references:
            _, state = rollout(state, refs, fault, reduced.weights)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def box_plot(results: dict[str, dict[str, list[float]]], path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(12, 4))
    for ax, (key, unit) in zip(axes, (("position", "m²"), ("velocity", "(m/s)²"), ("force", "N²"))):
        ax.boxplot([results[name][key] for name in results], tick_labels=list(results))
        ax.set_title(f"MSE of rail {key} [{unit}]")
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
    fig.suptitle("Reduced switch models vs the plant on 25 validation series of 100 s")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


STRESS_RATES_HZ = (10.0, 25.0, 50.0, 100.0)
STRESS_SUBSTEPS = (ReducedParams().substeps, 2 * ReducedParams().substeps)  # the diagnosis's, and twice as many


def stress(representation, weights, series: int) -> dict:
    """Divergences of one representation over the stress set and fault extremes, per rate and substeps: one
    step per sample (or more where a sample is longer than the longest step, ReducedParams.max_step_s), as the
    diagnosis integrates (its ReducedParams keep the default substeps), and twice that."""
    runs, diverged, worst = {}, 0, 0.0
    for rate in STRESS_RATES_HZ:
        for substeps in STRESS_SUBSTEPS:
            reduced = ReducedSwitch(representation, weights, ReducedParams(substeps=substeps), rate_hz=rate,
                                    compiler=MachineCode())
            found = divergence(reduced, series)
            runs[f"{rate:g}Hz/{substeps}"] = len(found.diverged_series) + len(found.diverged_fault_throws)
            diverged += runs[f"{rate:g}Hz/{substeps}"]
            worst = max(worst, found.max_excursion_m)
    return {"series": series, "fault_throws": found.fault_throws, "diverged": diverged,
            "max_excursion_m": worst, "diverged_per_rate_and_substeps": runs}


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--models", default=",".join(RAIL_MODELS))
    p.add_argument("--out", default="out/reduced-validation", help="directory for the JSON summary and box plot")
    p.add_argument("--shipped", action="store_true", help="validate the shipped weights instead of retraining")
    p.add_argument("--stress", type=int, default=0, metavar="N",
                   help="also look for divergence on N stress series and the fault extremes, at every rate")
    args = p.parse_args()
    cores = os.sched_getaffinity(0)
    pin_to_one_core()
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    plant = compiled_plant()
    plant_seconds = plant_two_throws_seconds(plant)
    series = plant_series(plant, VALIDATION_SEEDS)
    plant_peaks = plant_contact_peaks(plant, MODEL_RATE_HZ)
    result, mses = {}, {}
    for name in args.models.split(","):
        representation = REPRESENTATIONS[name]
        loaded = model_store.load(name)  # what the diagnosis runs on: shipped, or the user's
        start = time.perf_counter()
        if args.shipped:
            weights, train_seconds = loaded.weights, loaded.training["seconds"]
        else:
            os.sched_setaffinity(0, cores)  # training shares its data among the machine's cores, as `railswitch train`
            weights = reproducible_training(representation, threads=len(cores)).weights
            pin_to_one_core()  # the rollouts are timed on one core
            train_seconds = time.perf_counter() - start
        compiler = MachineCode()
        reduced = ReducedSwitch(representation, weights, compiler=compiler)
        reduced_seconds = reduced_two_throws_seconds(reduced)
        mses[name] = validate(ReducedSwitch(representation, weights, compiler=compiler), series)
        result[name] = {
            "speedup_vs_plant": round(plant_seconds / reduced_seconds, 1),
            "reduced_wall_seconds": round(reduced_seconds, 5),
            "plant_wall_seconds": round(plant_seconds, 4),
            "train_seconds": round(train_seconds, 1),
            "train_threads": len(cores) if not args.shipped else loaded.training.get("threads", 1),
            "position_rmse_m": float(np.sqrt(np.mean(mses[name]["position"]))),
            "max_series_position_rmse_m": float(np.sqrt(np.max(mses[name]["position"]))),
            "velocity_rmse_m_s": float(np.sqrt(np.mean(mses[name]["velocity"]))),
            "force_rmse_n": float(np.sqrt(np.mean(mses[name]["force"]))),
            "compiled": compiler.machine_code,
        }
        if not args.shipped:  # the diagnosis runs on the loaded model, not always the one trained here
            difference = weights_difference(representation, weights, loaded.weights)
            result[name]["weights_difference"] = difference
            result[name]["same_as_loaded_model"] = difference <= REPRODUCIBLE_WEIGHTS
        peaks = contact_peaks(ReducedSwitch(representation, weights, rate_hz=MODEL_RATE_HZ, compiler=compiler))
        result[name]["bolt_contact"] = {"peak_current_a": round(float(np.mean(peaks)), 3),
                                        "plant_peak_current_a": round(float(np.mean(plant_peaks)), 3),
                                        "roughness": round(roughness(peaks), 4),
                                        "plant_roughness": round(roughness(plant_peaks), 4)}
        if args.stress:
            result[name]["stress"] = stress(representation, weights, args.stress)
    (out_dir / "validation.json").write_text(json.dumps({"summary": result, "mse_per_series": mses,
                                                         "series_seeds": list(VALIDATION_SEEDS)}, indent=1))
    box_plot(mses, out_dir / "validation_boxplot.png")
    emit(result, args.json)


if __name__ == "__main__":
    main()
