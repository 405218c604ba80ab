"""Behaviour of the high-fidelity plant: throws, dissipation and the signatures of every fault."""
import math

import numpy as np
import pytest

from railswitch.models.plant.drive import motor_angle_at_rod
from railswitch.models.plant.faults import fault_vector
from railswitch.models.plant.high_fidelity import Plant
from railswitch.models.plant.simulation import SwitchSimulation


def throws(plant, n=2, faults=None):
    sim = SwitchSimulation(plant, faults=faults)
    return [sim.throw() for _ in range(n)]


def time_rails_pass(throw, position_m):
    """First time (s since the throw's start) the rails cross `position_m`."""
    x = throw.samples.rail_position_m
    t = np.arange(1, len(x) + 1) / 50.0
    crossed = np.flatnonzero(np.sign(x - position_m) != np.sign(x[0] - position_m))
    return t[crossed[0]] if len(crossed) else math.inf


def test_plant_has_at_least_250_states_and_60_rail_nodes(plant):
    stats = plant.describe()
    assert stats["states"] >= 250
    assert stats["rail_nodes"] >= 60


def test_rail_beam_tip_stiffness_matches_beam_theory_with_flexible_heel(plant):
    p = plant.params.rail
    length, heel, ei = p.length_m, p.heel_flex_length_m, p.bending_stiffness_n_m2
    # unit-load (Castigliano) compliance of a cantilever with a softer heel section
    compliance = (length**3 - (length - heel) ** 3) / (3 * p.heel_flex_factor * ei) + (length - heel) ** 3 / (3 * ei)
    assert plant.beam.tip_stiffness_n_m == pytest.approx(1 / compliance, rel=0.05)


def test_nominal_throws_close_against_each_stock_rail_within_5_mm(plant):
    left_to_right, right_to_left = throws(plant)
    assert left_to_right.direction == "left_to_right"
    assert abs(left_to_right.samples.rail_position_m[-1] - 1.20) < 0.005
    assert abs(right_to_left.samples.rail_position_m[-1] - 1.00) < 0.005


def test_nominal_currents_are_realistic(plant):
    left_to_right, _ = throws(plant)
    current = left_to_right.samples.signals.current_a
    moving = np.abs(left_to_right.samples.rail_position_m - 1.10) < 0.08
    assert 1.0 < np.mean(np.abs(current[moving])) < 5.0  # running current: a few amperes
    assert np.max(np.abs(current)) < 12.0


@pytest.mark.parametrize("rail_m,velocity_m_s", [(1.15, 0.2), (1.205, -0.15)])
def test_rail_energy_never_increases_with_the_motor_unpowered(rail_m, velocity_m_s):
    plant = Plant(reltol=1e-9, abstol=1e-11)
    drive = plant.params.drive
    centred = motor_angle_at_rod(drive, drive.linkage_ratio * rail_m)  # bolts clear on both sides
    state = plant.rest_state(rail_m, motor_angle_rad=centred)
    state[plant.nodes:2 * plant.nodes] = velocity_m_s * plant.beam.shape
    faults = {"bearing_friction": 2000.0, "obstacle_friction": 5e4, "obstacle_position": rail_m - 0.003}
    trajectory = plant.run(state, 1.5, 400.0, faults)
    energy = np.array([float(plant.energy(x, fault_vector(faults), plant.variables())[0]) for x in trajectory.states.T])
    initial = float(plant.energy(state, fault_vector(faults), plant.variables())[0])
    energy = np.concatenate([[initial], energy])
    kinetic = 0.5 * np.sum(plant.beam.masses_kg * state[plant.nodes:2 * plant.nodes] ** 2)
    assert kinetic > 1.0  # the test starts with something to dissipate
    assert np.all(np.diff(energy) <= 1e-7 * energy[0])
    assert energy[-1] < energy[0] - 0.9 * kinetic  # the motion dies out; friction may hold the bent beam


def test_left_bolt_offset_delays_rail_motion_left_to_right(plant):
    nominal = throws(plant, 1)[0]
    faulty = throws(plant, 1, {"left_bolt_offset": 0.05})[0]
    delay = time_rails_pass(faulty, 1.02) - time_rails_pass(nominal, 1.02)
    assert delay > 0.3
    assert faulty.samples.rail_position_m[-1] < 1.19  # the extra play leaves a gap at the stock rail


def test_right_bolt_offset_leaves_left_to_right_throw_unchanged(plant):
    nominal = throws(plant, 1)[0]
    faulty = throws(plant, 1, {"right_bolt_offset": 0.05})[0]
    assert abs(time_rails_pass(faulty, 1.02) - time_rails_pass(nominal, 1.02)) < 0.1
    assert abs(faulty.samples.rail_position_m[-1] - nominal.samples.rail_position_m[-1]) < 0.002


def right_to_left_from_closed_right(plant, faults):
    sim = SwitchSimulation(plant)
    sim.throw()  # nominal left-to-right: the rails close at 1.20 m
    sim.set_faults(faults)
    return sim.throw()


def test_right_bolt_offset_delays_rail_motion_right_to_left(plant):
    nominal = right_to_left_from_closed_right(plant, {})
    faulty = right_to_left_from_closed_right(plant, {"right_bolt_offset": 0.05})
    assert time_rails_pass(faulty, 1.18) - time_rails_pass(nominal, 1.18) > 0.3
    assert faulty.samples.rail_position_m[-1] > 1.01  # a gap at the left stock rail


def test_left_bolt_offset_leaves_right_to_left_throw_unchanged(plant):
    nominal = right_to_left_from_closed_right(plant, {})
    faulty = right_to_left_from_closed_right(plant, {"left_bolt_offset": 0.05})
    assert abs(time_rails_pass(faulty, 1.18) - time_rails_pass(nominal, 1.18)) < 0.1
    assert abs(faulty.samples.rail_position_m[-1] - nominal.samples.rail_position_m[-1]) < 0.002


def test_misaligned_bolt_gap_carries_into_the_next_throw(plant):
    first, second = throws(plant, 2, {"left_bolt_offset": 0.05})
    assert second.samples.rail_position_m[0] == pytest.approx(first.samples.rail_position_m[-1], abs=1e-3)
    assert second.samples.rail_position_m[0] < 1.19


def mean_current_while_rails_move(throw):
    x = throw.samples.rail_position_m
    moving = (x > 1.03) & (x < 1.17)
    return float(np.mean(np.abs(throw.samples.signals.current_a[moving])))


def test_bearing_friction_raises_current_while_rails_move(plant):
    nominal = throws(plant, 2)
    faulty = throws(plant, 2, {"bearing_friction": 5000.0})
    for n, f in zip(nominal, faulty):
        assert mean_current_while_rails_move(f) > mean_current_while_rails_move(n) + 0.3


def test_severe_obstacle_stops_rails_short_and_raises_current_near_it(plant):
    nominal = throws(plant, 1)[0]
    blocked = throws(plant, 1, {"obstacle_friction": 3e5, "obstacle_position": 1.10})[0]
    assert blocked.samples.rail_position_m[-1] < 1.19  # short of the stock rail at 1.20 m

    def current_near_obstacle(throw):
        near = np.abs(throw.samples.rail_position_m - 1.10) < 0.01
        return float(np.mean(np.abs(throw.samples.signals.current_a[near])))

    assert current_near_obstacle(blocked) > current_near_obstacle(nominal) + 3.0
    assert np.max(np.abs(blocked.samples.signals.current_a)) > 9.0  # near stall


def test_faults_combine(plant):
    both = throws(plant, 1, {"left_bolt_offset": 0.05, "bearing_friction": 5000.0})[0]
    left_only = throws(plant, 1, {"left_bolt_offset": 0.05})[0]
    assert time_rails_pass(both, 1.02) == pytest.approx(time_rails_pass(left_only, 1.02), abs=0.1)
    assert mean_current_while_rails_move(both) > mean_current_while_rails_move(left_only) + 0.3


def test_noise_is_relative_to_nominal_peaks_and_seeded(plant):
    clean = SwitchSimulation(plant).throw().samples.signals.current_a
    noisy_a = SwitchSimulation(plant, noise_rel=0.01, seed=3).throw().samples.signals.current_a
    noisy_b = SwitchSimulation(plant, noise_rel=0.01, seed=3).throw().samples.signals.current_a
    noisy_c = SwitchSimulation(plant, noise_rel=0.01, seed=4).throw().samples.signals.current_a
    np.testing.assert_array_equal(noisy_a, noisy_b)
    assert not np.array_equal(noisy_a, noisy_c)
    peak = np.max(np.abs(clean))
    assert np.std(noisy_a - clean) == pytest.approx(0.01 * peak, rel=0.2)


def test_a_plant_gives_the_same_throw_whatever_ran_before_it_in_the_process(plant):
    """Same inputs, same bits, on one machine: nothing a plant builds or caches (its integrators, the noise
    peaks) leaks from one plant, rate or run into another."""
    first = SwitchSimulation(Plant()).throw().samples.signals.current_a
    looser = SwitchSimulation(Plant(reltol=1e-3, abstol=1e-4)).throw().samples.signals.current_a
    assert not np.array_equal(looser, first)  # each plant integrates at its own tolerances
    SwitchSimulation(plant, faults={"obstacle_friction": 1e5, "obstacle_position": 1.1}, rate_hz=25.0).throw()
    SwitchSimulation(plant, own={"motor.supply_v": 100.0}, noise_rel=0.01, seed=3).throw()
    again = SwitchSimulation(plant).throw().samples.signals.current_a
    np.testing.assert_array_equal(again, first)


def test_closing_blades_follow_the_rod_and_are_never_snapped_in_by_the_lock(plant):
    for throw in throws(plant, 2):
        x = throw.samples.rail_position_m
        velocity = np.diff(x) * 50.0
        assert np.max(np.abs(velocity)) < 0.1  # the rod moves the blades at most ~0.065 m/s


def test_lock_holds_a_closed_blade_until_the_driving_bolt_arrives(plant):
    first, second = throws(plant, 2)
    for throw, closed in ((first, 1.00), (second, 1.20)):
        start = time_rails_pass(throw, closed + (0.01 if closed < 1.1 else -0.01))
        waiting = throw.samples.rail_position_m[: int(start * 50) - 10]
        assert np.max(np.abs(waiting - closed)) < 0.003  # within the lock's slack while the rod takes up the play


def test_a_run_keeps_its_numbers_when_the_plant_runs_again_and_they_are_those_of_the_dm_interface(plant):
    """Runs go through buffers the plant reuses (models/numerics/buffers.py): a trajectory owns its arrays, and they are the
    numbers CasADi's matrix interface gives for the same call."""
    from railswitch.models.plant.reference import throw_reference

    state = plant.start_throw(plant.rest_state(1.0))
    first = plant.run(state, 2.0, 50.0, reference=throw_reference("left_to_right"))
    kept = first.states.copy(), {name: values.copy() for name, values in first.signals.items()}
    plant.run(state, 2.0, 50.0, {"obstacle_friction": 1e5, "obstacle_position": 1.05}, throw_reference("left_to_right"))
    np.testing.assert_array_equal(first.states, kept[0])
    for name, values in first.signals.items():
        np.testing.assert_array_equal(values, kept[1][name])
    dt, steps = 1.0 / 50.0, 100
    t = dt * np.arange(1, steps + 1)
    reference = throw_reference("left_to_right")
    control = np.zeros((3, steps))
    control[0], control[1] = reference.linear_pieces(dt * np.arange(steps), t)
    control[2] = 1.0
    p = np.concatenate([fault_vector(), plant.variables()])
    expected = np.asarray(plant._integrator(dt, steps)(x0=state, p=p, u=control)["xf"])
    np.testing.assert_array_equal(first.states, expected)


@pytest.mark.parametrize("stroke_s", [6.4, 6.31])
def test_the_reference_reaches_the_plant_as_its_own_lines_one_pair_of_numbers_a_piece(stroke_s):
    """CVODES stops wherever the plant's control changes. Over the samples of one piece of the profile the control is
    that piece's line to the last bit, so the integrator stops at the profile's breakpoints, not at every sample of a
    ramp (chords through the samples differ in their last bits); an interval that spans a breakpoint gets the chord."""
    from railswitch.models.plant.reference import throw_reference

    reference = throw_reference("left_to_right", stroke_s=stroke_s)
    dt, steps = 1.0 / 50.0, 350
    start, end = dt * np.arange(steps), dt * np.arange(1, steps + 1)
    intercept, slope = reference.linear_pieces(start, end)
    spans = np.any((start[:, None] < reference.t_s) & (reference.t_s < end[:, None]), axis=1)
    middle = 0.5 * (start + end)
    for t, where in ((start, ...), (end, ...), (middle, ~spans)):
        np.testing.assert_allclose((intercept + slope * t)[where], reference(t)[where], rtol=0, atol=1e-9)
    changes = 1 + np.count_nonzero((np.diff(intercept) != 0) | (np.diff(slope) != 0))
    assert changes == len(reference.t_s) - 1 + np.count_nonzero(spans)  # the pieces (the last holds), the chords
