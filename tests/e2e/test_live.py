"""End to end with real processes: router, simulator, diagnoser, recorder, replay and demo on loopback."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import pytest
from mcap.reader import make_reader

from railswitch.schemas import FaultCommand, encode, key_expr
from railswitch.services.adapters.processes import free_loopback_endpoint
from tests.live import (
    ROOT,
    DiagnosisCollector,
    ServiceProcesses,
    ServiceWatch,
    client,
    instance_of,
    jsonl_decisions,
    live_bus,
    wait_for,
    wait_ready,
)

SCENARIO = """
interval_s = 10.0

[[switches]]
id = "healthy"
throws = 3

[[switches]]
id = "faulty"
throws = 3
faults = { left_bolt_offset = 0.05 }
"""
SPEED = "20"


@dataclass(frozen=True)
class LiveRun:
    recording: Path
    decisions: dict[tuple[str, int], str]
    recorder_exit: int
    watched: str
    features: dict[tuple[str, int], dict]


@pytest.fixture(scope="module")
def live_run(tmp_path_factory) -> LiveRun:
    """Two switches (a left bolt offset of 50 mm on one), three throws each, at 20x real time."""
    work = tmp_path_factory.mktemp("live")
    scenario = work / "scenario.toml"
    scenario.write_text(SCENARIO)
    recording = work / "live.mcap"
    with live_bus(work) as (services, endpoint, session, collector):
        services.start("diagnoser", "--connect", endpoint)
        recorders = ServiceWatch(session, "recorder")
        recorder = services.start("recorder", "--connect", endpoint, "--out", str(recording), "--status-interval", "0.5")
        watch = services.start("watch", "--connect", endpoint, "--jsonl", "--count", "6")
        wait_ready(session, services, diagnoser=1, recorder=1)
        simulator = services.start("simulator", "--connect", endpoint, "--scenario", str(scenario), "--speed", SPEED)
        assert simulator.wait(120) == 0, services.log(simulator)
        wait_for(lambda: len(collector.received) >= 6, 60, "six diagnoses")
        recorders.drained(instance_of(recorder))  # the recorder takes the last diagnoses off the bus too
        recorder.send_signal(signal.SIGTERM)
        recorder_exit = recorder.wait(30)
        watch.wait(30)
        watched = services.log(watch)
    return LiveRun(recording, collector.decisions(), recorder_exit, watched, collector.features())


def test_live_diagnoses_match_the_injected_faults(live_run):
    assert live_run.decisions == {**{("healthy", k): "nominal" for k in range(3)},
                                  **{("faulty", k): "left_bolt" for k in range(3)}}


def test_watch_prints_each_diagnosis_as_a_json_line(live_run):
    lines = [line for line in live_run.watched.splitlines() if line.startswith("{")]
    assert jsonl_decisions("\n".join(lines)) == live_run.decisions


def test_sigterm_leaves_a_complete_recording_with_every_channel(live_run):
    assert live_run.recorder_exit == 0
    with open(live_run.recording, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None  # finished: summary section written
        topics = {channel.topic for channel in summary.channels.values()}
        counts = {}
        for _, channel, _ in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    expected = {key_expr(s, kind) for s in ("healthy", "faulty") for kind in ("motor", "throw", "truth", "diagnosis")}
    assert expected <= topics
    assert all(counts[key_expr(s, "diagnosis")] == 3 for s in ("healthy", "faulty"))
    assert all(counts[key_expr(s, "throw")] == 6 for s in ("healthy", "faulty"))


def test_recording_has_no_missing_samples(live_run):
    from railswitch.services.adapters.recordings import load_recording

    recording = load_recording(live_run.recording)
    assert recording.note() is None
    for switch in ("healthy", "faulty"):
        seqs = [m.seq for m in recording.messages if getattr(m, "seq", None) is not None and m.switch_id == switch]
        assert seqs == list(range(len(seqs))) and len(seqs) > 3 * 350


def test_replay_into_a_fresh_diagnoser_and_offline_diagnosis_agree_with_live(live_run, tmp_path):
    with live_bus(tmp_path) as (services, endpoint, session, collector):
        services.start("diagnoser", "--connect", endpoint)
        wait_ready(session, services, diagnoser=1)
        replay = services.start("replay", str(live_run.recording), "--connect", endpoint, "--fast")
        assert replay.wait(120) == 0, services.log(replay)
        wait_for(lambda: len(collector.received) >= 6, 60, "six diagnoses of the replay")
    offline = subprocess.run([sys.executable, "-m", "railswitch", "diagnose", str(live_run.recording), "--jsonl"],
                             cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert offline.returncode == 0, offline.stderr
    assert collector.decisions() == live_run.decisions
    assert jsonl_decisions(offline.stdout) == live_run.decisions
    # a throw's features come from its samples alone: the same from the bus, a replay and the file
    offline_features = {(d["switch_id"], d["throw_index"]): d["features"]
                        for d in map(json.loads, offline.stdout.splitlines())}
    assert len(live_run.features) == 6 and live_run.features["faulty", 2]["peak_current_a"] > 0
    assert collector.features() == live_run.features == offline_features


def test_fault_command_changes_the_next_throws_diagnosis(tmp_path):
    """Also: services started before their router wait for it."""
    with ServiceProcesses(tmp_path) as services:
        endpoint = free_loopback_endpoint()
        early = services.start("diagnoser", "--connect", endpoint)
        wait_for(lambda: "waiting for the bus" in services.log(early), 60, "the diagnoser to wait for its router",
                 abort=lambda: services.log(early, 8) if early.poll() is not None else None)
        services.start("router", "--listen", endpoint)
        session = client(endpoint)
        try:
            collector = DiagnosisCollector(session)
            wait_ready(session, services, diagnoser=1)
            simulator = services.start("simulator", "--connect", endpoint, "--switch-id", "sw7", "--throws", "5",
                                       "--speed", "5")
            wait_for(lambda: len(collector.received) >= 1, 120, "the first diagnosis")
            command = FaultCommand(switch_id="sw7", params={"bearing_friction": 6000.0})
            session.put(key_expr("sw7", "inject"), encode(command))
            sent_during = len(collector.received)  # throws diagnosed when the command went out
            assert simulator.wait(120) == 0, services.log(simulator)
            wait_for(lambda: len(collector.received) >= 5, 60, "five diagnoses")
        finally:
            session.close()
    decisions = [collector.decisions()["sw7", k] for k in range(5)]
    assert decisions[0] == "nominal"
    # The throw running when the command arrived was computed before it; the one after is faulty.
    assert decisions[sent_during + 1:] == ["missing_bearing"] * (4 - sent_during)


def test_demo_with_small_settings_exits_0_and_writes_its_recording(tmp_path):
    out = tmp_path / "demo.mcap"
    result = subprocess.run([sys.executable, "-m", "railswitch", "demo", "--switches", "2", "--throws", "2",
                             "--speed", "20", "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "4 of 4 throws decided as expected" in result.stdout, result.stdout + result.stderr
    with open(out, "rb") as f:
        topics = {channel.topic for _, channel, _ in make_reader(f).iter_messages()}
    assert {key_expr(s, "diagnosis") for s in ("sw1", "sw2")} <= topics


def _processes_mentioning(text: str) -> list[int]:
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text in (entry / "cmdline").read_bytes().decode(errors="replace"):
                    pids.append(int(entry.name))
            except OSError:
                continue
    return pids


def test_ctrl_c_stops_the_demos_processes_and_still_finishes_its_recording(tmp_path):
    out = tmp_path / "interrupted.mcap"
    demo = subprocess.Popen([sys.executable, "-m", "railswitch", "demo", "--switches", "2", "--throws", "20",
                             "--speed", "2", "--out", str(out)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(demo.stdout), daemon=True)
    reader.start()
    try:
        # Interrupted once its first throw was diagnosed (a throw's samples went through the bus and the recorder):
        # a fixed wait after the recorder started left it empty on a loaded machine, the simulator still starting.
        wait_for(lambda: any(" throw 0 " in line for line in lines), 300, "the demo's first diagnosis",
                 abort=lambda: None if demo.poll() is None else f"the demo exited first: {''.join(lines)[-2000:]}")
        demo.send_signal(signal.SIGINT)
        demo.wait(timeout=120)
        reader.join(timeout=30)
        output = "".join(lines)
    finally:
        if demo.poll() is None:
            demo.kill()
    assert demo.returncode == 130, output
    assert "stopped early" in output and "recording:" in output
    assert _processes_mentioning(str(out)) == []  # the recorder (and the rest) stopped with it
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 100
