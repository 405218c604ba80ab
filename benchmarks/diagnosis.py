"""Diagnosis quality and latency (issues 4, 16, 17).

- The paper's four scenarios: the noise-free recordings in recordings/, decided
  per recording (the switch's decision after its last throw), with the
  injected parameter's relative error.
- A randomized matrix drawn from a printed seed: single faults of every mode spread
  over their ranges (away from zero, obstacles across the travel) and nominal cases,
  each two throws of the plant with 1 % noise after the switch was commissioned
  on its healthy throws (the paper's recordings are faulty from their first throw:
  decided provisionally, against the population).
- Latency of one throw's whole diagnosis on one core (estimators built first), and
  throws per core-second over every throw diagnosed (commissioning included).
- current_only: the same matrix as a unit that logs the motor current alone sees it.
- mixed_stream: switches sampled at 10, 25, 50 and 100 Hz whose throws last 5 to 9 s
  (machine types of other stroke times), on the one warm diagnoser: its compiles and
  latency, next to a plain stream (50 Hz, 7 s) of as many throws; and healthy switches
  of the same rates and lengths, whose faulty decisions after commissioning are false
  alarms (`healthy`).
- paper_de: the paper's estimator (differential evolution per hypothesis,
  benchmarks/paper_de.py) on the faulty throws of the first cases of the matrix, from
  the same commissioned state as ours, against ours on the same throws.
"""
from __future__ import annotations

import statistics
from collections.abc import Iterable
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.common import emit, parser, pin_to_one_core
from benchmarks.paper_de import PaperEstimator, paper_twin
from railswitch.models.diagnosis.estimation import WITHOUT
from railswitch.models.diagnosis.isolation import presence
from railswitch.models.diagnosis.switch_diagnoser import ThrowVerdict
from railswitch.models.plant.high_fidelity import Plant
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.schemas import RAIL_MODELS, Diagnosis
from railswitch.services.adapters.recordings import load_recording
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.core.fleet_diagnoser import diagnose_messages
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.throw_cutter import CutThrow
from railswitch.services.core.switch_messages import SimulatedThrows

RECORDINGS = Path(__file__).resolve().parent.parent / "recordings"
PAPER_SCENARIOS = {  # recording -> (mode, injected parameters), as in recordings/make.sh
    "left_bolt": ("left_bolt", {"left_bolt_offset": 0.05}),
    "right_bolt": ("right_bolt", {"right_bolt_offset": 0.20}),
    "missing_bearing": ("missing_bearing", {"bearing_friction": 5000.0}),
    "obstacle": ("obstacle", {"obstacle_friction": 1e5, "obstacle_position": 1.1}),
}
MAGNITUDE = {"left_bolt": "left_bolt_offset", "right_bolt": "right_bolt_offset",
             "missing_bearing": "bearing_friction", "obstacle": "obstacle_friction",
             "drive_friction": "drive_friction_nm"}
HEALTHY_THROWS = 4  # of each healthy switch of MIXED, after its commissioning
MIXED = ((10.0, 5.0), (25.0, 6.0), (50.0, 7.0), (100.0, 9.0), (10.0, 9.0), (25.0, 8.0), (50.0, 5.0), (100.0, 6.0))


def draw_cases(seed: int, per_mode: int, nominal: int) -> list[tuple[str, dict[str, float]]]:
    """Single faults spread over their ranges, away from zero, plus nominal cases."""
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(per_mode):
        cases.append(("left_bolt", {"left_bolt_offset": float(rng.uniform(0.02, 0.20))}))
        cases.append(("right_bolt", {"right_bolt_offset": float(rng.uniform(0.02, 0.20))}))
        cases.append(("missing_bearing", {"bearing_friction": float(rng.uniform(1500.0, 10_000.0))}))
        cases.append(("obstacle", {"obstacle_friction": float(np.exp(rng.uniform(np.log(3e4), np.log(3e5)))),
                                   "obstacle_position": float(rng.uniform(1.03, 1.17))}))
        cases.append(("drive_friction", {"drive_friction_nm": float(rng.uniform(0.04, 0.30))}))
    cases += [("nominal", {})] * nominal
    return cases


def latest_each_way(verdicts: Iterable[ThrowVerdict | None]) -> list[ThrowVerdict]:
    """The latest of the verdicts in each direction (whole: a switch keeps its own without reports)."""
    latest = {v.direction: v for v in verdicts if v is not None}
    return list(latest.values())


def true_mode_estimate(latest: Iterable[ThrowVerdict], mode: str) -> dict[str, float]:
    """The true mode's estimate from the latest throw (of each direction) that shows it best: a new fault by its
    evidence against the switch as it was, a present one by its presence (the switch as it is against the same
    without it), which is how the throws after the one that confirmed it test it."""
    def shown(v: ThrowVerdict) -> float:
        if mode in v.evidence:
            return v.evidence[mode].ratio
        if WITHOUT + mode in v.estimates:
            return presence(v.estimates, mode).ratio
        return -1.0

    verdicts = [v for v in latest if mode in v.reported]
    return max(verdicts, key=shown).reported[mode].params


def relative_errors(estimate: dict[str, float], truth: dict[str, float]) -> dict[str, float]:
    return {name: abs(estimate[name] - value) / abs(value) for name, value in truth.items()}


class Timed:
    """A Diagnoser whose every diagnosis is timed (wall time on the one core the benchmark runs on)."""

    def __init__(self, diagnoser: Diagnoser, signals: tuple[str, ...] | None = None):
        self.diagnoser = diagnoser
        self.signals = signals  # None: every signal the throw has; else these (what a unit logging less sends)
        self.seconds: list[float] = []
        self.verdicts: dict[str, list[ThrowVerdict]] = {}  # per switch, its latest each way

    def __call__(self, throw: CutThrow) -> Diagnosis:
        if self.signals is not None:
            throw = replace(throw, signals=throw.signals.only(self.signals))
        start = time.perf_counter()
        outcome = self.diagnoser.diagnose(throw)
        self.seconds.append(time.perf_counter() - start)
        self.verdicts[throw.switch_id] = latest_each_way([*self.verdicts.get(throw.switch_id, []), outcome.verdict])
        return outcome.diagnosis


def run_case(timed: Timed, plant: Plant, switch_id: str, faults: dict, noise: float, seed: int, throws: int = 2,
             kept: list | None = None, **machine) -> list[Diagnosis]:
    """The switch commissioned on its healthy throws first (as every switch is), then `throws` with the faults;
    their diagnoses. With `kept`, the commissioned switch (a copy, before its faulty throws) and those throws
    are appended to it, for the paper's estimator to diagnose from the same state."""
    sim = SwitchSimulation(plant, noise_rel=noise, seed=seed, **machine)
    source = SimulatedThrows(switch_id, sim)
    for _ in range(2 * COMMISSIONING_THROWS):
        timed(source.next())
    sim.set_faults(faults)
    faulty = [source.next() for _ in range(throws)]
    if kept is not None:
        switch = timed.diagnoser.switches[switch_id]
        kept.append((faults, paper_twin(switch, switch.estimator), faulty))
    return [timed(throw) for throw in faulty]


def percentiles(milliseconds: list[float]) -> dict[str, float]:
    return {"p50": round(float(np.percentile(milliseconds, 50)), 1),
            "p95": round(float(np.percentile(milliseconds, 95)), 1), "throws": len(milliseconds)}


def paper_scenarios(timed: Timed, latencies: list[float], verbose: bool) -> tuple[list[dict], float]:
    paper, worst = [], 0.0
    diagnoser = timed.diagnoser
    for name, (mode, truth) in PAPER_SCENARIOS.items():
        messages = load_recording(RECORDINGS / f"{name}.mcap").messages
        items = list(diagnose_messages(messages, diagnoser))
        diagnoses = [item.diagnosis for item in items]
        latencies += [d.latency_ms for d in diagnoses]
        switch_id = diagnoses[-1].switch_id
        errors = relative_errors(true_mode_estimate(latest_each_way(item.verdict for item in items), mode), truth)
        worst = max(worst, *errors.values())
        paper.append({"scenario": name, "decision": diagnoses[-1].named(), "correct": diagnoses[-1].named() == mode,
                      "rel_error": {k: round(v, 4) for k, v in errors.items()}})
        del diagnoser.switches[switch_id]
        if verbose:
            print(paper[-1])
    return paper, worst


def matrix(timed: Timed, plant: Plant, cases, seed: int, noise: float, latencies: list[float], verbose: bool,
           keep: int = 0) -> tuple[dict, list]:
    """Accuracy over the cases; the first `keep` faulty cases' commissioned switches and throws are returned
    (for the paper's estimator to diagnose from the same state)."""
    diagnoser = timed.diagnoser
    correct, false_alarms, magnitude_errors, rows, kept = 0, 0, [], [], []
    for k, (mode, faults) in enumerate(cases):
        switch_id = f"case{k}"
        keeping = len(kept) < keep and mode != "nominal"
        diagnoses = run_case(timed, plant, switch_id, faults, noise, seed + k, kept=kept if keeping else None)
        latencies += [d.latency_ms for d in diagnoses]
        decision = diagnoses[-1].named()  # every fault believed present: the one injected alone is right
        correct += decision == mode
        if mode == "nominal":
            false_alarms += decision != "nominal"
        else:
            errors = relative_errors(true_mode_estimate(timed.verdicts[switch_id], mode), faults)
            magnitude_errors.append(errors[MAGNITUDE[mode]])
        rows.append({"mode": mode, "faults": {n: round(v, 4) for n, v in faults.items()}, "decision": decision})
        if verbose:
            print(k, rows[-1], f"rel_error={magnitude_errors[-1]:.3f}" if mode != "nominal" else "")
        del diagnoser.switches[switch_id], timed.verdicts[switch_id]
    nominal = sum(mode == "nominal" for mode, _ in cases)
    return {"cases": len(cases), "accuracy": round(correct / len(cases), 4),
            "median_rel_error": round(statistics.median(magnitude_errors), 4),
            "false_alarms": false_alarms, "nominal_cases": nominal,
            "misdiagnosed": [r for r in rows if r["decision"] != r["mode"]]}, kept


def paper_de(timed: Timed, kept: list, verbose: bool) -> dict:
    """Ours and the paper's estimator on the same faulty throws, each from the same commissioned state."""
    estimator = PaperEstimator(timed.diagnoser.estimator)
    results = {"ours": {"seconds": [], "correct": 0, "errors": []}, "paper_de": {"seconds": [], "correct": 0, "errors": []}}
    for faults, switch, throws in kept:
        mode = next(m for m, name in MAGNITUDE.items() if name in faults)
        for name, twin in (("ours", paper_twin(switch, switch.estimator)), ("paper_de", paper_twin(switch, estimator))):
            verdicts = []
            for throw in throws:
                start = time.perf_counter()
                outcome = twin.diagnose(throw)
                results[name]["seconds"].append(time.perf_counter() - start)
                verdicts.append(outcome.verdict)
            results[name]["correct"] += outcome.named() == mode
            estimate = true_mode_estimate(latest_each_way(verdicts), mode)
            results[name]["errors"].append(max(relative_errors(estimate, faults).values()))
            if verbose:
                print(name, mode, faults, outcome.named(), f"{results[name]['errors'][-1]:.4f}")
    out = {}
    for name, r in results.items():
        out[name] = {"ms_per_throw": round(1e3 * float(np.mean(r["seconds"])), 1),
                     "max_rel_error": round(max(r["errors"]), 4), "median_rel_error": round(statistics.median(r["errors"]), 4),
                     "accuracy": round(r["correct"] / len(kept), 4)}
    out["paper_de"]["evaluations_per_throw"] = round(estimator.evaluations / max(len(results["paper_de"]["seconds"]), 1))
    out["cases"], out["throws"] = len(kept), len(results["ours"]["seconds"])
    return out


def mixed_stream(timed: Timed, plant: Plant, noise: float, seed: int, verbose: bool) -> dict:
    """Every (rate, length) of MIXED through the warm diagnoser, then as many plain throws: compiles and latency."""
    latency = {"mixed": [], "plain": []}
    correct = 0
    for name, machines in (("mixed", MIXED), ("plain", [(50.0, 7.0)] * len(MIXED))):
        for k, (rate, length) in enumerate(machines):
            mode, faults = ("left_bolt", {"left_bolt_offset": 0.08}) if k % 2 else ("drive_friction", {"drive_friction_nm": 0.15})
            first = len(timed.seconds)
            diagnoses = run_case(timed, plant, f"{name}{k}", faults, noise, seed + k, rate_hz=rate, stroke_s=length - 0.6)
            latency[name] += [1e3 * s for s in timed.seconds[first:]]
            correct += name == "mixed" and diagnoses[-1].named() == mode
            if verbose:
                print(name, rate, length, mode, diagnoses[-1].named())
            del timed.diagnoser.switches[f"{name}{k}"]
    alarmed = []  # healthy switches of every (rate, length): (rate, length, faulty decisions of HEALTHY_THROWS)
    for k, (rate, length) in enumerate(MIXED):
        # A Timed of its own: these throws stay out of the latency and throughput figures.
        diagnoses = run_case(Timed(timed.diagnoser), plant, f"healthy{k}", {}, noise, seed + 100 + k,
                             throws=HEALTHY_THROWS, rate_hz=rate, stroke_s=length - 0.6)
        faulty = [d.decision for d in diagnoses if d.decision != "nominal"]
        if faulty:
            alarmed.append({"rate_hz": rate, "length_s": length, "decisions": faulty})
        if verbose:
            print("healthy", rate, length, [d.decision for d in diagnoses])
        del timed.diagnoser.switches[f"healthy{k}"]
    return {"compiles": timed.diagnoser.compiles,  # in this process, warm-up included
            "rates_hz": sorted({r for r, _ in MIXED}), "lengths_s": sorted({s for _, s in MIXED}),
            "correct": correct, "switches": len(MIXED),
            "latency_ms": percentiles(latency["mixed"]), "plain_latency_ms": percentiles(latency["plain"]),
            "healthy": {"switches": len(MIXED), "throws": HEALTHY_THROWS * len(MIXED),
                        "false_alarms": sum(len(a["decisions"]) for a in alarmed), "alarmed": alarmed}}


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--model", choices=RAIL_MODELS, default="poly")
    p.add_argument("--seed", type=int, default=None, help="matrix seed (default: drawn and printed)")
    p.add_argument("--per-mode", type=int, default=10, help="random cases per fault mode")
    p.add_argument("--nominal", type=int, default=10, help="random nominal cases")
    p.add_argument("--noise", type=float, default=0.01)
    p.add_argument("--de-cases", type=int, default=5, help="faulty cases the paper's estimator diagnoses too")
    p.add_argument("--skip", action="append", default=[], choices=["current_only", "mixed_stream", "paper_de"],
                   help="leave a part out (repeatable)")
    p.add_argument("--lean", action="store_true", help="a lean diagnoser: no borrowed slopes (benchmarks.memory)")
    args = p.parse_args()
    core = pin_to_one_core()
    seed = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % 2**31)
    verbose = not args.json
    diagnoser = Diagnoser(args.model, lean=args.lean)
    start = time.perf_counter()
    diagnoser.warm_up()
    build_s = time.perf_counter() - start
    timed = Timed(diagnoser)
    plant = compiled_plant()
    latencies: list[float] = []
    paper, worst = paper_scenarios(timed, latencies, verbose)
    cases = draw_cases(seed, args.per_mode, args.nominal)
    accuracy, kept = matrix(timed, plant, cases, seed, args.noise, latencies, verbose,
                            keep=0 if "paper_de" in args.skip else args.de_cases)
    result = {
        "paper_scenarios": {"correct": sum(r["correct"] for r in paper), "total": len(paper),
                            "max_rel_error": round(worst, 4), "cases": paper},
        "matrix": {"seed": seed, "noise": args.noise, **accuracy},
        "latency_ms": percentiles(latencies),
        "throws_per_core_s": round(len(timed.seconds) / sum(timed.seconds), 1),
    }
    if "paper_de" not in args.skip:
        compared = paper_de(timed, kept, verbose)
        result["paper_de"] = compared["paper_de"]
        result["ours_on_paper_de_throws"] = compared["ours"]
        result["speedup_vs_paper_de"] = round(compared["paper_de"]["ms_per_throw"] / compared["ours"]["ms_per_throw"], 1)
    if "current_only" not in args.skip:
        current, _ = matrix(Timed(diagnoser, ("current_a",)), plant, cases, seed, args.noise, [], verbose)
        result["current_only"] = current
    if "mixed_stream" not in args.skip:
        result["mixed_stream"] = mixed_stream(timed, plant, args.noise, seed, verbose)
    result.update({"model": args.model, "lean": args.lean, "build_seconds": round(build_s, 1), "core": core})
    emit(result, args.json)


if __name__ == "__main__":
    main()
