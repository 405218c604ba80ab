"""benchmarks.profile's accounting: a phase's time is its own, not that of the phases it calls, and every function it
times still exists (a renamed one must fail here, not in a benchmark run)."""
import inspect
import itertools
from types import SimpleNamespace

from benchmarks.profile import PHASES, Timers


def test_a_phase_counts_its_own_time_and_a_hypothesis_all_of_its_fit():
    ticks = itertools.count()
    timers = Timers(clock=lambda: float(next(ticks)))  # each reading of the clock one second later
    rollout = timers.timed("rollouts", lambda: None)

    def fit(self, spec):
        rollout()
        rollout()
        return spec.mode

    fit = timers.timed("solver", fit, hypothesis=True)
    assert fit(None, SimpleNamespace(mode="left_bolt")) == "left_bolt"
    # clock readings: fit starts 0, rollouts 1-2 and 3-4, fit ends 5
    assert timers.phases == {"rollouts": 2.0, "solver": 3.0}
    assert timers.hypotheses == {"left_bolt": 5.0}
    assert timers.calls == {"rollouts": 2, "solver": 1, "fits": 1}
    assert timers.stack == []


def test_a_phase_that_raises_is_still_counted_and_leaves_the_stack_empty():
    ticks = itertools.count()
    timers = Timers(clock=lambda: float(next(ticks)))

    def broken():
        raise ValueError("no")

    wrapped = timers.timed("model_io", broken)
    try:
        wrapped()
    except ValueError:
        pass
    assert timers.phases == {"model_io": 1.0} and timers.stack == []


def test_every_function_the_profile_times_exists():
    for phase, places in PHASES.items():
        for owner, attribute in places:
            assert callable(inspect.getattr_static(owner, attribute, None)) or isinstance(
                inspect.getattr_static(owner, attribute, None), staticmethod), f"{phase}: {owner} has no {attribute}"
