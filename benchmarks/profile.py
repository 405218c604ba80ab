"""Where one throw's diagnosis spends its time (issue 42): per phase and per hypothesis, on one core.

The throws are benchmarks.diagnosis's matrix (the same seed draws the same cases): each switch commissioned on its
healthy throws, then two faulty ones, their bus messages made beforehand. Every throw is diagnosed twice, by two
diagnosers fed alike: once plainly (the wall time a diagnosis takes) and once with each phase's functions wrapped in
a timer. A phase's time is exclusive: a compiled rollout called inside a fit counts as the rollout's, not the fit's.
Time in no listed function is `other` (the wrapper's own cost lands there too: compare `instrumented_ms` with
`plain_ms`). Phases:

- cutting: the bus messages into a throw, the throw into what the estimator reads (interpolation timeline included);
- rollouts, sensitivities, grid: the compiled model, one rollout at a time, with its forward sensitivities, and
  batched over a grid of starting points;
- model_io: the numpy work around those calls (the model's outputs at the samples' times, scaling, the Jacobian's
  gather);
- linear_algebra: the normal equations, damped steps, Broyden updates and the algebra behind them;
- uncertainty: the fits' standard deviations and effective sample counts;
- solver: the Levenberg-Marquardt loop's and the fits' own Python (starts, stopping rules, scans);
- isolation: building the hypotheses, deciding, the present faults' bookkeeping;
- health: throw features, stroke profile, health trends;
- messages: the Diagnosis, SwitchHealth and alarm messages.

`faulty` is what benchmarks.diagnosis's latency is measured over (the throws after commissioning with a fault);
`all` adds the commissioning throws.
"""
from __future__ import annotations

import functools
import inspect
import time
from collections import Counter

import numpy as np

from benchmarks.common import emit, parser, pin_to_one_core
from benchmarks.diagnosis import draw_cases
from railswitch.models.diagnosis import estimation, isolation, switch_diagnoser
from railswitch.models.diagnosis.estimation import ThrowEstimator
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS, SwitchDiagnoser
from railswitch.models.health import prognosis
from railswitch.models.numerics import buffers, least_squares
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.schemas import RAIL_MODELS
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.core import fleet_diagnoser, throw_cutter
from railswitch.services.core.switch_messages import motor_messages, throw_messages, truth_message
from railswitch.services.wiring import Diagnoser

# phase -> (owner, attribute) pairs: a module's global (where the caller looks it up) or a class's method
PHASES = {
    "cutting": [(throw_cutter.ThrowCutter, "feed"), (switch_diagnoser, "measurement"), (ThrowEstimator, "prepare")],
    "model_io": [(ThrowEstimator, name) for name in ("all_outputs", "residuals", "linearise", "costs", "simulate")],
    "linear_algebra": [*((least_squares, name) for name in ("_normal_equations", "_promised", "_damped", "_proposal",
                                                            "_broyden")),
                       *((cls, name) for cls in (least_squares.Algebra, least_squares.SameOnEveryProcessor)
                         for name in ("dot", "squares", "quadratic", "gradient", "gram", "solve")
                         if name in vars(cls))],
    "uncertainty": [(ThrowEstimator, "_std"), (estimation, "effective_samples")],
    "solver": [(estimation, "levenberg_marquardt"),
               *((ThrowEstimator, name) for name in ("fit", "fit_all", "grid_starts", "scanned", "_nominal_start",
                                                     "_lowest_start", "_start_objective", "_start", "_estimate"))],
    "isolation": [(switch_diagnoser, "judge"), (isolation, "judge"),
                  *((SwitchDiagnoser, name) for name in ("specs", "_spec", "_warm", "negligible", "_judged",
                                                         "_repairs", "_additions", "_reports"))],
    "health": [(switch_diagnoser, "throw_features"), (switch_diagnoser, "stroke_profile"),
               (prognosis.HealthTracker, "update"), (SwitchDiagnoser, "_health_estimates")],
    "messages": [(fleet_diagnoser, name) for name in ("diagnosis_message", "health_message", "alarm_conditions")],
}
COMPILED = {"sensitivity_chunk": "sensitivities", "model_chunk_grid": "grid", "coarse_chunk_grid": "grid",
            "model_chunk": "rollouts"}  # a compiled Function's name (its prefix) -> its phase


class Timers:
    """Exclusive time per phase, inclusive time per hypothesis, and compiled calls, for the throws since `reset`."""

    def __init__(self, clock=time.perf_counter) -> None:
        self.clock = clock
        self.stack: list[list] = []  # [phase, start, time spent in phases called from it]
        self.reset()

    def reset(self) -> None:
        self.phases: Counter[str] = Counter()
        self.hypotheses: Counter[str] = Counter()
        self.calls: Counter[str] = Counter()

    def timed(self, phase: str | None, function, hypothesis: bool = False):
        timers = self

        @functools.wraps(function)
        def wrapper(*args, **kwargs):
            name = phase or compiled_phase(args[0])
            frame = [name, timers.clock(), 0.0]
            timers.stack.append(frame)
            try:
                return function(*args, **kwargs)
            finally:
                spent = timers.clock() - frame[1]
                timers.stack.pop()
                timers.phases[name] += spent - frame[2]
                timers.calls[name] += 1
                if timers.stack:
                    timers.stack[-1][2] += spent
                if hypothesis:
                    timers.hypotheses[args[1].mode] += spent
                    timers.calls["fits"] += 1
        return wrapper

    def install(self) -> None:
        for phase, places in PHASES.items():
            for owner, attribute in places:
                wrapped = self.timed(phase, getattr(owner, attribute),
                                     hypothesis=(owner, attribute) == (ThrowEstimator, "fit"))
                static = isinstance(inspect.getattr_static(owner, attribute), staticmethod)
                setattr(owner, attribute, staticmethod(wrapped) if static else wrapped)
        buffers.InPlace.views = self.timed(None, buffers.InPlace.views)


def compiled_phase(in_place: buffers.InPlace) -> str:
    name = in_place.function.name()
    return next(phase for prefix, phase in COMPILED.items() if name.startswith(prefix))


def messages_of(model_cases, plant, noise: float, seed: int) -> list[tuple[str, list, list[list]]]:
    """Per case: its switch, the messages before its first throw, and each throw's messages."""
    out = []
    for k, (mode, faults) in enumerate(model_cases):
        switch_id = f"case{k}"
        sim = SwitchSimulation(plant, noise_rel=noise, seed=seed + k)
        first = [truth_message(switch_id, sim, 0)[1], *(m for _, m in motor_messages(switch_id, sim, sim.initial_sample()))]
        throws = []
        for n in range(2 * COMMISSIONING_THROWS + 2):
            if n == 2 * COMMISSIONING_THROWS:
                sim.set_faults(faults)
            throws.append([m for _, m in throw_messages(switch_id, sim, sim.throw())])
        out.append((switch_id, first, throws))
    return out


def diagnose_all(diagnoser: Diagnoser, cases, timers: Timers | None = None
                 ) -> tuple[dict[str, list[float]], dict[str, tuple[Counter, Counter, Counter]]]:
    """Seconds per throw (cutting included), by kind, and with `timers` what they counted (phases, hypotheses,
    calls), by kind."""
    seconds: dict[str, list[float]] = {"faulty": [], "all": []}
    split = {"faulty": (Counter(), Counter(), Counter()), "all": (Counter(), Counter(), Counter())}
    for switch_id, first, throws in cases:
        cutter = throw_cutter.ThrowCutter()
        for message in first:
            cutter.feed(message)
        for n, messages in enumerate(throws):
            if timers is not None:
                timers.reset()
            start = time.perf_counter()
            cut = [throw for throw in map(cutter.feed, messages) if throw is not None]
            diagnoser.diagnose(cut[0])
            spent = time.perf_counter() - start
            kinds = ("all", "faulty") if n >= 2 * COMMISSIONING_THROWS else ("all",)
            for kind in kinds:
                seconds[kind].append(spent)
                if timers is not None:
                    for total, part in zip(split[kind], (timers.phases, timers.hypotheses, timers.calls)):
                        total.update(part)
        del diagnoser.switches[switch_id]
    return seconds, split


def per_throw(counts: Counter, throws: int, scale: float = 1e3, digits: int = 2) -> dict[str, float]:
    return {name: round(scale * value / throws, digits) for name, value in sorted(counts.items())}


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--model", choices=RAIL_MODELS, default="poly")
    p.add_argument("--seed", type=int, default=11, help="matrix seed (as benchmarks.diagnosis's)")
    p.add_argument("--per-mode", type=int, default=10)
    p.add_argument("--nominal", type=int, default=10)
    p.add_argument("--noise", type=float, default=0.01)
    args = p.parse_args()
    core = pin_to_one_core()
    cases = messages_of(draw_cases(args.seed, args.per_mode, args.nominal), compiled_plant(), args.noise, args.seed)
    plain = Diagnoser(args.model)
    diagnose_all(plain, cases[:1])  # its estimators built and loaded first
    plain_seconds, _ = diagnose_all(plain, cases)
    timers = Timers()
    timers.install()  # from here on every diagnoser of this process is timed
    timed = Diagnoser(args.model)
    diagnose_all(timed, cases[:1])
    timed_seconds, split = diagnose_all(timed, cases, timers)
    result = {"model": args.model, "seed": args.seed, "core": core, "throws": {k: len(v) for k, v in plain_seconds.items()}}
    for kind in ("faulty", "all"):
        phases, hypotheses, calls = split[kind]
        n = len(plain_seconds[kind])
        timed_total = float(np.sum(timed_seconds[kind]))
        phases = Counter({**phases, "other": timed_total - sum(phases.values())})
        result[kind] = {
            "plain_ms": {"mean": round(1e3 * float(np.mean(plain_seconds[kind])), 2),
                         "p50": round(1e3 * float(np.median(plain_seconds[kind])), 2)},
            "instrumented_ms": round(1e3 * timed_total / n, 2),
            "phases_ms": per_throw(phases, n),
            "phases_share": {name: round(value / timed_total, 3) for name, value in sorted(phases.items())},
            "hypotheses_ms": per_throw(hypotheses, n),
            "calls_per_throw": per_throw(Counter({k: calls[k] for k in ("rollouts", "sensitivities", "grid", "fits")}), n,
                                         scale=1.0, digits=1),
        }
    emit(result, args.json)


if __name__ == "__main__":
    main()
