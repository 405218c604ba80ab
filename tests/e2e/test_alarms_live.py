"""Alarms over the bus (issue 40), with real processes on a real router: the diagnoser publishes alarm changes, an
operator acknowledges them with `railswitch ack`, the historian keeps them, and junk or misdirected commands change
nothing and are counted in the diagnoser's status."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading

import pytest
import zenoh

from railswitch.schemas import Alarm, decode
from railswitch.services.adapters.processes import services_alive
from tests.live import ROOT, ServiceWatch, live_bus, wait_for, wait_ready

SCENARIO = """
interval_s = 10.0

[[switches]]
id = "faulty"
throws = 3
faults = { left_bolt_offset = 0.05 }
"""


class AlarmCollector:
    def __init__(self, session: zenoh.Session):
        self.received: list[Alarm] = []
        self._lock = threading.Lock()
        self._subscriber = session.declare_subscriber("railswitch/*/alarm", self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.received.append(decode(Alarm, sample.payload.to_bytes()))

    def changes(self) -> list[tuple[str, str, str]]:
        with self._lock:
            return [(a.switch_id, a.alarm, a.change) for a in self.received]


def railswitch(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "railswitch", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)


@pytest.fixture(scope="module")
def bus(tmp_path_factory):
    work = tmp_path_factory.mktemp("alarms")
    scenario = work / "scenario.toml"
    scenario.write_text(SCENARIO)
    db = work / "history.sqlite"
    with live_bus(work) as (services, endpoint, session, collector):
        alarms = AlarmCollector(session)
        status = ServiceWatch(session, "diagnoser")
        state = work / "state"
        diagnoser = services.start("diagnoser", "--connect", endpoint, "--status-interval", "0.5", "--state", str(state))
        services.start("historian", "--connect", endpoint, "--db", str(db))
        wait_ready(session, services, diagnoser=1, historian=1)
        simulator = services.start("simulator", "--connect", endpoint, "--scenario", str(scenario), "--speed", "20")
        assert simulator.wait(120) == 0, services.log(simulator)
        wait_for(lambda: ("faulty", "left_bolt", "raised") in alarms.changes(), 60, "the bolt's alarm raised")
        # the diagnoser killed and started again on its state: the latched alarm is what it acknowledges below
        services.stop(diagnoser, signal.SIGKILL)
        wait_for(lambda: services_alive(session)["diagnoser"] == 0, 30, "the diagnoser gone")
        services.start("diagnoser", "--connect", endpoint, "--status-interval", "0.5", "--state", str(state))
        wait_ready(session, services, diagnoser=1)
        yield endpoint, session, alarms, status, db


def rejected(status: ServiceWatch, reason: str) -> int:
    latest = [s for _, s in status.statuses]
    return latest[-1].rejected.get(reason, 0) if latest else 0


def test_a_raised_alarm_survives_a_diagnoser_killed_and_is_acknowledged_once_kept_by_the_historian_and_misdirected_acks_change_nothing(bus):
    endpoint, session, alarms, status, db = bus
    raised = [a for a in alarms.received if a.alarm == "left_bolt"]
    assert [a.change for a in raised][:1] == ["raised"] and len([a for a in raised if a.change == "raised"]) == 1
    assert raised[0].cause == "fault" and raised[0].first_throw == 0 and not raised[0].acknowledged

    result = railswitch("ack", "faulty", "--note", "bolt reset", "--connect", endpoint)
    assert result.returncode == 0, result.stderr
    wait_for(lambda: ("faulty", "left_bolt", "acknowledged") in alarms.changes(), 30, "the acknowledgement")
    acknowledged = next(a for a in alarms.received if a.change == "acknowledged")
    assert acknowledged.note == "bolt reset" and acknowledged.acknowledged and acknowledged.sequence > raised[0].sequence

    count = len(alarms.received)
    assert railswitch("ack", "faulty", "--connect", endpoint).returncode == 0  # nothing left to acknowledge
    assert railswitch("ack", "ghost", "--connect", endpoint).returncode == 0  # a switch no diagnoser knows
    session.put("railswitch/faulty/ack", b'{"switch_id": "faulty", "alarm": 7')  # junk
    session.put("railswitch/faulty/maintenance", b'{"switch_id": "faulty", "action": "pause"}')
    wait_for(lambda: all(rejected(status, reason) >= 1 for reason in (
        "ack: no such unacknowledged alarm", "ack: unknown switch", "ack: not json",
        "maintenance: validation: action: Input should be 'start' or 'end'")), 30, "the refusals counted")
    assert len(alarms.received) == count  # none of them changed an alarm

    def kept() -> list[dict]:
        history = railswitch("history", "faulty", "--db", str(db), "--json", "--kind", "alarm")
        assert history.returncode == 0, history.stderr
        return [json.loads(line) for line in history.stdout.splitlines()]

    wait_for(lambda: acknowledged.sequence in {a["sequence"] for a in kept()}, 30, "the historian to keep it")
    assert [(a["alarm"], a["change"]) for a in kept() if a["alarm"] == "left_bolt"][-1] == ("left_bolt", "acknowledged")
    assert {a["sequence"] for a in kept()} >= {raised[0].sequence, acknowledged.sequence}


def test_the_fleet_view_from_the_bus_and_from_the_file_agree(bus):
    endpoint, _, alarms, _, db = bus
    wait_for(lambda: any(a.change == "acknowledged" for a in alarms.received), 60, "an acknowledgement")
    from_bus = railswitch("fleet", "--connect", endpoint, "--json")
    from_file = railswitch("fleet", "--db", str(db), "--json")
    assert from_bus.returncode == 0 and from_file.returncode == 0, from_bus.stderr + from_file.stderr
    rows = [json.loads(line) for line in from_bus.stdout.splitlines()]
    assert [(r["switch_id"], r["acknowledged"], r["last_throw"]) for r in rows] == [("faulty", True, 2)]
    assert rows[0]["alarms"][0]["alarm"] == "left_bolt" and "left_bolt" in rows[0]["faults"]
    assert [json.loads(line) for line in from_file.stdout.splitlines()] == rows
    table = railswitch("fleet", "--db", str(db))
    assert table.returncode == 0 and "faulty" in table.stdout and "left_bolt" in table.stdout


def test_maintenance_starts_once_over_the_bus(bus):
    endpoint, _, _, status, _ = bus
    assert railswitch("maintenance", "faulty", "--start", "--note", "bolts", "--connect", endpoint).returncode == 0
    wait_for(lambda: status.statuses and status.statuses[-1][1].counters.get("maintenance") == 1, 30,
             "maintenance started")
    assert railswitch("maintenance", "faulty", "--start", "--connect", endpoint).returncode == 0
    wait_for(lambda: rejected(status, "maintenance: already in maintenance") >= 1, 30, "a second start refused")
