"""A fleet of switches that are not the model's twin (issue 14).

Switches drawn from the population (models/population.py), noise 1 %, each commissioned on its
own first healthy throws, then healthy for the rest of its run or carrying one fault from a
random throw on (every mode, magnitudes across their ranges); some go through a cold night
(winding resistance down 10 %, supply sagging 7 %) or chairs drying out to twice their friction
over the run. Prints the false alarms
per 1000 healthy throws, detection, isolation, the relative error of the decided fault's size,
how often the truth lies within +-2 standard deviations (per throw, and per switch from its latest estimate), the
detection delay and the latency.
"""
from __future__ import annotations

import statistics
from dataclasses import dataclass, field

import numpy as np

from benchmarks.common import emit, parser, pin_to_one_core
from railswitch.models.estimation import DRIVING_BOLT
from railswitch.models.population import draw_switch
from railswitch.models.switch import SwitchSimulation
from railswitch.schemas import RAIL_MODELS, Diagnosis
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.core.calibration import fault_cases
from railswitch.services.core.fleet_diagnoser import Diagnoser
from railswitch.services.core.switch_messages import SimulatedThrows

MAGNITUDE = {"left_bolt": "left_bolt_offset", "right_bolt": "right_bolt_offset", "missing_bearing": "bearing_friction",
             "obstacle": "obstacle_friction", "drive_friction": "drive_friction_nm"}


@dataclass
class SwitchRun:
    """One switch's plan: its population seed, fault (if any) and onset, and weather changes by throw."""

    switch_id: str
    seed: int
    mode: str | None = None
    faults: dict[str, float] = field(default_factory=dict)
    onset: int | None = None
    weather: dict[int, dict[str, float]] = field(default_factory=dict)  # throw -> own parameters from then on


def plan_fleet(seed: int, switches: int, throws: int, commissioning: int) -> list[SwitchRun]:
    rng = np.random.default_rng(seed)
    cases = fault_cases(max(1, switches // 6), seed * 1000 + 7)
    runs = []
    for k in range(switches):
        run = SwitchRun(f"f{k}", seed * 1000 + 100 + k)
        if k % 4 != 0 and cases:  # three switches in four get a fault
            case = cases.pop(0)
            run.mode, run.faults = case.mode, case.faults
            run.onset = int(rng.integers(commissioning + 1, throws - 3))
        own = draw_switch(run.seed).plant
        kind = k % 5
        if kind == 1:  # a cold night: the winding 25 K colder and the supply sagging, for four throws
            night = int(rng.integers(commissioning + 1, throws - 4))
            run.weather[night] = {**own, "motor.resistance_ohm": own["motor.resistance_ohm"] * (1 - 0.00393 * 25),
                                  "motor.supply_v": own["motor.supply_v"] * 0.93}
            run.weather[night + 4] = dict(own)
        elif kind == 3:  # chairs drying out: twice the friction by the end of the run
            for throw in range(commissioning, throws):
                share = (throw - commissioning + 1) / (throws - commissioning)
                run.weather[throw] = {**own, "rail.chair_friction_coefficient":
                                      own["rail.chair_friction_coefficient"] * (1 + share)}
        runs.append(run)
    return runs


def visible(run: SwitchRun, throw: int, direction: str, seen: bool) -> bool:
    """Whether the fault can show in this throw: after its onset, and a bolt from its first driving throw on."""
    if run.mode is None or throw < run.onset:
        return False
    return run.mode not in DRIVING_BOLT.values() or seen or DRIVING_BOLT[direction] == run.mode


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--model", choices=RAIL_MODELS, default="poly")
    p.add_argument("--seed", type=int, default=None, help="fleet seed (default: drawn and printed)")
    p.add_argument("--switches", type=int, default=60)
    p.add_argument("--throws", type=int, default=24, help="throws per switch")
    p.add_argument("--noise", type=float, default=0.01)
    args = p.parse_args()
    core = pin_to_one_core()
    seed = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % 2**31)
    plant = compiled_plant()
    diagnoser = Diagnoser(args.model)
    diagnoser.warm_up()
    commissioning = 2 * 4
    runs = plan_fleet(seed, args.switches, args.throws, commissioning)
    healthy = false_alarms = 0
    latencies, delays, rel_errors, covered = [], [], [], []
    last_z: dict[tuple[str, str], float] = {}  # (switch, parameter) -> z of its latest estimate
    faults = detected = isolated = 0
    for run in runs:
        own = draw_switch(run.seed).plant
        sim = SwitchSimulation(plant, own=own, noise_rel=args.noise, seed=run.seed)
        source = SimulatedThrows(run.switch_id, sim)
        seen, first_visible, first_detected = False, None, None
        last: Diagnosis | None = None
        for throw in range(args.throws):
            if throw in run.weather:
                sim.set_own(run.weather[throw])
            if run.mode is not None and throw == run.onset:
                sim.set_faults(run.faults)
            item = diagnoser.diagnose(source.next())
            d = item.diagnosis
            latencies.append(d.latency_ms)
            shows = visible(run, throw, d.direction, seen)
            seen = seen or shows
            if run.mode is None or throw < run.onset:
                healthy += 1
                false_alarms += d.decision != "nominal"
                continue
            if not shows:
                continue
            first_visible = throw if first_visible is None else first_visible
            if d.decision != "nominal" and first_detected is None:
                first_detected = throw
            estimate = d.estimate_of(run.mode)
            if estimate is not None:
                for name, value in estimate.params.items():
                    covered.append((name, abs(value - run.faults[name]) <= 2 * estimate.std[name],
                                    (value - run.faults[name]) / estimate.std[name]))
                    last_z[run.switch_id, name] = covered[-1][2]
            last = d
        if run.mode is not None:
            faults += 1
            if first_detected is not None:
                detected += 1
                delays.append(first_detected - first_visible)
            if last is not None and last.named() == run.mode:  # the fault alone, nothing beside it
                isolated += 1
                truth = run.faults[MAGNITUDE[run.mode]]
                rel_errors.append(abs(last.estimate_of(run.mode).params[MAGNITUDE[run.mode]] - truth) / abs(truth))
        if not args.json:
            print(run.switch_id, run.mode, run.faults, "onset", run.onset, "last", last.named() if last else None,
                  last.estimate.params if last and last.estimate else "", flush=True)
        del diagnoser.switches[run.switch_id]
    emit({
        "switches": len(runs), "seed": seed, "model": args.model, "noise": args.noise,
        "healthy_throws": healthy,
        "false_alarms_per_1000_throws": round(1000.0 * false_alarms / max(healthy, 1), 2),
        "faults": faults, "detected": detected,
        "isolation_accuracy": round(isolated / max(faults, 1), 4),
        "median_rel_error": round(statistics.median(rel_errors), 4) if rel_errors else None,
        "interval_coverage": round(float(np.mean([c for _, c, _ in covered])), 4) if covered else None,
        # each switch once: its latest estimate of each parameter (a switch's throws share its model error, so the
        # per-throw figure above moves in steps of a whole switch's throws)
        "interval_coverage_per_switch": round(float(np.mean(np.abs(list(last_z.values())) <= 2.0)), 4) if last_z else None,
        "interval_switch_parameters": len(last_z),
        "interval_coverage_per_parameter": {name: round(float(np.mean([c for n, c, _ in covered if n == name])), 3)
                                            for name in sorted({n for n, _, _ in covered})},
        "z_quantiles": {name: [round(float(q), 2) for q in np.quantile([z for n, _, z in covered if n == name], [0.05, 0.5, 0.95])]
                        for name in sorted({n for n, _, _ in covered})},
        "median_detection_delay_throws": statistics.median(delays) if delays else None,
        "latency_ms": {"p50": round(float(np.percentile(latencies, 50)), 1),
                       "p95": round(float(np.percentile(latencies, 95)), 1)},
        "core": core,
    }, args.json)


if __name__ == "__main__":
    main()
