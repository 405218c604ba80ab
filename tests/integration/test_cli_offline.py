"""`railswitch simulate`, `describe` and `report` as a user runs them: real processes, real files."""
import json
import os
import subprocess
import sys

import pytest
from mcap.reader import make_reader

from railswitch.services.adapters.recordings import read_recording

RAILSWITCH = [sys.executable, "-m", "railswitch"]


def run(*args, cwd=None):
    return subprocess.run([*RAILSWITCH, *args], capture_output=True, text=True, timeout=300, cwd=cwd)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "left.mcap"
    result = run("simulate", "--out", str(path), "--switch-id", "pm-7", "--throws", "2",
                 "--fault", "left_bolt_offset=0.05", "--noise", "0.01", "--seed", "5")
    assert result.returncode == 0, result.stderr
    assert str(path) in result.stdout
    return path


def test_recording_reads_back_with_the_official_reader(recording):
    with open(recording, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(topics) == {"railswitch/pm-7/motor", "railswitch/pm-7/throw", "railswitch/pm-7/truth"}
        for channel in topics.values():
            assert channel.message_encoding == "json"
            assert summary.schemas[channel.schema_id].encoding == "jsonschema"
            json.loads(summary.schemas[channel.schema_id].data)
        counts = {topics[t].id: 0 for t in topics}
        for _, channel, message in reader.iter_messages():
            payload = json.loads(message.data)
            assert message.log_time == payload["t_ns"]
            counts[channel.id] += 1
    assert counts[topics["railswitch/pm-7/motor"].id] == 1 + 2 * 350  # 50 samples/s over two 7 s throws
    assert counts[topics["railswitch/pm-7/throw"].id] == 4


def test_throw_events_carry_direction_and_reference_profile(recording):
    events = [m.message for m in read_recording(recording) if m.kind == "throw"]
    assert [(e.throw_index, e.phase, e.direction) for e in events] == [
        (0, "start", "left_to_right"), (0, "end", "left_to_right"),
        (1, "start", "right_to_left"), (1, "end", "right_to_left")]
    assert events[1].t_ns - events[0].t_ns == 7_000_000_000
    assert max(events[0].reference_velocity_rad_s) > 100 > -100 > min(events[2].reference_velocity_rad_s)
    truth = [m.message for m in read_recording(recording) if m.kind == "truth"]
    assert truth and all(t.left_bolt_offset == 0.05 and t.active_modes() == ["left_bolt"] for t in truth)


def test_same_seed_gives_the_same_bytes_and_another_seed_does_not(recording, tmp_path):
    common = ["--switch-id", "pm-7", "--throws", "2", "--fault", "left_bolt_offset=0.05", "--noise", "0.01"]
    again, other = tmp_path / "again.mcap", tmp_path / "other.mcap"
    assert run("simulate", "--out", str(again), *common, "--seed", "5").returncode == 0
    assert run("simulate", "--out", str(other), *common, "--seed", "6").returncode == 0
    assert again.read_bytes() == recording.read_bytes()
    assert other.read_bytes() != recording.read_bytes()


@pytest.mark.parametrize("args,expected", [
    (["--fault", "stuck_blade=1"], ["stuck_blade", "left_bolt_offset"]),
    (["--fault", "left_bolt_offset=0.5"], ["0.5", "-0.02", "0.2"]),
    (["--fault", "bearing_friction=-5"], ["-5", "10000"]),
    (["--fault", "obstacle_position=1.5"], ["1.5", "1.02", "1.18"]),
    (["--fault", "obstacle_friction=nan"], ["nan"]),
    (["--fault", "left_bolt_offset"], ["NAME=VALUE"]),
    (["--throws", "0"], ["0", "1", "10000"]),
    (["--throws", "-3"], ["-3", "1", "10000"]),
    (["--throws", "two"], ["two"]),
    (["--noise", "2"], ["2", "0.5"]),
    (["--rate", "0"], ["0", "1000"]),
    (["--switch-id", "a/b"], ["a/b"]),
])
def test_bad_values_fail_in_one_line_with_exit_2_and_leave_no_file(tmp_path, args, expected):
    out = tmp_path / "x.mcap"
    result = run("simulate", "--out", str(out), *args)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    for text in expected:
        assert text in lines[0]
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("target", ["missing-dir/x.mcap", "."])
def test_unwritable_output_fails_in_one_line_before_simulating(tmp_path, target):
    result = run("simulate", "--out", str(tmp_path / target))
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1
    assert "cannot write recording" in result.stderr
    assert sorted(os.listdir(tmp_path)) == []


def test_describe_json_reports_plant_statistics():
    result = run("describe", "--json")
    assert result.returncode == 0, result.stderr
    plant = json.loads(result.stdout)["plant"]
    assert plant["states"] >= 250 and plant["rail_nodes"] >= 60 and plant["parameters"] > plant["states"]


def test_report_overlays_recordings_in_one_picture_per_throw(recording, tmp_path):
    nominal = tmp_path / "nominal.mcap"
    assert run("simulate", "--out", str(nominal), "--switch-id", "pm-7").returncode == 0
    result = run("report", str(recording), str(nominal), "--out", str(tmp_path / "pictures"))
    assert result.returncode == 0, result.stderr
    pictures = sorted((tmp_path / "pictures").glob("*.png"))
    assert [p.name for p in pictures] == ["pm-7_throw000_left_to_right.png", "pm-7_throw001_right_to_left.png"]
    assert all(p.read_bytes().startswith(b"\x89PNG") and p.stat().st_size > 20_000 for p in pictures)


def test_report_of_one_recording_draws_the_fits_and_the_estimates_over_throws(recording, tmp_path):
    result = run("report", str(recording), "--out", str(tmp_path / "fits"))
    assert result.returncode == 0, result.stderr
    names = sorted(p.name for p in (tmp_path / "fits").glob("*.png"))
    assert names == ["pm-7_estimates.png", "pm-7_health.png", "pm-7_throw000_left_to_right.png",
                     "pm-7_throw001_right_to_left.png"]  # estimates and health: one picture per switch
    assert (tmp_path / "fits" / "pm-7_estimates.png").stat().st_size > 20_000


def test_report_on_a_file_that_is_not_a_recording_fails_in_one_line(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"definitely not mcap")
    result = run("report", str(junk), "--out", str(tmp_path / "pictures"))
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"railswitch: error: {junk}: no throws found in 0 messages; not an MCAP file (bad magic bytes)"]


def test_report_on_a_truncated_recording_says_so_and_draws_what_was_recovered(recording, tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recording.read_bytes()[: recording.stat().st_size * 2 // 3])
    result = run("report", str(cut), "--out", str(tmp_path / "pictures"), "--model", "none")
    assert result.returncode == 0, result.stderr
    assert "truncated" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert len(list((tmp_path / "pictures").glob("*.png"))) >= 1
