"""The control room's fleet view (issue 40): latched alarms first, then the fewest throws to a limit."""
from railswitch.schemas import Alarm, Diagnosis, HistoryReply, SwitchHealth
from railswitch.services.core.fleet_view import fleet_rows, open_alarms


def alarm(switch_id: str, sequence: int, change: str, severity: str = "medium", active: bool = True,
          acknowledged: bool = False, name: str = "left_bolt") -> Alarm:
    return Alarm(switch_id=switch_id, alarm=name, change=change, severity=severity, cause="fault", text=f"{name} text",
                 first_throw=1, last_throw=2, count=2, active=active, acknowledged=acknowledged, sequence=sequence,
                 t_ns=sequence, model="poly")


def reply(switch_id: str, alarms=(), to_limit=None, tag="normal") -> HistoryReply:
    diagnosis = Diagnosis(switch_id=switch_id, throw_index=7, direction="left_to_right", t_start_ns=1, t_end_ns=9,
                          model="poly", decision="nominal", faults=[], latency_ms=1.0, tag=tag)
    health = SwitchHealth(switch_id=switch_id, throw_index=7, t_ns=9, model="poly", state="ok",
                          worst="bearing_friction" if to_limit else None, throws_to_limit=to_limit)
    return HistoryReply(switch_id=switch_id, historian="h", diagnoses=[diagnosis], health=[health], alarms=list(alarms))


def test_an_alarm_is_open_until_acknowledged_and_cleared():
    assert open_alarms([alarm("a", 1, "raised")])[0].change == "raised"
    assert open_alarms([alarm("a", 1, "raised"), alarm("a", 2, "cleared", active=False)])[0].change == "cleared"
    closed = [alarm("a", 1, "raised"), alarm("a", 2, "cleared", active=False),
              alarm("a", 3, "acknowledged", active=False, acknowledged=True)]
    assert open_alarms(reversed(closed)) == []  # by sequence, whatever order they came in


def test_switches_come_by_urgency():
    rows = fleet_rows([
        reply("quiet"),
        reply("wearing", to_limit=40.0),
        reply("soon", to_limit=5.0),
        reply("seen", [alarm("seen", 1, "raised", "critical"),
                       alarm("seen", 2, "acknowledged", "critical", acknowledged=True)]),
        reply("new-low", [alarm("new-low", 1, "raised", "low")]),
        reply("new-high", [alarm("new-high", 1, "raised", "high")], tag="maintenance"),
    ])
    assert [r.switch_id for r in rows] == ["new-high", "new-low", "seen", "soon", "wearing", "quiet"]
    assert rows[0].maintenance and not rows[0].acknowledged and rows[2].acknowledged
    assert rows[0].worst == "left_bolt text" and rows[3].worst == "bearing_friction"
