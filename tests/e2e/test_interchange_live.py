"""Other publishers on a live bus (issue 17): a newer publisher's payloads, and switches of other sample rates and
throw lengths, served by the diagnoser and kept by the recorder. Real routers and processes on loopback."""
from __future__ import annotations

import json
import queue
import subprocess
import sys
from collections import Counter

import pytest
import zenoh
from mcap.reader import make_reader

from railswitch.schemas import MotorSample, ServiceStatus, decode
from railswitch.services.adapters.recordings import load_recording
from tests.interchange.foreign import EXTRA, EXTRA_KINDS, foreign_payload
from tests.live import (DiagnosisCollector, ServiceProcesses, client, jsonl_decisions, start_router, wait_for,
                        wait_ready)

NEWER_CONTRACT = 2
SWITCH = "pm-4711"
THROWS = 3


def plain_session(endpoint: str) -> zenoh.Session:
    """A Zenoh client as another team opens one, without railswitch's helpers; waits up to 30 s for its router."""
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("client"))
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("connect/timeout_ms", "30000")
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


class Republisher:
    """Takes a simulator's motor, throw and truth messages off one router and puts them on another as a newer
    publisher writes them (tests/interchange/foreign.py, contract 2). The callback only queues; forward() publishes.

    One subscription, as in the diagnoser: zenoh-python runs each subscription's callbacks in a thread of its own,
    so two could hand over a throw's last sample after its end event."""

    def __init__(self, source: str, target: str):
        self._source, self._target = plain_session(source), plain_session(target)
        self._queue: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        self._subscriber = self._source.declare_subscriber("railswitch/*/*", self._on_sample)
        self._publishers: dict[str, zenoh.Publisher] = {}
        self.sent: Counter[str] = Counter()  # per kind

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if str(sample.key_expr).rsplit("/", 1)[1] in EXTRA_KINDS:
            self._queue.put((str(sample.key_expr), sample.payload.to_bytes()))

    def forward(self, timeout_s: float) -> bool:
        """Republish one message; False when none came within timeout_s."""
        try:
            key, payload = self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return False
        if key not in self._publishers:  # blocking, not dropping, so every count below is exact
            self._publishers[key] = self._target.declare_publisher(key,
                                                                   congestion_control=zenoh.CongestionControl.BLOCK)
        self._publishers[key].put(foreign_payload(payload, contract=NEWER_CONTRACT))
        self.sent[key.rsplit("/", 1)[1]] += 1
        return True

    def close(self) -> None:
        for session in (self._source, self._target):
            session.close()


class StatusWatcher:
    """The latest ServiceStatus of each service on the bus."""

    def __init__(self, session: zenoh.Session):
        self.latest: dict[str, ServiceStatus] = {}
        self._subscriber = session.declare_subscriber("railswitch/@service/*/*/status", self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        status = decode(ServiceStatus, sample.payload.to_bytes())
        self.latest[status.service] = status

    def ignored(self, service: str) -> dict[str, int]:
        status = self.latest.get(service)
        return {} if status is None else status.ignored_fields


def expected_ignored(sent: Counter[str], kinds: tuple[str, ...]) -> dict[str, int]:
    """What a service taking `kinds` must have counted of what the republisher sent."""
    names = [*EXTRA, f"contract={NEWER_CONTRACT}"]
    return {f"{kind}: {name}": sent[kind] for kind in kinds for name in names}


def test_a_newer_publisher_is_diagnosed_counted_and_recorded_as_it_published(tmp_path):
    recording = tmp_path / "newer.mcap"
    with ServiceProcesses(tmp_path) as services:
        upstream, bus = start_router(services), start_router(services)  # two routers that do not know each other
        session = client(bus)
        republisher = Republisher(upstream, bus)
        try:
            collector, statuses = DiagnosisCollector(session), StatusWatcher(session)
            diagnoser = services.start("diagnoser", "--connect", bus, "--status-interval", "0.5",
                                       "--state", str(tmp_path / "baselines"))
            recorder = services.start("recorder", "--connect", bus, "--out", str(recording), "--status-interval", "0.5")
            wait_ready(session, services, diagnoser=1, recorder=1)
            simulator = services.start("simulator", "--connect", upstream, "--switch-id", SWITCH, "--throws",
                                       str(THROWS), "--speed", "10", "--fault", "left_bolt_offset=0.05")
            while simulator.poll() is None:
                republisher.forward(0.1)
            while republisher.forward(1.0):  # what was still on its way when the simulator ended
                pass
            assert simulator.returncode == 0, services.log(simulator)
            sent = republisher.sent
            wait_for(lambda: len(collector.received) >= THROWS, 120, "a diagnosis of every throw")
            wait_for(lambda: statuses.ignored("diagnoser") == expected_ignored(sent, ("motor", "throw")), 30,
                     "the diagnoser's status to count every ignored field")
            wait_for(lambda: statuses.ignored("recorder") == expected_ignored(sent, EXTRA_KINDS), 30,
                     "the recorder's status to count every ignored field")
            services.stop(recorder)
            diagnoser_log = services.log(diagnoser)
        finally:
            republisher.close()
            session.close()
    offline = subprocess.run([sys.executable, "-m", "railswitch", "diagnose", str(recording), "--jsonl"],
                             capture_output=True, text=True, timeout=300)
    assert offline.returncode == 0, offline.stderr
    assert collector.decisions() == jsonl_decisions(offline.stdout)  # the live diagnoser read what a file keeps
    assert len(collector.decisions()) == THROWS and "unknown" not in collector.decisions().values()
    logged = [line for line in diagnoser_log.splitlines() if "does not know" in line]
    assert len(logged) == len(expected_ignored(sent, ("motor", "throw")))  # once per kind and name
    assert not statuses.latest["diagnoser"].rejected and not statuses.latest["recorder"].rejected
    with open(recording, "rb") as f:
        kept = Counter()
        for _, channel, message in make_reader(f).iter_messages():
            payload = json.loads(message.data)
            kind = channel.topic.rsplit("/", 1)[1]
            kept[kind] += 1
            if kind in EXTRA_KINDS:
                assert payload["unit_serial"] == EXTRA["unit_serial"] and payload["contract"] == NEWER_CONTRACT
    assert {kind: kept[kind] for kind in (*EXTRA_KINDS, "diagnosis")} == {**sent, "diagnosis": THROWS}
    assert load_recording(recording).ignored == expected_ignored(sent, EXTRA_KINDS)


# -- switches of other sample rates and throw lengths on one bus -----------------------------------------------------
# (switch, samples/s, stroke s, throw length s): machine types that stroke faster or slower, units that log slower
MIXED = [("r10-5s", 10, 4.4, 5.0), ("r25-6s", 25, 5.4, 6.5), ("r50-8s", 50, 6.4, 8.0), ("r100-9s", 100, 8.4, 9.0)]


class SampleClock:
    """The shortest time between two motor samples of each switch: its sample period."""

    def __init__(self, session: zenoh.Session):
        self.last: dict[str, int] = {}
        self.period_ns: dict[str, int] = {}
        self._subscriber = session.declare_subscriber("railswitch/*/motor", self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        motor = decode(MotorSample, sample.payload.to_bytes())
        if motor.switch_id in self.last:
            step = motor.t_ns - self.last[motor.switch_id]
            self.period_ns[motor.switch_id] = min(step, self.period_ns.get(motor.switch_id, step))
        self.last[motor.switch_id] = motor.t_ns


def test_switches_of_four_rates_and_lengths_on_one_bus_are_all_diagnosed(tmp_path):
    with ServiceProcesses(tmp_path) as services:
        bus = start_router(services)
        session = client(bus)
        try:
            collector, clock = DiagnosisCollector(session), SampleClock(session)
            services.start("diagnoser", "--connect", bus, "--state", str(tmp_path / "baselines"))
            wait_ready(session, services, diagnoser=1)
            simulators = [services.start("simulator", "--connect", bus, "--switch-id", switch, "--rate", str(rate),
                                         "--stroke", str(stroke), "--throw-length", str(length), "--throws", "2",
                                         "--speed", "10")
                          for switch, rate, stroke, length in MIXED]
            for simulator in simulators:
                assert simulator.wait(120) == 0, services.log(simulator)
            wait_for(lambda: len(collector.received) >= 2 * len(MIXED), 120, "a diagnosis of every throw")
        finally:
            session.close()
    assert clock.period_ns == {switch: round(1e9 / rate) for switch, rate, _, _ in MIXED}
    lengths = {(d.switch_id, d.throw_index): (d.t_end_ns - d.t_start_ns) / 1e9 for d in collector.received}
    # The end event falls on a sample: within one sample period of the length asked for (6.48 s for 6.5 s at 25/s).
    assert lengths == {(switch, k): pytest.approx(length, abs=1 / rate) for switch, rate, _, length in MIXED
                       for k in range(2)}
    undecided = {(d.switch_id, d.throw_index): d.reason for d in collector.received if d.decision == "unknown"}
    assert not undecided
