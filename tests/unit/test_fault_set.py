"""A switch's present faults: when one is repaired, how an undecided pair is settled, what a standing condition is
called (models/diagnosis/fault_set.py), and which sizes are no fault (models/diagnosis/switch_diagnoser.py small)."""
from collections import deque

import pytest

from railswitch.models.diagnosis.fault_set import Fault, Undecided, decide_between, describe_standing, repaired
from railswitch.models.diagnosis.isolation import Evidence
from railswitch.models.diagnosis.switch_diagnoser import (
    BOLT_TOLERANCE,
    OBSTACLE_TOLERANCE,
    SHORT_SHARE,
    TIGHT_TOLERANCE,
    small,
)


def bearing(size: float, std: float, presence: list[float]) -> Fault:
    """A present missing bearing whose latest throws showed it at these evidence ratios (latest first)."""
    return Fault("missing_bearing", 10, {"bearing_friction": size}, size, std,
                 [Evidence("missing_bearing", r, statistic=13.0 * r, own=13.0 * r) for r in presence], deque())


def shown(ratio: float) -> Evidence:
    return Evidence("missing_bearing", ratio, statistic=13.0 * ratio, own=13.0 * ratio)


def test_a_sudden_drop_back_to_the_reference_on_two_throws_in_a_row_is_a_repair_even_after_strong_presence():
    fault = bearing(3000.0, 300.0, [4.0, 4.0])
    assert not repaired(fault, shown(0.1), size=120.0, size_std=300.0, small=False) and fault.dropped
    assert repaired(fault, shown(0.05), size=80.0, size_std=300.0, small=False)


def test_one_throw_that_misfits_a_present_fault_away_is_no_repair():
    fault = bearing(3000.0, 300.0, [4.0, 4.0])
    assert not repaired(fault, shown(0.0), size=150.0, size_std=300.0, small=False)
    assert not repaired(fault, shown(3.8), size=2950.0, size_std=300.0, small=False) and not fault.dropped


def test_a_present_fault_that_a_throw_still_shows_is_not_repaired():
    fault = bearing(3000.0, 300.0, [4.0, 4.0])
    assert not repaired(fault, shown(1.5), size=2900.0, size_std=300.0, small=False)


def test_a_weak_throw_of_a_fault_still_there_is_no_repair():
    """A small bearing, found by adding up throws: one throw that alone does not show it is not a repair, since its
    size has not dropped and its latest throws together still show it."""
    fault = bearing(1400.0, 500.0, [0.8, 0.9])
    assert not repaired(fault, shown(0.7), size=1300.0, size_std=500.0, small=False)
    assert not repaired(fault, shown(0.2), size=1500.0, size_std=500.0, small=False)  # not back at its reference


def test_a_fault_that_faded_out_of_three_throws_in_a_row_is_repaired():
    fault = bearing(900.0, 500.0, [0.2, 0.3])
    assert not repaired(fault, shown(0.1), size=300.0, size_std=500.0, small=False)
    assert not repaired(fault, shown(0.2), size=350.0, size_std=500.0, small=False)
    assert repaired(fault, shown(0.1), size=300.0, size_std=500.0, small=False)


def test_a_throw_that_shows_a_new_fault_repairs_only_a_sudden_drop():
    faded = bearing(900.0, 500.0, [0.2, 0.3])
    assert not repaired(faded, shown(0.1), size=300.0, size_std=500.0, small=False, sudden_only=True)
    dropped = bearing(3000.0, 300.0, [4.0, 4.0])
    dropped.dropped = True  # the throw before showed it gone too
    assert repaired(dropped, shown(0.1), size=100.0, size_std=300.0, small=False, sudden_only=True)


def test_a_bolt_back_within_its_adjustment_is_repaired_whatever_its_evidence():
    bolt = Fault("left_bolt", 10, {"left_bolt_offset": 0.04}, 0.04, 0.0005, [Evidence("left_bolt", 50.0)], deque())
    assert repaired(bolt, Evidence("left_bolt", 3.0), size=0.002, size_std=0.0005, small=True)


@pytest.mark.parametrize("offset, loaded, expected", [
    (BOLT_TOLERANCE * 0.9, False, True), (-BOLT_TOLERANCE * 0.9, False, True), (BOLT_TOLERANCE * 1.1, False, False),
    (-BOLT_TOLERANCE * 1.1, False, False),
    # beside another fault, the model reads a bolt tight by up to TIGHT_TOLERANCE; never loose
    (-BOLT_TOLERANCE * 1.1, True, True), (-TIGHT_TOLERANCE * 1.1, True, False), (BOLT_TOLERANCE * 1.1, True, False),
])
def test_which_bolt_offsets_are_an_adjustment_not_a_fault(offset, loaded, expected):
    assert small("right_bolt", {"right_bolt_offset": offset}, loaded) is expected


def test_a_throw_starting_short_reads_its_bolt_within_a_share_of_the_shortfall():
    short = 0.05  # rod travel: blades 25 mm short of the stock rail
    assert small("left_bolt", {"left_bolt_offset": 0.9 * (BOLT_TOLERANCE + SHORT_SHARE * short)}, short_m=short)
    assert small("left_bolt", {"left_bolt_offset": -0.9 * (BOLT_TOLERANCE + SHORT_SHARE * short)}, short_m=short)
    assert not small("left_bolt", {"left_bolt_offset": 1.1 * (BOLT_TOLERANCE + SHORT_SHARE * short)}, short_m=short)


def test_an_obstacle_below_its_tolerance_is_the_models_error_not_a_fault():
    assert small("obstacle", {"obstacle_friction": OBSTACLE_TOLERANCE * 0.5, "obstacle_position": 1.17})
    assert not small("obstacle", {"obstacle_friction": OBSTACLE_TOLERANCE * 1.5, "obstacle_position": 1.1})
    assert not small("missing_bearing", {"bearing_friction": 10.0})  # the F test alone decides the others


def test_an_undecided_pair_is_settled_by_the_other_direction():
    pair = Undecided(("left_bolt", "obstacle"), "left_to_right", 12)
    assert decide_between(pair, "right_to_left", ["obstacle", "missing_bearing"]) == "obstacle"
    # the other direction shows neither: what it cannot see, the left bolt, is what the first throw showed
    assert decide_between(pair, "right_to_left", []) == "left_bolt"
    both_seen = Undecided(("missing_bearing", "drive_friction"), "left_to_right", 12)
    assert decide_between(both_seen, "right_to_left", []) is None  # gone: it was the throw's, not the switch's
    assert "a left to right throw cannot tell them apart; deciding on the next right to left throw" in pair.describe()


def test_standing_conditions_are_named_in_an_operators_words():
    assert describe_standing("missing_bearing", {"bearing_friction": 9072.0}, 300.0 * 37.8, 0.14) == \
        "rolling losses 1.8x"
    assert describe_standing("drive_friction", {"drive_friction_nm": 0.07}, 11340.0, 0.14) == \
        "point machine friction 1.5x"
    assert describe_standing("left_bolt", {"left_bolt_offset": 0.025}, 11340.0, 0.14) == "left bolt +25 mm off its mark"
