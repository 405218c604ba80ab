"""Reduced rail models against the plant: speed-up, training time and validation errors.

For each representation: trains it (timed, deterministic), times the plant and
the reduced switch model over the same two throws (14 s) in the same run, and
validates on 25 random-push series of 100 s never used in training (MSE of rail
position, velocity and force per series, written as JSON and a box plot).
"""
from __future__ import annotations

import json
import statistics
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.common import emit, parser, pin_to_one_core  # noqa: E402
from models.plant import Plant  # noqa: E402
from models.rail_models import REPRESENTATIONS  # noqa: E402
from models.reduced import ReducedSwitch  # noqa: E402
from models.reference import THROW_DURATION_S, throw_reference  # noqa: E402
from models.switch import SwitchSimulation  # noqa: E402
from models.training import RATE_HZ, VALIDATION_SEEDS, random_push_run, train  # noqa: E402
import models.params as shipped  # noqa: E402

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
    """The same two throws: one rollout per throw, each from the end of the previous."""
    references = [reduced.reference_columns(throw_reference(d), SAMPLES) for d in ("left_to_right", "right_to_left")]
    rollout = reduced.rollout(SAMPLES)
    fault = np.array([0.0, 0.0, 0.0, 0.0, 1.10])
    s0 = reduced.initial_state(1.0, 0.0)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        state = s0
        for refs in references:
            _, state = rollout(state, refs, fault, reduced.weights)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def validation_series(plant: Plant) -> list[dict]:
    """Plant runs of the 25 validation references (shared by every representation)."""
    out = []
    for seed in VALIDATION_SEEDS:
        reference, start, trajectory = random_push_run(plant, seed, 100.0)
        out.append({"seed": seed, "reference": reference, "start": start, "plant": trajectory})
    return out


def validate(reduced: ReducedSwitch, series: list[dict]) -> dict[str, list[float]]:
    mse = {"position": [], "velocity": [], "force": []}
    for item in series:
        start, plant = item["start"], item["plant"]
        s0 = reduced.initial_state(start["rail_position_m"], start["angle_rad"])
        out = reduced.simulate(s0, item["reference"], len(plant.t_s))
        for key, signal in (("position", "rail_position_m"), ("velocity", "rail_velocity_m_s"), ("force", "drive_force_n")):
            mse[key].append(float(np.mean((out[signal] - plant[signal]) ** 2)))
    return mse


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


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--models", default="poly,nn,causal")
    p.add_argument("--out", default="out/reduced-validation", help="directory for the JSON summary and box plot")
    p.add_argument("--shipped", action="store_true", help="validate the shipped weights instead of retraining")
    args = p.parse_args()
    pin_to_one_core()
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    plant = Plant()
    plant_seconds = plant_two_throws_seconds(plant)
    series = validation_series(plant)
    result, mses = {}, {}
    for name in args.models.split(","):
        representation = REPRESENTATIONS[name]
        start = time.perf_counter()
        if args.shipped:
            _, weights, provenance = shipped.load(name)
            train_seconds = provenance["seconds"]
        else:
            weights = train(representation, plant).weights
            train_seconds = time.perf_counter() - start
        reduced = ReducedSwitch(representation, weights, compiled=True)
        reduced_seconds = reduced_two_throws_seconds(reduced)
        mses[name] = validate(ReducedSwitch(representation, weights), series)
        result[name] = {
            "speedup_vs_plant": round(plant_seconds / reduced_seconds, 1),
            "reduced_wall_seconds": round(reduced_seconds, 5),
            "plant_wall_seconds": round(plant_seconds, 4),
            "train_seconds": round(train_seconds, 1),
            "position_rmse_m": float(np.sqrt(np.mean(mses[name]["position"]))),
            "velocity_rmse_m_s": float(np.sqrt(np.mean(mses[name]["velocity"]))),
            "force_rmse_n": float(np.sqrt(np.mean(mses[name]["force"]))),
            "compiled": reduced.compiled,
        }
    (out_dir / "validation.json").write_text(json.dumps({"summary": result, "mse_per_series": mses,
                                                         "series_seeds": list(VALIDATION_SEEDS)}, indent=1))
    box_plot(mses, out_dir / "validation_boxplot.png")
    emit(result, args.json)


if __name__ == "__main__":
    main()
