"""CSV input (services/adapters/csv_throws.py): a trackside logger's export of one row per sample is diagnosed as the
same throws in a recording are, through the real command; a file that cannot be read gives one line naming the
file, row and column, exit code 2 and nothing on stdout."""
from __future__ import annotations

import csv
import json
import random
import subprocess
import sys
from pathlib import Path

import pytest

from railswitch.services.adapters.csv_throws import CsvInputError, load_csv
from railswitch.services.adapters.recordings import load_recording
from railswitch.services.core.throw_cutter import cut_throws

ROOT = Path(__file__).resolve().parents[2]
RECORDINGS = ROOT / "recordings"
RECORDING = RECORDINGS / "left_bolt.mcap"
HEADER = ["logger_row", "switch_id", "throw_index", "direction", "t_s", "current_a", "angle_rad", "velocity_rad_s"]


def write_csv(path: Path, recording: Path = RECORDING, signals: tuple[str, ...] = ("current_a", "angle_rad", "velocity_rad_s"),
              drop: str | None = None) -> None:
    """The recording's complete throws as a logger exports them: each throw's rows in time order, the throws' rows
    interleaved as two loggers' files merged, a column the reader does not know, `drop` left out."""
    throws = [t for t in cut_throws(load_recording(recording).messages) if t.complete]
    rows = [[[t.switch_id, t.start.throw_index, t.start.direction, repr(float(t_s)),
              *(repr(float(getattr(t.signals, name)[k])) if name in signals else "" for name in HEADER[5:])]
             for k, t_s in enumerate(t.t_s)] for t in throws]
    merged, rng = [], random.Random(1)
    while any(rows):
        merged.append(rng.choice([r for r in rows if r]).pop(0))
    header = [name for name in HEADER if name != drop]
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for number, row in enumerate(merged):
            cells = dict(zip(HEADER, [str(number), *row]))
            writer.writerow([cells[name] for name in header])


def diagnose(path: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "railswitch", "diagnose", str(path), "--jsonl"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)


def decisions(result: subprocess.CompletedProcess) -> list[tuple]:
    assert result.returncode == 0, result.stderr
    found = [json.loads(line) for line in result.stdout.splitlines()]
    return [(d["switch_id"], d["throw_index"], d["direction"], d["decision"], d["faults"],
             {n: round(v, 4) for n, v in (d["estimate"] or {}).get("params", {}).items()}) for d in found]


@pytest.mark.parametrize("fault", ["left_bolt", "missing_bearing"])
def test_the_same_throws_from_csv_and_from_the_recording_get_the_same_decisions(tmp_path, fault):
    log = tmp_path / "logger.csv"
    write_csv(log, RECORDINGS / f"{fault}.mcap")
    from_csv, from_mcap = decisions(diagnose(log)), decisions(diagnose(RECORDINGS / f"{fault}.mcap"))
    assert len(from_mcap) >= 2 and any(d[3] == fault for d in from_mcap)  # the fault is there to be found
    assert from_csv == from_mcap


def test_a_current_only_csv_is_read_as_current_only_throws(tmp_path):
    log = tmp_path / "current.csv"
    write_csv(log, signals=("current_a",), drop="velocity_rad_s")
    records = [r.message for r in load_csv(log).records]
    assert records and all(r.angle_rad is None and r.velocity_rad_s is None and r.current_a for r in records)
    assert [r.throw_index for r in records] == sorted(r.throw_index for r in records)


@pytest.mark.parametrize("damage, expected", [
    (lambda lines: [lines[0].replace("current_a", "amps"), *lines[1:]], "row 1: no column current_a (the header needs switch_id, throw_index, direction, t_s, current_a; "
     "angle_rad, velocity_rad_s are optional)"),
    (lambda lines: [lines[0], lines[1], lines[2].replace(",left_to_right,", ",left,"), *lines[3:]],
     "row 3, column direction: 'left' is not one of left_to_right, right_to_left"),
    (lambda lines: [lines[0], *[line.replace(line.split(",")[5], "n/a") if k == 40 else line
                                for k, line in enumerate(lines[1:], start=2)]],
     "row 40, column current_a: 'n/a' is not a number"),
])
def test_a_bad_csv_gives_one_line_naming_file_row_and_column_and_exit_2(tmp_path, damage, expected):
    good = tmp_path / "good.csv"
    write_csv(good)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(damage(good.read_text().splitlines())) + "\n")
    result = diagnose(bad)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.strip() == f"railswitch diagnose: {bad}: {expected}"


def test_a_time_going_back_within_a_throw_names_its_row(tmp_path):
    log = tmp_path / "log.csv"
    lines = ["switch_id,throw_index,direction,t_s,current_a", "sw1,0,left_to_right,0.0,0.1",
             "sw2,0,right_to_left,0.0,0.1", "sw1,0,left_to_right,0.01,2.0", "sw1,0,left_to_right,0.005,2.1"]
    log.write_text("\n".join(lines) + "\n")
    with pytest.raises(CsvInputError, match=r"log.csv: row 5, column t_s: 0.005 s does not come after the throw's "
                                            r"previous sample at 0.01 s"):
        load_csv(log)
    log.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    with pytest.raises(CsvInputError, match="not UTF-8 text"):
        load_csv(log)
