"""A switch's alarms as an operator handles them (issue 40): latched until acknowledged, repeats suppressed."""
from railswitch.models.health.alarms import AlarmBook, Condition

BOLT = Condition("fault", "medium", "left_bolt: left_bolt_offset 0.04 m", {"left_bolt_offset": 0.04})


def test_a_condition_raises_once_and_its_repeats_only_count():
    book = AlarmBook()
    first = book.observe(10, 100, {"left_bolt": BOLT})
    assert [(c.change, c.alarm.alarm, c.sequence) for c in first] == [("raised", "left_bolt", 1)]
    assert book.observe(11, 110, {"left_bolt": BOLT}) == []  # a repeat: no change to publish
    assert book.observe(12, 120, {"left_bolt": BOLT}) == []
    state = book.alarms["left_bolt"]
    assert (state.first_throw, state.last_throw, state.count) == (10, 12, 3)


def test_a_higher_severity_escalates_and_asks_for_a_new_acknowledgement():
    book = AlarmBook()
    book.observe(1, 1, {"left_bolt": BOLT})
    assert [c.change for c in book.acknowledge(2, note="seen")] == ["acknowledged"]
    worse = Condition("fault", "critical", "left_bolt: left_bolt_offset 0.09 m", {"left_bolt_offset": 0.09})
    changes = book.observe(3, 3, {"left_bolt": worse})
    assert [(c.change, c.alarm.severity, c.alarm.acknowledged) for c in changes] == [("escalated", "critical", False)]
    assert book.observe(4, 4, {"left_bolt": BOLT}) == []  # a lower severity does not step it down


def test_a_cleared_alarm_stays_latched_until_acknowledged_and_then_closes():
    book = AlarmBook()
    book.observe(1, 1, {"left_bolt": BOLT})
    assert book.observe(2, 2, {}) == []  # one quiet throw does not clear it
    cleared = book.observe(2, 2, {})
    assert [(c.change, c.alarm.active) for c in cleared] == [("cleared", False)]
    assert [s.alarm for s in book.latched()] == ["left_bolt"]  # still there for the operator
    assert book.observe(3, 3, {}) == []
    acknowledged = book.acknowledge(4, "left_bolt", "bolt reset")
    assert [(c.change, c.alarm.note) for c in acknowledged] == [("acknowledged", "bolt reset")]
    assert book.latched() == [] and book.alarms == {}
    assert book.acknowledge(5) == []  # nothing left to acknowledge: no change
    again = book.observe(6, 6, {"left_bolt": BOLT})
    assert [(c.change, c.alarm.first_throw, c.sequence) for c in again] == [("raised", 6, 4)]


def test_a_condition_that_comes_and_goes_throw_by_throw_stays_one_active_alarm():
    book = AlarmBook()
    changes = [c.change for k in range(10) for c in book.observe(k, k, {"left_bolt": BOLT} if k % 2 == 0 else {})]
    assert changes == ["raised"]


def test_an_acknowledged_active_alarm_closes_when_it_clears_and_a_named_ack_leaves_the_others():
    book = AlarmBook()
    anomaly = Condition("anomaly", "high", "winding resistance at its bound", {"motor.resistance_ohm": 11.4})
    book.observe(1, 1, {"left_bolt": BOLT, "anomaly:motor.resistance_ohm": anomaly})
    assert [c.alarm.alarm for c in book.acknowledge(2, "left_bolt")] == ["left_bolt"]
    assert [c.alarm.alarm for c in book.acknowledge(3, "nothing-such")] == []
    book.observe(4, 4, {"anomaly:motor.resistance_ohm": anomaly})
    assert [(c.change, c.alarm.alarm) for c in book.observe(5, 5, {"anomaly:motor.resistance_ohm": anomaly})] == [
        ("cleared", "left_bolt")]
    assert list(book.alarms) == ["anomaly:motor.resistance_ohm"]


def test_only_the_alarms_a_throw_judged_are_cleared():
    book = AlarmBook()
    feature = Condition("feature", "low", "peak current outside its band", {"peak_current_a": 4.0})
    book.observe(1, 1, {"feature:peak_current_a:left_to_right": feature})
    for k in (2, 3):
        assert book.observe(k, k, {}, judged=set()) == []  # throws the other way do not see it
    judged = {"feature:peak_current_a:left_to_right"}
    assert book.observe(4, 4, {}, judged=judged) == []
    assert [c.change for c in book.observe(5, 5, {}, judged=judged)] == ["cleared"]


def test_a_book_read_back_from_its_state_goes_on_where_it_was():
    book = AlarmBook()
    book.observe(1, 1, {"left_bolt": BOLT})
    again = AlarmBook.from_dict(book.to_dict())
    assert again.observe(2, 2, {"left_bolt": BOLT}) == []  # still latched and active: a repeat
    assert [(c.change, c.sequence) for c in again.acknowledge(3)] == [("acknowledged", 2)]
    assert AlarmBook.from_dict(None).alarms == {}  # a state saved before alarms were kept


def _outside(name: str, value: float) -> dict:
    return {"name": name, "direction": "left_to_right", "value": value, "mean": 2.0, "low": 1.8, "high": 2.2,
            "slope_per_100": 0.0, "state": "outside"}


def test_features_outside_their_band_raise_one_alarm_and_none_beside_a_fault():
    from railswitch.models.diagnosis.switch_diagnoser import Outcome
    from railswitch.services.core.fleet_diagnoser import alarm_conditions
    features = [_outside("peak_current_a", 3.1), _outside("mean_current_a", 2.6),
                {**_outside("throw_time_s", 5.0), "state": "ok"}]
    alone = Outcome("nominal", None, None, None, feature_health=features)
    conditions, _ = alarm_conditions(alone, "left_to_right", AlarmBook())
    assert list(conditions) == ["features:left_to_right"]
    assert conditions["features:left_to_right"].parameters == {"peak_current_a": 3.1, "mean_current_a": 2.6}
    beside = Outcome("missing_bearing", None, None, None, faults=("missing_bearing",), feature_health=features)
    conditions, _ = alarm_conditions(beside, "left_to_right", AlarmBook())
    assert list(conditions) == ["missing_bearing"]  # the fault explains its features
