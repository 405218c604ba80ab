"""Health over time: slowly degrading switches, their trends and throws to the limit (issue 15).

Switches drawn from the population (models/plant/population.py), noise 1 %, each commissioned on its own
first healthy throws, then healthy for a while. A few stay healthy to the end (controls); the others
degrade gradually until past their maintenance limit (models/health/prognosis.py DEFAULT_LIMITS): bearing
friction rising linearly to 1.3 times its limit over 150 to 300 throws, a bolt loosening a few
millimetres at a time (a step every 10 to 25 throws), or drive friction growing linearly. Every switch's
weather wanders meanwhile: the chairs' friction drifts slowly by up to 20 % and the winding's
temperature follows a daily cycle (resistance +-4 %).

Measured, per degrading switch and its degrading parameter:
- throws to limit: the tracker's prediction against the truth (the schedule's first throw at or past
  the limit) when the true value is halfway from the commissioned level to the limit; its interval's
  coverage at 40, 50, 60 and 70 % of the way;
- detection delay: the first throw in state `alarm` minus the first throw whose true value reaches the
  limit (negative: warned ahead of the limit);
- alarm flaps: a switch's state going down again after it went up;
- false alarms: healthy throws (controls, and degrading switches before their onset) decided as a fault
  or in state `alarm`, per 1000.
Switches are diagnosed in two processes (one per core); the historian's figures come from
benchmarks/historian.py on a 100 000-row database.
"""
from __future__ import annotations

import statistics
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from benchmarks.common import emit, parser
from railswitch.models.health.prognosis import DEFAULT_LIMITS, STATES
from railswitch.models.plant.population import draw_switch
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.schemas import RAIL_MODELS
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.switch_messages import SimulatedThrows

KINDS = ("bearing_friction", "left_bolt_offset", "right_bolt_offset", "drive_friction_nm")
OVERSHOOT = 1.3  # degradation runs to this many times the limit
AFTER_LIMIT = 10  # throws diagnosed past the limit
FRACTIONS = (0.4, 0.5, 0.6, 0.7)  # of the way to the limit, where the interval's coverage is judged


@dataclass
class Plan:
    """One switch: population seed, degrading parameter (None: a control), its true value before every throw."""

    switch_id: str
    seed: int
    parameter: str | None
    truth: list[float] = field(default_factory=list)
    onset: int = 0

    def limit_throw(self) -> int | None:
        limit = DEFAULT_LIMITS.get(self.parameter, np.inf)
        return next((k for k, v in enumerate(self.truth) if v >= limit), None)


def plan_switches(seed: int, switches: int, controls: int, healthy_throws: int) -> list[Plan]:
    rng = np.random.default_rng(seed)
    plans = []
    for k in range(switches):
        parameter = None if k < controls else KINDS[(k - controls) % len(KINDS)]
        plan = Plan(f"p{k}", seed * 1000 + k, parameter)
        commissioned = 2 * COMMISSIONING_THROWS
        plan.onset = commissioned + int(rng.integers(10, 40))
        if parameter is None:
            plan.truth = [0.0] * (commissioned + healthy_throws)
        else:
            span = int(rng.integers(150, 301))  # throws from onset to OVERSHOOT x the limit
            top = OVERSHOOT * DEFAULT_LIMITS[parameter]
            if parameter.endswith("bolt_offset"):  # loosening a few millimetres at a time
                steps, k_step = [], 0
                while k_step < span:
                    steps.append(k_step)
                    k_step += int(rng.integers(10, 26))
                rise = [top * (1 + sum(s <= t for s in steps[1:])) / len(steps) for t in range(span)]
            else:
                rise = list(np.linspace(top / span, top, span))
            past = next(t for t, v in enumerate(rise) if v >= DEFAULT_LIMITS[parameter])
            plan.truth = [0.0] * plan.onset + rise[:past + AFTER_LIMIT]
        plans.append(plan)
    return plans


def weather(own: dict[str, float], throw: int, rng_phase: float, drift: float) -> dict[str, float]:
    """The switch's own parameters at a throw: chairs drifting by up to `drift`, a daily temperature cycle
    (about 100 throws a day) in the winding's resistance."""
    out = dict(own)
    out["rail.chair_friction_coefficient"] = own["rail.chair_friction_coefficient"] * (1 + drift * np.sin(throw / 400 + rng_phase))
    out["motor.resistance_ohm"] = own["motor.resistance_ohm"] * (1 + 0.04 * np.sin(2 * np.pi * throw / 100 + rng_phase))
    return out


def run_switch(args: tuple[Plan, str, float]) -> dict:
    """Diagnose one planned switch throw by throw; what the metrics need of every throw."""
    plan, model, noise = args
    diagnoser = Diagnoser(model)
    own = draw_switch(plan.seed).plant
    rng = np.random.default_rng(plan.seed)
    phase, drift = float(rng.uniform(0, 2 * np.pi)), float(rng.uniform(0.0, 0.2))
    sim = SwitchSimulation(compiled_plant(), own=own, noise_rel=noise, seed=plan.seed)
    source = SimulatedThrows(plan.switch_id, sim)
    rows = []
    for throw, value in enumerate(plan.truth):
        sim.set_own(weather(own, throw, phase, drift))
        sim.set_faults({plan.parameter: value} if plan.parameter and value > 0 else {})
        diagnosed = diagnoser.diagnose(source.next())
        health = diagnosed.health
        mine = None
        if health is not None and plan.parameter is not None:
            mine = next((p for p in health.parameters if p.name == plan.parameter), None)
        rows.append({"decision": diagnosed.diagnosis.decision, "state": health.state if health else "ok",
                     "to_limit": None if mine is None else mine.throws_to_limit,
                     "low": None if mine is None else mine.throws_to_limit_low,
                     "high": None if mine is None else mine.throws_to_limit_high,
                     "commissioned": diagnosed.diagnosis.commissioning.state == "commissioned"})
    return {"plan": plan, "rows": rows}


def flaps(states: list[str]) -> int:
    """How often the state went down again (a state that went up and came back)."""
    ranks = [STATES.index(s) for s in states]
    return sum(b < a for a, b in zip(ranks, ranks[1:]))


def judge(results: list[dict]) -> dict:
    errors, covered, delays, healthy, false_alarms = [], [], [], 0, 0
    control_flaps, degrading_flaps = 0, []
    for result in results:
        plan, rows = result["plan"], result["rows"]
        commissioned = next((k for k, r in enumerate(rows) if r["commissioned"]), len(rows))
        healthy_rows = rows[commissioned + 1:plan.onset] if plan.parameter else rows[commissioned + 1:]
        healthy += len(healthy_rows)
        false_alarms += sum(r["decision"] != "nominal" or r["state"] == "alarm" for r in healthy_rows)
        states = [r["state"] for r in rows[commissioned + 1:]]
        if plan.parameter is None:
            control_flaps += flaps(states)
            continue
        degrading_flaps.append(flaps(states))
        limit_throw = plan.limit_throw()
        limit = DEFAULT_LIMITS[plan.parameter]
        for fraction in FRACTIONS:
            at = next(k for k, v in enumerate(plan.truth) if v >= fraction * limit)
            row, remaining = rows[at], limit_throw - at
            if fraction == 0.5:
                predicted = row["to_limit"]
                errors.append(abs(predicted - remaining) / remaining if predicted is not None else 1.0)
            covered.append(row["low"] is not None and row["high"] is not None and row["low"] <= remaining <= row["high"])
        alarm = next((k for k, r in enumerate(rows) if r["state"] == "alarm" and k >= plan.onset), None)
        delays.append((alarm if alarm is not None else len(rows)) - limit_throw)
    return {"median_detection_delay_throws": float(statistics.median(delays)),
            "throws_to_limit_median_rel_error": round(float(statistics.median(errors)), 4),
            "interval_coverage": round(float(np.mean(covered)), 4),
            "alarm_flaps": {"controls": control_flaps, "degrading_max": max(degrading_flaps),
                            "degrading_total": sum(degrading_flaps)},
            "false_alarms_per_1000_throws": round(1000.0 * false_alarms / max(healthy, 1), 2),
            "healthy_throws": healthy, "delays": delays,
            "rel_errors": [round(e, 3) for e in errors]}


def historian_figures() -> dict:
    try:
        from benchmarks.historian import measure
    except ImportError as error:
        return {"missing": str(error)}
    return measure()


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--model", choices=RAIL_MODELS, default="poly")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--switches", type=int, default=24)
    p.add_argument("--controls", type=int, default=4)
    p.add_argument("--healthy-throws", type=int, default=250, help="throws of a control after commissioning")
    p.add_argument("--noise", type=float, default=0.01)
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args()
    plans = plan_switches(args.seed, args.switches, args.controls, args.healthy_throws)
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(run_switch, [(plan, args.model, args.noise) for plan in plans]))
    result = {"switches": len(plans), "controls": args.controls, "throws": sum(len(p.truth) for p in plans),
              **judge(results), "historian": historian_figures(), "model": args.model, "seed": args.seed}
    emit(result, args.json)


if __name__ == "__main__":
    main()
