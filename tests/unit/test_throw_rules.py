"""Which throws can be diagnosed: any ordinary length, any rate, current alone (issue 17)."""
import numpy as np
import pytest

from railswitch.models.plant.reference import throw_reference
from railswitch.models.plant.signals import MotorSignals
from railswitch.models.diagnosis.switch_diagnoser import MAX_THROW_S, ThrowInput, problem
from railswitch.schemas import MotorSample, ThrowEvent
from railswitch.services.core.throw_cutter import cut_throws


def throw(duration_s: float, rate_hz: float = 50.0, stroke_s: float = 6.4, moving_at_end: bool = False,
          current_only: bool = False) -> ThrowInput:
    """A throw whose motor follows its reference (velocity = the reference; `moving_at_end`: still at top speed)."""
    reference = throw_reference("left_to_right", stroke_s=stroke_s, duration_s=stroke_s + 0.6)
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / rate_hz)
    velocity = reference(t)
    if moving_at_end:
        velocity[-1] = np.abs(reference.velocity_rad_s).max()
    angle = np.concatenate([[0.0], np.cumsum(velocity[1:] / rate_hz)])
    signals = MotorSignals(np.full(len(t), 2.0)) if current_only else MotorSignals(np.full(len(t), 2.0), angle, velocity)
    return ThrowInput(0, "left_to_right", reference, t, signals, duration_s)


@pytest.mark.parametrize("duration_s, rate_hz, stroke_s", [
    (6.9, 50.0, 6.4),  # ends 0.1 s before its 7 s reference: the end position was detected early
    (9.0, 50.0, 6.4),  # ends long after it
    (3.0, 10.0, 2.4),  # a fast machine type at 10 Hz
    (15.0, 200.0, 14.0),  # a slow one at 200 Hz
])
def test_a_throw_of_any_ordinary_length_and_rate_whose_motor_has_stopped_can_be_diagnosed(duration_s, rate_hz,
                                                                                         stroke_s):
    assert problem(throw(duration_s, rate_hz, stroke_s)) is None


def test_a_throw_cut_short_while_the_motor_is_still_asked_to_turn_is_refused_saying_so():
    why = problem(throw(5.0))
    assert why is not None and "still asked to turn" in why and "6.40 s" in why


def test_a_throw_whose_motor_still_turns_at_its_end_is_refused_even_if_its_reference_had_stopped():
    why = problem(throw(7.0, moving_at_end=True))
    assert why is not None and "still turning" in why


def test_a_current_only_throw_is_judged_on_its_reference_alone():
    assert problem(throw(6.9, current_only=True)) is None
    assert "still asked to turn" in problem(throw(5.0, current_only=True))


def test_a_throw_longer_than_any_machine_is_refused():
    assert "longer than" in problem(throw(MAX_THROW_S + 1.0))


def test_the_cutter_takes_a_unit_that_logs_the_current_alone_as_current_only():
    reference = throw_reference("left_to_right")
    events = [ThrowEvent(switch_id="s", throw_index=0, phase=phase, direction="left_to_right", t_ns=t,
                         reference_t_s=list(reference.t_s), reference_velocity_rad_s=list(reference.velocity_rad_s))
              for phase, t in (("start", 0), ("end", 100_000_000))]
    samples = [MotorSample(switch_id="s", seq=k, t_ns=k * 20_000_000, current_a=1.0,
                           angle_rad=0.0 if k == 2 else None, velocity_rad_s=None) for k in range(6)]
    (cut,) = list(cut_throws([events[0], *samples, events[1]]))
    assert cut.signals.names == ("current_a",)  # angle on one sample only: not a logged signal
    assert len(cut.signals) == 6
