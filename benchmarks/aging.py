"""Switches as they age: several faults at once, standing conditions, slow growth and repairs (issue 38).

Switches drawn from the population (models/plant/population.py), noise 1 %, diagnosed throw by throw from their first
throw (commissioning included) while their weather wanders (the winding's temperature over a day, the chairs
drying and wetting by up to a fifth). Every magnitude is drawn from a range, never a round number. Per
representation:

- stacked: a first fault, then a second of another mode 6 to 10 throws later, for every ordered pair of the five
  modes (a pair of bolts once: they never share a throw), at least 28 throws, at least 8 of them after the second
  fault's onset. `both_named`: both are in the diagnosis's `faults` on each of the last 4 throws; `masked`: the first
  was named before the second came and is gone from them at the end; `extra`: sequences that end with a fault
  present that is not.
- ramps: bearing friction growing 250 to 350 N·s/m a throw, drive friction and a bolt creeping so that they reach
  their limits (models/health/prognosis.py DEFAULT_LIMITS) in 18 to 30 throws, from a random throw after commissioning on.
  `held_at_fraction_of_limit`: the true value over the limit when the mode entered `faults` for good;
  `alarm_throws_before_limit`: the throw at which the truth reaches its limit less the first throw whose health
  state is `alarm` (the 50th percentile over the ramps, and every ramp's).
- repairs: a fault of each mode, or a bearing that grew slowly, present and named, then repaired without a word.
  `seen_within_throws`: throws from the repair until the mode leaves `faults` for good (1: at the repair's own
  throw); a bolt is set right before a throw it drives (set while the blades rest short against it, after a throw of
  the other direction, the plant's contact would push them across at once, which no fitter's adjustment does); `level_after_repair_max_fraction_of_limit`: the largest health level of the repaired parameter over its
  limit, from the third throw after the repair on.
- standing: switches whose rolling losses are 1.3 to 2 times the population's from their installation, with a fault
  of another mode 14 to 18 throws in; every other one accepted (`commission --accept`) at throw 12. `later_fault_named`:
  the later fault is in `faults` on each of the last 4 throws.
- healthy: every throw after commissioning before any fault (a throw whose `faults` is not empty is a false alarm),
  and healthy switches through a dry spell (chairs up to 1.8 times as dry over 12 throws, and back) or a wet one.
"""
from __future__ import annotations

import itertools
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from benchmarks.common import emit, parser
from railswitch.models.health.prognosis import DEFAULT_LIMITS
from railswitch.models.plant.population import draw_switch
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.schemas import RAIL_MODELS
from railswitch.schemas.faults import FAULT_MODES
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.switch_messages import SimulatedThrows

MAGNITUDE = {"left_bolt": "left_bolt_offset", "right_bolt": "right_bolt_offset", "missing_bearing": "bearing_friction",
             "obstacle": "obstacle_friction", "drive_friction": "drive_friction_nm"}
COMMISSIONED = 2 * COMMISSIONING_THROWS
BOLT_DIRECTION = {"left_bolt": 0, "right_bolt": 1}  # throws alternate, left to right first: a bolt's throws' parity
STEADY = 4  # the last throws on which a fault must be named
FIRST_SEED = 900_000  # switches apart from every calibration's, benchmark's and test's


def draw_fault(mode: str, rng: np.random.Generator) -> dict[str, float]:
    """One fault of `mode` at a magnitude like a real one's (a loose bolt, a missing bearing, a stone, a worn machine)."""
    if mode in ("left_bolt", "right_bolt"):
        return {MAGNITUDE[mode]: float(rng.uniform(0.015, 0.09))}
    if mode == "missing_bearing":
        return {"bearing_friction": float(rng.uniform(2000.0, 7000.0))}
    if mode == "obstacle":
        return {"obstacle_friction": float(np.exp(rng.uniform(np.log(3e4), np.log(1.2e5)))),
                "obstacle_position": float(rng.uniform(1.03, 1.17))}
    return {"drive_friction_nm": float(rng.uniform(0.04, 0.2))}


@dataclass
class Sequence:
    """One switch's life: its population seed, its own build changes, and its faults (each parameter's value) before
    every throw; `accept_at`: the throw before which an operator accepts the switch as it is."""

    kind: str
    seed: int
    faults: list[dict[str, float]]
    own_factor: dict[str, float] = field(default_factory=dict)
    chairs: list[float] | None = None  # the chairs' friction factor before every throw (a dry or wet spell)
    accept_at: int | None = None
    info: dict = field(default_factory=dict)


def stacked(rng: np.random.Generator, seed: int, first: str, second: str) -> Sequence:
    onset = COMMISSIONED + int(rng.integers(2, 6))
    later = onset + int(rng.integers(6, 11))
    throws = max(28, later + 8)
    a, b = draw_fault(first, rng), draw_fault(second, rng)
    faults = [{} if k < onset else dict(a) if k < later else {**a, **b} for k in range(throws)]
    return Sequence("stacked", seed, faults, info={"first": first, "second": second, "onset": onset, "later": later})


def ramp(rng: np.random.Generator, seed: int, parameter: str) -> Sequence:
    limit = DEFAULT_LIMITS[parameter]
    if parameter == "bearing_friction":
        rate = float(rng.uniform(250.0, 350.0))
    else:
        rate = limit / float(rng.uniform(18.0, 30.0))
    onset = COMMISSIONED + int(rng.integers(3, 8))
    reach = int(np.ceil(limit / rate))  # throws after the onset to the limit
    throws = onset + reach + 6
    faults = [{parameter: rate * (k - onset + 1)} if k >= onset else {} for k in range(throws)]
    return Sequence("ramp", seed, faults, info={"parameter": parameter, "onset": onset, "rate": rate})


def repair(rng: np.random.Generator, seed: int, mode: str, slow: bool = False) -> Sequence:
    onset = COMMISSIONED + int(rng.integers(2, 5))
    if slow:  # a bearing that grew slowly to most of its limit, then repaired
        rate = float(rng.uniform(250.0, 350.0))
        grown = int(rng.integers(10, 15))
        values = [{"bearing_friction": rate * (k + 1)} for k in range(grown)]
    else:
        fault = draw_fault(mode, rng)
        values = [dict(fault)] * int(rng.integers(6, 10))
    repaired_at = onset + len(values)
    if mode in BOLT_DIRECTION and repaired_at % 2 != BOLT_DIRECTION[mode]:
        repaired_at += 1  # a bolt is set right before a throw it drives (see the module's docstring)
        values.append(values[-1])
    throws = repaired_at + 10
    faults = [{} if k < onset else values[k - onset] if k < repaired_at else {} for k in range(throws)]
    return Sequence("repair", seed, faults, info={"mode": mode, "onset": onset, "repaired_at": repaired_at,
                                                  "slow": slow})


def standing(rng: np.random.Generator, seed: int, later_mode: str, accept: bool) -> Sequence:
    factor = float(rng.uniform(1.3, 2.0))
    later = int(rng.integers(14, 19))
    throws = later + 12
    fault = draw_fault(later_mode, rng)
    faults = [{} if k < later else dict(fault) for k in range(throws)]
    return Sequence("standing", seed, faults, own_factor={"rail.chair_viscous_n_s_m": factor},
                    accept_at=12 if accept else None,
                    info={"mode": later_mode, "later": later, "rolling_losses": factor, "accepted": accept})


def spell(rng: np.random.Generator, seed: int, dry: bool) -> Sequence:
    """A healthy switch through a dry (or wet) spell: its chairs' friction moves over 12 throws and back."""
    peak = float(rng.uniform(1.4, 1.8)) if dry else float(rng.uniform(0.6, 0.75))
    throws = COMMISSIONED + 30
    start = COMMISSIONED + int(rng.integers(2, 6))
    chairs = []
    for k in range(throws):
        phase = min(max((k - start) / 12.0, 0.0), 2.0)
        share = phase if phase <= 1.0 else 2.0 - phase
        chairs.append(1.0 + (peak - 1.0) * share)
    return Sequence("spell", seed, [{}] * throws, chairs=chairs, info={"peak": peak})


def plan(seed: int, pair_seeds: int, ramp_seeds: int) -> list[Sequence]:
    rng = np.random.default_rng(seed)
    sequences: list[Sequence] = []
    next_seed = itertools.count(FIRST_SEED + seed * 10_000)
    for first, second in itertools.permutations(FAULT_MODES, 2):
        if {first, second} == {"left_bolt", "right_bolt"} and first == "right_bolt":
            continue
        for _ in range(pair_seeds):
            sequences.append(stacked(rng, next(next_seed), first, second))
    for parameter in ("bearing_friction", "drive_friction_nm", "left_bolt_offset", "right_bolt_offset"):
        for _ in range(ramp_seeds):
            sequences.append(ramp(rng, next(next_seed), parameter))
    for mode in FAULT_MODES:
        for _ in range(2):
            sequences.append(repair(rng, next(next_seed), mode))
    for _ in range(3):
        sequences.append(repair(rng, next(next_seed), "missing_bearing", slow=True))
    later_modes = ("left_bolt", "right_bolt", "obstacle", "drive_friction")
    for k in range(8):
        sequences.append(standing(rng, next(next_seed), later_modes[k % 4], accept=k % 2 == 1))
    for k in range(6):
        sequences.append(spell(rng, next(next_seed), dry=k % 3 != 2))
    return sequences


def weather(own: dict[str, float], throw: int, phase: float, chairs: float) -> dict[str, float]:
    out = dict(own)
    out["motor.resistance_ohm"] = own["motor.resistance_ohm"] * (1 + 0.04 * np.sin(2 * np.pi * throw / 100 + phase))
    out["rail.chair_friction_coefficient"] = own["rail.chair_friction_coefficient"] * chairs
    return out


def run(args: tuple[Sequence, str, float]) -> dict:
    """Diagnose one sequence throw by throw: what the judging needs of every throw."""
    sequence, model, noise = args
    diagnoser = Diagnoser(model)
    own = draw_switch(sequence.seed).plant
    for name, factor in sequence.own_factor.items():
        own[name] *= factor
    rng = np.random.default_rng(sequence.seed)
    phase = float(rng.uniform(0.0, 2 * np.pi))
    wander = float(rng.uniform(-0.2, 0.2))  # the chairs' slow drift over the sequence
    sim = SwitchSimulation(compiled_plant(), own=own, noise_rel=noise, seed=sequence.seed)
    source = SimulatedThrows("aging", sim)
    rows = []
    for throw, faults in enumerate(sequence.faults):
        chairs = sequence.chairs[throw] if sequence.chairs else 1.0 + wander * throw / len(sequence.faults)
        sim.set_own(weather(own, throw, phase, chairs))
        sim.set_faults({name: value for name, value in faults.items() if value})
        if sequence.accept_at == throw:
            diagnoser.commission(source.switch_id, accept=True)
        diagnosed = diagnoser.diagnose(source.next())
        d, health = diagnosed.diagnosis, diagnosed.health
        levels = {p.name: p.level for p in health.parameters} if health is not None else {}
        rows.append({"faults": list(d.faults or []), "decision": d.decision, "direction": d.direction,
                     "sizes": {e.mode: {n: round(v, 4) for n, v in e.params.items()} for e in d.estimates},
                     "state": health.state if health is not None else "ok",
                     "states": {p.name: p.state for p in health.parameters} if health is not None else {},
                     "levels": levels, "commissioned": d.commissioning is not None
                     and d.commissioning.state == "commissioned", "latency_ms": d.latency_ms})
    return {"sequence": sequence, "rows": rows}


def named_for_good(rows: list[dict], mode: str) -> int | None:
    """The first throw from which `mode` is in `faults` on every later throw."""
    first = None
    for k, row in enumerate(rows):
        if mode in row["faults"]:
            first = k if first is None else first
        else:
            first = None
    return first


def gone_for_good(rows: list[dict], mode: str, since: int) -> int | None:
    for k in range(since, len(rows)):
        if all(mode not in row["faults"] for row in rows[k:]):
            return k
    return None


def judge(results: list[dict]) -> dict:
    out: dict = {}
    stacked_runs = [r for r in results if r["sequence"].kind == "stacked"]
    both = masked = extra = 0
    failures = []
    for result in stacked_runs:
        s, rows = result["sequence"], result["rows"]
        first, second = s.info["first"], s.info["second"]
        steady = rows[-STEADY:]
        named = all(first in row["faults"] and second in row["faults"] for row in steady)
        both += named
        was_named = any(first in row["faults"] for row in rows[s.info["onset"]:s.info["later"]])
        masked += was_named and first not in rows[-1]["faults"]
        extra += bool(set(rows[-1]["faults"]) - {first, second})
        if not named or set(rows[-1]["faults"]) - {first, second}:
            failures.append({"pair": [first, second], "seed": s.seed, "end": rows[-1]["faults"],
                             "extra": {m: rows[-1]["sizes"].get(m) for m in set(rows[-1]["faults"]) - {first, second}},
                             "since": next((k for k, row in enumerate(rows) if set(row["faults"]) - {first, second}),
                                           None)})
    out["stacked"] = {"sequences": len(stacked_runs), "both_named": round(both / max(len(stacked_runs), 1), 4),
                      "masked": masked, "extra": extra, "failures": failures}

    held, before, per_ramp = [], [], []
    for result in (r for r in results if r["sequence"].kind == "ramp"):
        s, rows = result["sequence"], result["rows"]
        parameter = s.info["parameter"]
        mode = next(m for m, p in MAGNITUDE.items() if p == parameter)
        limit = DEFAULT_LIMITS[parameter]
        truth = [f.get(parameter, 0.0) for f in s.faults]
        limit_throw = next(k for k, v in enumerate(truth) if v >= limit)
        k_held = named_for_good(rows, mode)
        fraction = truth[k_held] / limit if k_held is not None else None
        alarm = next((k for k, row in enumerate(rows) if k >= s.info["onset"] and row["state"] == "alarm"), None)
        ahead = limit_throw - alarm if alarm is not None else None
        held.append(fraction if fraction is not None else 2.0)
        before.append(ahead if ahead is not None else -99)
        per_ramp.append({"parameter": parameter, "rate": round(s.info["rate"], 5), "held_at": None if fraction is None
                         else round(fraction, 3), "alarm_throws_before_limit": ahead})
    out["ramps"] = {"ramps": len(per_ramp), "held_at_fraction_of_limit_p50": round(float(np.median(held)), 3),
                    "alarm_throws_before_limit_p50": float(np.median(before)), "per_ramp": per_ramp}

    seen, after_levels, per_repair = [], [], []
    for result in (r for r in results if r["sequence"].kind == "repair"):
        s, rows = result["sequence"], result["rows"]
        mode, at = s.info["mode"], s.info["repaired_at"]
        parameter = MAGNITUDE[mode]
        named = any(mode in row["faults"] for row in rows[s.info["onset"]:at])
        gone = gone_for_good(rows, mode, at)
        within = (gone - at + 1) if gone is not None else len(rows) - at + 1
        level = max((abs(row["levels"].get(parameter, 0.0)) for row in rows[at + 2:]), default=0.0)
        fraction = level / DEFAULT_LIMITS[parameter]
        if named:
            seen.append(within)
        after_levels.append(fraction)
        per_repair.append({"mode": mode, "slow": s.info["slow"], "named_before": named, "seen_within": within,
                           "level_after_fraction": round(fraction, 3)})
    out["repairs"] = {"repairs": len(per_repair),
                      "seen_within_throws_p95": float(np.percentile(seen, 95)) if seen else None,
                      "level_after_repair_max_fraction_of_limit": round(max(after_levels), 3) if after_levels else None,
                      "per_repair": per_repair}

    standing_runs = [r for r in results if r["sequence"].kind == "standing"]
    named = 0
    per_standing = []
    for result in standing_runs:
        s, rows = result["sequence"], result["rows"]
        ok = all(s.info["mode"] in row["faults"] for row in rows[-STEADY:])
        named += ok
        per_standing.append({"mode": s.info["mode"], "rolling_losses": round(s.info["rolling_losses"], 2),
                             "accepted": s.info["accepted"], "named": ok, "end": rows[-1]["faults"],
                             "sizes": rows[-1]["sizes"]})
    out["standing"] = {"sequences": len(standing_runs), "later_fault_named": round(named / max(len(standing_runs), 1), 4),
                       "per_sequence": per_standing}

    healthy = alarms = 0
    alarmed = []
    for result in results:
        s, rows = result["sequence"], result["rows"]
        if s.kind == "standing":
            continue
        commissioned = next((k for k, row in enumerate(rows) if row["commissioned"]), len(rows))
        clean_until = next((k for k, f in enumerate(s.faults) if f), len(rows))
        for k in range(commissioned + 1, clean_until):
            healthy += 1
            if rows[k]["faults"]:
                alarms += 1
                alarmed.append({"kind": s.kind, "seed": s.seed, "throw": k, "faults": rows[k]["faults"]})
    out["healthy"] = {"throws": healthy, "false_alarms_per_1000": round(1000.0 * alarms / max(healthy, 1), 2),
                      "alarmed": alarmed}
    latencies = [row["latency_ms"] for r in results for row in r["rows"]]
    out["latency_ms"] = {"p50": round(float(np.percentile(latencies, 50)), 1),
                         "p95": round(float(np.percentile(latencies, 95)), 1)}
    return out


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--model", choices=(*RAIL_MODELS, "all"), default="all")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--pair-seeds", type=int, default=2, help="sequences per ordered pair of modes")
    p.add_argument("--ramp-seeds", type=int, default=3, help="ramps per growing parameter")
    p.add_argument("--noise", type=float, default=0.01)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--only", action="append", choices=("stacked", "ramp", "repair", "standing", "spell"),
                   help="run these kinds of sequences alone")
    args = p.parse_args()
    models = RAIL_MODELS if args.model == "all" else (args.model,)
    sequences = [s for s in plan(args.seed, args.pair_seeds, args.ramp_seeds) if not args.only or s.kind in args.only]
    result: dict = {"seed": args.seed, "sequences": len(sequences), "throws": sum(len(s.faults) for s in sequences)}
    with ProcessPoolExecutor(args.workers) as pool:
        for model in models:
            results = list(pool.map(run, [(s, model, args.noise) for s in sequences], chunksize=1))
            result[model] = judge(results)
            if not args.json:
                print(model, {k: {n: v for n, v in section.items() if not isinstance(v, list)}
                              for k, section in result[model].items() if isinstance(section, dict)}, flush=True)
    emit(result, args.json)


if __name__ == "__main__":
    main()
