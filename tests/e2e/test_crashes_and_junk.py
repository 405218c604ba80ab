"""Junk on the bus, crashed and restarted processes, damaged files (issue 6)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from railswitch.schemas import (
    CHANNEL_MODELS,
    MotorSample,
    ServiceStatus,
    decode,
    encode,
    key_expr,
)
from railswitch.services.adapters.recordings import load_recording
from railswitch.services.adapters.processes import free_loopback_endpoint, services_alive
from tests.live import (
    ROOT,
    DiagnosisCollector,
    ServiceProcesses,
    ServiceWatch,
    ThrowWatcher,
    client,
    instance_of,
    live_bus,
    throw_event,
    wait_for,
    wait_ready,
)

KINDS = list(CHANNEL_MODELS)


# -- junk on the live bus -------------------------------------------------------------------------
def junk(switch_id: str, t_ns: int) -> list[tuple[str, bytes]]:
    """Every kind of bad payload, on every key the services read, around time t_ns."""
    sample = {"switch_id": switch_id, "seq": 3, "t_ns": t_ns, "current_a": 1.0, "angle_rad": 0.0,
              "velocity_rad_s": 0.0}
    bad = [
        b"\xff\xfe\x00not json at all",
        b'{"switch_id": "' + switch_id.encode() + b'", "seq": 1',  # truncated
        json.dumps({**sample, "current_a": "high"}).encode(),  # wrong type
        json.dumps({"switch_id": switch_id}).encode(),  # missing fields
        json.dumps(sample).replace('"current_a": 1.0', '"current_a": NaN').encode(),
        json.dumps(sample).replace('"current_a": 1.0', '"current_a": Infinity').encode(),
        json.dumps({**sample, "current_a": 1e12}).encode(),  # absurd
        json.dumps({**sample, "seq": -4}).encode(),  # negative seq
        b'{"pad": "' + b"x" * (3 << 20) + b'"}',  # several megabytes
    ]
    out = [(key_expr(switch_id, kind), payload) for kind in KINDS for payload in bad]
    out.append((key_expr(switch_id, "motor"), json.dumps({**sample, "t_ns": 1_000}).encode()))  # time going back
    out.append((key_expr(switch_id, "motor"), json.dumps({**sample, "t_ns": t_ns - 10**9}).encode()))  # repeated seq
    end = throw_event("end", 999, t_ns, switch_id)
    out.append((key_expr(switch_id, "throw"), encode(end)))  # an end without its start
    return out


def test_junk_on_every_key_is_counted_and_the_valid_stream_still_diagnosed(tmp_path):
    scenario = tmp_path / "s.toml"
    scenario.write_text('interval_s = 10.0\n[[switches]]\nid = "sw1"\nthrows = 4\n'
                        'faults = { obstacle_friction = 1e5, obstacle_position = 1.1 }\n')
    recording = tmp_path / "junk.mcap"
    statuses: dict[str, ServiceStatus] = {}
    with live_bus(tmp_path) as (services, endpoint, session, collector):
        session.declare_subscriber("railswitch/@service/*/*/status", lambda s: statuses.__setitem__(
            str(s.key_expr).split("/")[2], decode(ServiceStatus, s.payload.to_bytes())))
        watches = {name: ServiceWatch(session, name) for name in ("diagnoser", "recorder")}
        diagnoser = services.start("diagnoser", "--connect", endpoint, "--status-interval", "0.5")
        recorder = services.start("recorder", "--connect", endpoint, "--out", str(recording), "--status-interval",
                                  "0.5")
        wait_ready(session, services, diagnoser=1, recorder=1)
        simulator = services.start("simulator", "--connect", endpoint, "--scenario", str(scenario), "--speed", "5")
        wait_for(lambda: len(collector.received) >= 1, 120, "the first diagnosis")
        latest_t = collector.received[0].t_end_ns
        # An unknown switch: valid start with no end, then every kind of junk.
        session.put(key_expr("ghost", "throw"), encode(throw_event("start", 0, latest_t, "ghost")))
        while simulator.poll() is None:
            for key, payload in junk("sw1", latest_t) + junk("ghost", latest_t):
                session.put(key, payload)
            time.sleep(0.3)
        assert simulator.returncode == 0, services.log(simulator)
        wait_for(lambda: len(collector.received) >= 4, 60, "four diagnoses")
        for name, process in (("diagnoser", diagnoser), ("recorder", recorder)):
            watches[name].drained(instance_of(process))  # its status after the last junk
        assert diagnoser.poll() is None and recorder.poll() is None
        logs = {"diagnoser": services.log(diagnoser), "recorder": services.log(recorder)}
    decisions = {d.throw_index: d.decision for d in collector.received if d.switch_id == "sw1"}
    assert decisions == {k: "obstacle" for k in range(4)}
    for name in ("diagnoser", "recorder"):
        rejected = statuses[name].rejected
        assert {"motor: not utf-8", "motor: not json", "motor: payload over 1 MiB",
                "motor: time not after the previous sample's (repeated or going back)"} <= set(rejected), rejected
        assert any(reason.startswith("motor: validation: current_a") for reason in rejected), rejected
        assert logs[name].count("rejected a message") == len(rejected)  # one line per kind, not per message
    assert "throw: end without its start" in statuses["diagnoser"].rejected
    assert any(reason.startswith("truth:") for reason in statuses["recorder"].rejected)
    seqs = [m.seq for m in load_recording(recording).messages if isinstance(m, MotorSample) and m.switch_id == "sw1"]
    assert seqs == list(range(len(seqs)))  # junk samples never reached the file


# -- crashes and restarts -------------------------------------------------------------------------
def test_a_diagnoser_killed_during_a_throw_and_restarted_diagnoses_the_next_full_throw(tmp_path):
    with live_bus(tmp_path) as (services, endpoint, session, collector):
        throws = ThrowWatcher(session)
        first = services.start("diagnoser", "--connect", endpoint)
        wait_ready(session, services, diagnoser=1)
        services.start("simulator", "--connect", endpoint, "--switch-id", "sw1", "--throws", "6", "--speed", "2",
                       "--fault", "bearing_friction=6000")
        wait_for(lambda: 1 in throws.starts, 60, "throw 1 to start")
        time.sleep(1.0)  # mid-throw (3.5 s of wall time at 2x)
        services.stop(first, signal.SIGKILL)
        wait_for(lambda: services_alive(session)["diagnoser"] == 0, 30, "the killed diagnoser's token to go")
        second = services.start("diagnoser", "--connect", endpoint)
        wait_ready(session, services, diagnoser=1)
        # the next full throw is the first to start once the new diagnoser is up (how many went by while it
        # started depends on the machine, not on what this test guards)
        next_full = max(throws.starts) + 1
        assert next_full <= 5, "the restarted diagnoser took the whole run to start"
        wait_for(lambda: any(d.throw_index >= next_full for d in collector.received), 120, "a throw after the restart")
        assert second.poll() is None
    by_throw = collector.decisions()
    assert by_throw["sw1", 0] == "missing_bearing"
    assert ("sw1", 1) not in by_throw  # its start went by while no diagnoser ran
    reasons = {d.throw_index: d.reason for d in collector.received if d.switch_id == "sw1"}
    assert by_throw["sw1", next_full] == "missing_bearing", (next_full, reasons)  # why, when it is not


def test_services_reconnect_after_a_router_restart_and_the_recording_shows_a_bounded_gap(tmp_path):
    recording = tmp_path / "gap.mcap"
    endpoint = free_loopback_endpoint()
    with ServiceProcesses(tmp_path) as services:
        router = services.start("router", "--listen", endpoint)
        session = client(endpoint)
        try:
            collector = DiagnosisCollector(session)
            services.start("diagnoser", "--connect", endpoint)
            recorders = ServiceWatch(session, "recorder")
            recorder = services.start("recorder", "--connect", endpoint, "--out", str(recording), "--status-interval",
                                      "0.5")
            wait_ready(session, services, diagnoser=1, recorder=1)
            simulator = services.start("simulator", "--connect", endpoint, "--switch-id", "sw1", "--throws", "6",
                                       "--speed", "2", "--fault", "left_bolt_offset=0.05")
            wait_for(lambda: len(collector.received) >= 1, 120, "the first diagnosis")
            services.stop(router)
            time.sleep(2.0)
            services.start("router", "--listen", endpoint)
            assert simulator.wait(120) == 0
            wait_for(lambda: any(d.throw_index >= 4 for d in collector.received), 60, "diagnoses after the restart")
            recorders.drained(instance_of(recorder))  # it has the last diagnoses too
            assert services.stop(recorder) == 0
        finally:
            session.close()
    after = {d.throw_index: d.decision for d in collector.received if d.throw_index >= 4}
    assert set(after.values()) == {"left_bolt"}
    seqs = sorted(m.seq for m in load_recording(recording).messages if isinstance(m, MotorSample))
    missing = seqs[-1] + 1 - len(seqs)
    # Visible, and bounded: 2 s down plus at most a few seconds of reconnection, at 2x and 50 Hz.
    assert 0 < missing <= 8 * 2 * 50, missing
    assert seqs[-1] >= 6 * 350  # the recording went on to the last throw


def test_a_killed_recorders_file_is_recovered_with_at_most_a_few_seconds_lost(tmp_path):
    recording = tmp_path / "killed.mcap"
    with live_bus(tmp_path) as (services, endpoint, session, collector):
        watcher = ThrowWatcher(session)
        recorder = services.start("recorder", "--connect", endpoint, "--out", str(recording))
        wait_ready(session, services, recorder=1)
        services.start("simulator", "--connect", endpoint, "--switch-id", "sw1", "--throws", "3")
        # 10 s of samples on the bus (at 50 Hz, real time), however long the simulator took to start
        wait_for(lambda: watcher.samples >= 10 * 50, 120, "10 s of samples")
        services.stop(recorder, signal.SIGKILL)
        killed_at_ns = watcher.last_sample_ns
    assert load_recording(recording).damage is not None  # no summary: the file was never finished
    recovered = tmp_path / "recovered.mcap"
    result = subprocess.run([sys.executable, "-m", "railswitch", "recover", str(recording), "-o", str(recovered)],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "recovered" in result.stdout and len(result.stdout.strip().splitlines()) == 1
    back = load_recording(recovered)
    assert back.damage is None
    last_ns = max(m.t_ns for m in back.messages if isinstance(m, MotorSample))
    lost_s = (killed_at_ns - last_ns) * 1e-9
    assert 0 <= lost_s <= 4.0, lost_s
    seqs = [m.seq for m in back.messages if isinstance(m, MotorSample)]
    assert seqs == list(range(len(seqs))) and len(seqs) > 5 * 50


@pytest.mark.parametrize("out, words", [
    ("/proc/railswitch.mcap", "cannot write recording"),
    ("/dev/full", "cannot"),
])
def test_an_unwritable_or_full_output_fails_at_start_up(out, words):
    if not os.path.exists(os.path.dirname(out)):
        pytest.skip(f"{os.path.dirname(out)} does not exist here")
    # No router runs: a recorder that got as far as connecting would wait forever.
    result = subprocess.run([sys.executable, "-m", "railswitch", "recorder", "--connect", free_loopback_endpoint(),
                             "--out", out], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert words in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr


# -- damaged recordings ---------------------------------------------------------------------------
RECORDING = ROOT / "recordings" / "left_bolt.mcap"


def _damaged(tmp_path: Path, kind: str) -> Path:
    data = RECORDING.read_bytes()
    path = tmp_path / f"{kind}.mcap"
    if kind == "truncated":
        path.write_bytes(data[: len(data) * 2 // 3])
    elif kind == "corrupted":
        middle = len(data) // 2
        path.write_bytes(data[:middle] + bytes(4096) + data[middle + 4096:])
    else:  # nothing readable
        path.write_bytes(b"\x89MCAP0\r\n" + os.urandom(64))
    return path


@pytest.fixture(scope="module")
def router_endpoint(tmp_path_factory):
    """A router for replays of damaged files to publish into."""
    with ServiceProcesses(tmp_path_factory.mktemp("router")) as services:
        endpoint = free_loopback_endpoint()
        services.start("router", "--listen", endpoint)
        yield endpoint


@pytest.mark.parametrize("kind", ["truncated", "corrupted", "garbage"])
@pytest.mark.parametrize("command", ["replay", "diagnose"])
def test_damaged_recordings_give_one_line_and_what_was_recovered(tmp_path, router_endpoint, kind, command):
    path = _damaged(tmp_path, kind)
    args = [str(path), "--connect", router_endpoint, "--fast"] if command == "replay" else [str(path)]
    result = subprocess.run([sys.executable, "-m", "railswitch", command, *args], cwd=ROOT, capture_output=True,
                            text=True, timeout=120, env={**os.environ, "COLUMNS": "200"})
    assert "Traceback" not in result.stderr
    damage_lines = [line for line in result.stderr.splitlines() if str(path) in line]
    assert len(damage_lines) == 1, result.stderr
    if kind == "garbage":
        assert result.returncode == 1
        assert "recovered 0 messages" in damage_lines[0]
    else:
        assert result.returncode == 0, result.stderr
        assert "recovered" in damage_lines[0]
