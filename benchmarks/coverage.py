"""Whether a reported standard deviation keeps its promise, on held-out switches.

A sweep of single faults over every mode, their sizes drawn across their ranges (between any grid's
points), on population switches apart from every calibration, benchmark and test switch: each
commissioned on its own healthy throws, its weather then changed as the calibration changes it
(winding, supply, chairs), then six throws with the fault. For every throw decided as the true mode,
z = (estimate - truth) / std of the decided fault's estimate (`Diagnosis.estimate`, combined over the
throws since it appeared). Prints, per fault parameter, how often the truth lies within +-2 std after
the first throw that decides the fault and after the last (target: about 95 %), z's 5/50/95 %
quantiles, and the cases decided otherwise.
"""
from __future__ import annotations

import numpy as np

from benchmarks.common import emit, parser, pin_to_one_core
from railswitch.models.plant.population import draw_switch
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.schemas import RAIL_MODELS
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.core.calibration import FAULTY_THROWS, NOISE, changed_weather, fault_cases
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.switch_messages import SimulatedThrows

FIRST_SEED = 700_000  # apart from the calibration's (500 000 on), the fleet's and the tests'
COMMISSIONING = 8  # healthy throws, four each way


def summary(rows: list[tuple[float, float]]) -> dict:
    """Coverage of +-2 std after the first and the last deciding throw, and z's quantiles after the last."""
    first, last = np.array(rows).T
    return {"cases": len(rows), "coverage_first": round(float(np.mean(np.abs(first) <= 2.0)), 3),
            "coverage_last": round(float(np.mean(np.abs(last) <= 2.0)), 3),
            "z_quantiles_last": [round(float(q), 2) for q in np.quantile(last, [0.05, 0.5, 0.95])]}


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--model", choices=RAIL_MODELS, default="poly")
    p.add_argument("--per-mode", type=int, default=30, help="faulty switches per fault mode")
    p.add_argument("--seed", type=int, default=1, help="which held-out switches (and fault sizes)")
    args = p.parse_args()
    if args.per_mode < 1:
        p.error(f"--per-mode {args.per_mode}: must be at least 1")
    core = pin_to_one_core()
    plant = compiled_plant()
    diagnoser = Diagnoser(args.model)
    diagnoser.warm_up()
    z: dict[str, list[tuple[float, float]]] = {}
    missed = []
    cases = fault_cases(args.per_mode, FIRST_SEED + 1000 * args.seed)
    for case in cases:
        switch_id = f"c{case.seed}"
        sim = SwitchSimulation(plant, own=draw_switch(case.seed).plant, noise_rel=NOISE, seed=case.seed)
        source = SimulatedThrows(switch_id, sim)
        for _ in range(COMMISSIONING):
            diagnoser.diagnose(source.next())
        sim.set_own(changed_weather(sim.own, np.random.default_rng(case.seed)))
        sim.set_faults(case.faults)
        seen: dict[str, list[float]] = {}
        for _ in range(FAULTY_THROWS):
            d = diagnoser.diagnose(source.next()).diagnosis
            estimate = d.estimate_of(case.mode)
            if estimate is not None:
                for name, truth in case.faults.items():
                    seen.setdefault(name, []).append((estimate.params[name] - truth) / estimate.std[name])
        if not seen:
            missed.append({"mode": case.mode, "faults": {n: round(v, 4) for n, v in case.faults.items()},
                           "decision": d.named()})
        for name, values in seen.items():
            z.setdefault(name, []).append((values[0], values[-1]))
        if not args.json:
            print(case.mode, {n: round(v, 4) for n, v in case.faults.items()},
                  {n: round(v[-1], 2) for n, v in seen.items()} or d.named(), flush=True)
        del diagnoser.switches[switch_id]
    every = [pair for rows in z.values() for pair in rows]
    emit({"model": args.model, "seed": args.seed, "cases": len(cases),
          **{key: value for key, value in summary(every).items() if key != "cases"},
          "per_parameter": {name: summary(rows) for name, rows in sorted(z.items())},
          "not_decided_as_the_fault": missed, "core": core}, args.json)


if __name__ == "__main__":
    main()
