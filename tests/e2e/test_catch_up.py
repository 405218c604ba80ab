"""No throw lost to an outage (docs/contracts.md section 3, Catching up): the simulator's records and the diagnoser's
diagnoses go out through Zenoh advanced publishers that keep each switch's latest ones, and a diagnoser or historian
that was down asks for them when it comes back. Real processes on a real router; the switch states on disk are the
test's own (tests/conftest.py), as a restarted diagnoser's are its own."""
from __future__ import annotations

import json
import re
import signal
import sqlite3
import subprocess
import threading
import time
from pathlib import Path

import zenoh

from railswitch.services.adapters.processes import services_alive
from tests.live import ServiceProcesses, ServiceWatch, instance_of, live_bus, wait_for, wait_ready

SWITCHES = ("sw1", "sw2", "sw3")
THROWS = 40  # 20 s of wall time: the simulator (and its cache) outlives the outage and the restart
INTERVAL_S = 10.0
SPEED = 20.0  # a switch throws every half second of wall time
IN_FLIGHT_S = 1.0  # longer than a diagnoser takes over the throws it has received


class RecordTimes:
    """When each record (switch, throw index) went by on the bus; of a sample stream, when each throw's end event
    did."""

    def __init__(self, session: zenoh.Session):
        self.arrived: dict[tuple[str, int], float] = {}
        self._lock = threading.Lock()
        self._subscribers = [session.declare_subscriber("railswitch/*/record", self._on_sample),
                             session.declare_subscriber("railswitch/*/throw", self._on_sample)]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        message = json.loads(sample.payload.to_bytes())
        if message.get("phase", "end") == "end":
            with self._lock:
                self.arrived[(message["switch_id"], message["throw_index"])] = time.monotonic()

    def between(self, start_s: float, end_s: float) -> set[tuple[str, int]]:
        with self._lock:
            return {throw for throw, at_s in self.arrived.items() if start_s <= at_s <= end_s}


def simulator_args(endpoint: str, *extra: str, records: bool = True) -> list[str]:
    return ["--connect", endpoint, *(a for s in SWITCHES for a in ("--switch-id", s)), "--throws", str(THROWS),
            "--interval", str(INTERVAL_S), "--speed", str(SPEED), *(["--as-records"] if records else []), *extra]


def stored_diagnoses(db: Path) -> list[tuple[str, int]]:
    with sqlite3.connect(db) as connection:
        return [tuple(row) for row in connection.execute(
            "SELECT switch_id, throw_index FROM history WHERE kind = 'diagnosis'")]


def outage(services: ServiceProcesses, session: zenoh.Session, endpoint: str, records: RecordTimes,
           down_s: float) -> tuple[subprocess.Popen, set[tuple[str, int]]]:
    """Kill the only diagnoser, wait down_s, start another: the new one, and the throws that ended while none was
    there (or in the second before the kill: the killed one may not have diagnosed those yet)."""
    first = next(p for name, _, p in services.started if name == "diagnoser" and p.poll() is None)
    down_at = time.monotonic() - IN_FLIGHT_S
    services.stop(first, signal.SIGKILL)
    wait_for(lambda: services_alive(session)["diagnoser"] == 0, 30, "the killed diagnoser's token to go")
    time.sleep(down_s)
    second = services.start("diagnoser", "--connect", endpoint, "--status-interval", "0.5")
    wait_ready(session, services, diagnoser=1)
    return second, records.between(down_at, time.monotonic())


def test_the_only_diagnoser_killed_and_restarted_diagnoses_every_throw_and_history_stores_each_once(tmp_path):
    db = tmp_path / "history.sqlite"
    everything = {(s, i) for s in SWITCHES for i in range(THROWS)}
    with live_bus(tmp_path) as (services, endpoint, session, collector):
        records = RecordTimes(session)
        services.start("diagnoser", "--connect", endpoint, "--status-interval", "0.5")
        historians = ServiceWatch(session, "historian")
        historian = services.start("historian", "--connect", endpoint, "--db", str(db), "--status-interval", "0.5")
        wait_ready(session, services, diagnoser=1, historian=1)
        simulator = services.start("simulator", *simulator_args(endpoint))
        wait_for(lambda: len(collector.received) >= 2 * len(SWITCHES), 120, "the first throws' diagnoses")
        _, while_down = outage(services, session, endpoint, records, down_s=2.0)
        assert simulator.wait(120) == 0, services.log(simulator)
        wait_for(lambda: set(collector.decisions()) >= everything, 120, "a diagnosis of every throw")
        wait_for(lambda: len(stored_diagnoses(db)) >= len(everything), 60, "every diagnosis in the history")
        historians.drained(instance_of(historian))  # so anything stored twice would be by now
    assert len(while_down) >= len(SWITCHES), "no throw ended while the diagnoser was down: the test shows nothing"
    assert set(collector.decisions()) == everything
    stored = stored_diagnoses(db)
    assert sorted(stored) == sorted(everything)  # each once


def test_a_sample_stream_s_throws_that_ended_while_the_only_diagnoser_was_down_come_from_the_recorder(tmp_path):
    """The simulator streams samples and events, which no publisher's cache can replay in order; the recorder keeps
    each switch's recent throws as records, and the restarted diagnoser diagnoses those it did not hear, once each,
    before going on live."""
    everything = {(s, i) for s in SWITCHES for i in range(THROWS)}
    with live_bus(tmp_path) as (services, endpoint, session, collector):
        records = RecordTimes(session)
        watch = ServiceWatch(session, "diagnoser")
        services.start("diagnoser", "--connect", endpoint, "--status-interval", "0.5")
        services.start("recorder", "--connect", endpoint, "--out", str(tmp_path / "all.mcap"))
        wait_ready(session, services, diagnoser=1, recorder=1)
        simulator = services.start("simulator", *simulator_args(endpoint, records=False))
        wait_for(lambda: len(collector.received) >= 2 * len(SWITCHES), 120, "the first throws' diagnoses")
        second, while_down = outage(services, session, endpoint, records, down_s=2.0)
        assert simulator.wait(120) == 0, services.log(simulator)
        try:
            wait_for(lambda: set(collector.decisions()) >= everything, 60, "a diagnosis of every throw")
        except TimeoutError as error:
            raise AssertionError(f"{error}: not diagnosed {sorted(everything - set(collector.decisions()))}; "
                                 f"{services.log(second)[-3000:]}") from None
        counters = watch.latest(instance_of(second)).counters
        watch.drained(instance_of(second))  # so anything diagnosed twice would be by now
        counts = collector.counts()
    assert len(while_down) >= len(SWITCHES), "no throw ended while the diagnoser was down: the test shows nothing"
    # those that ended before the new one subscribed came from the recorder (while_down runs on until it was ready)
    assert counters["recovered"] >= len(SWITCHES) and counters["missed"] == 0, counters
    # once each, but for a throw whose diagnosis the killed one published before saving its state (one a switch)
    twice = [throw for throw, n in counts.items() if n > 1]
    assert len(twice) <= len(SWITCHES) and all(counts[t] == 2 for t in twice), twice


def test_throws_older_than_the_cache_are_reported_missed_with_their_indices(tmp_path):
    """The simulator keeps 10 s of a switch's throws (2 records); a diagnoser down for longer misses some, and says
    which: the status counts them, the log names them, and every other throw is diagnosed."""
    everything = {(s, i) for s in SWITCHES for i in range(THROWS)}
    with live_bus(tmp_path) as (services, endpoint, session, collector):
        records = RecordTimes(session)
        watch = ServiceWatch(session, "diagnoser")
        services.start("diagnoser", "--connect", endpoint, "--status-interval", "0.5")
        wait_ready(session, services, diagnoser=1)
        simulator = services.start("simulator", *simulator_args(endpoint, "--outage", "10"))
        wait_for(lambda: len(collector.received) >= 2 * len(SWITCHES), 120, "the first throws' diagnoses")
        second, while_down = outage(services, session, endpoint, records, down_s=4.0)
        assert simulator.wait(120) == 0, services.log(simulator)
        wait_for(lambda: all((s, THROWS - 1) in collector.decisions() for s in SWITCHES), 120, "the last throws")
        diagnosed = set(collector.decisions())
        not_diagnosed = everything - diagnosed

        def counters() -> dict[str, int]:
            status = watch.latest(instance_of(second))
            return status.counters if status is not None else {}
        # Every throw not diagnosed is reported missed. A throw whose diagnosis the killed diagnoser published
        # but whose state it had not saved yet is reported too (one a switch at most): diagnosed, and missed.
        try:
            wait_for(lambda: len(not_diagnosed) <= counters().get("missed", 0) <= len(not_diagnosed) + len(SWITCHES),
                     10, f"{len(not_diagnosed)} missed throws in the status")
        except TimeoutError as error:
            raise AssertionError(f"{error}: {counters()}; not diagnosed {sorted(not_diagnosed)}; the new diagnoser "
                                 f"said {[line for line in services.log(second).splitlines() if 'missed' in line]}")
        log = services.log(second)
    assert len(while_down) >= 3 * len(SWITCHES)  # more than the 2 kept of each switch
    assert not_diagnosed and not_diagnosed <= while_down
    for switch_id in SWITCHES:
        reported = [range(int(first), int(last or first) + 1) for first, last in
                    re.findall(rf"{switch_id} throws (\d+)(?: to (\d+))? missed", log)]
        assert {i for s, i in not_diagnosed if s == switch_id} <= {i for r in reported for i in r}, log
