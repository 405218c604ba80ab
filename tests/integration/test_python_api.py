"""The Python API (railswitch/api.py): the README's first Python block runs as written from an empty folder, and a
throw read from a file or built from arrays is diagnosed as the same throw cut off the bus."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import railswitch
from tests.integration.test_csv_input import write_csv

ROOT = Path(__file__).resolve().parents[2]


def test_the_readmes_first_python_block_runs_from_an_empty_folder_and_finds_the_bolt(tmp_path):
    block = re.search(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    result = subprocess.run([sys.executable, "-c", block], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == 4 and all("left_to_right" in line or "right_to_left" in line for line in lines)
    assert "['left_bolt']" in lines[-1]  # a left bolt 5 cm out is found by the last throw at the latest


def test_throws_from_a_csv_file_and_from_arrays_are_the_recordings_own(tmp_path):
    recording = ROOT / "recordings" / "left_bolt.mcap"
    log = tmp_path / "log.csv"
    write_csv(log, recording)
    from_mcap, from_csv = railswitch.read_throws(recording), railswitch.read_throws(log)
    assert len(from_csv) == len([t for t in from_mcap if t.complete]) >= 2
    for streamed, logged in zip(from_mcap, from_csv):
        built = railswitch.make_throw(streamed.switch_id, streamed.start.throw_index, streamed.start.direction,
                                      streamed.t_s, streamed.signals.current_a, streamed.signals.angle_rad,
                                      streamed.signals.velocity_rad_s)
        for throw in (logged, built):
            assert isinstance(throw, railswitch.Throw) and throw.complete
            assert np.array_equal(throw.t_s, streamed.t_s)
            assert np.array_equal(throw.signals.current_a, streamed.signals.current_a)
            assert np.array_equal(throw.signals.velocity_rad_s, streamed.signals.velocity_rad_s)


def test_a_throw_built_from_arrays_is_diagnosed_as_the_simulated_one(plant):
    simulated = railswitch.simulate(2, faults={"right_bolt_offset": 0.08}, seed=3, plant=plant)
    assert simulated[0].truth.right_bolt_offset == 0.08
    first, second = railswitch.Diagnoser(model="poly"), railswitch.Diagnoser(model="poly")
    for throw in simulated:
        built = railswitch.make_throw(throw.switch_id, throw.start.throw_index, throw.start.direction, throw.t_s,
                                      throw.signals.current_a, throw.signals.angle_rad, throw.signals.velocity_rad_s,
                                      t_start_ns=throw.start.t_ns)
        by_sim, by_arrays = first.diagnose(throw).diagnosis, second.diagnose(built).diagnosis
        assert by_sim.hypotheses
        assert by_arrays.model_dump(exclude={"latency_ms"}) == by_sim.model_dump(exclude={"latency_ms"})


@pytest.mark.parametrize("store", ["sqlite", "postgresql"])
def test_read_history_gives_a_stores_messages_back_oldest_first(plant, tmp_path, store, request):
    from railswitch.schemas import encode
    from railswitch.services.adapters.history_store import HistoryRow, open_history

    db = str(tmp_path / "history.sqlite") if store == "sqlite" else request.getfixturevalue("pg_url")
    diagnoser = railswitch.Diagnoser(model="poly")
    results = [diagnoser.diagnose(throw) for throw in railswitch.simulate(3, seed=5, plant=plant)]
    with open_history(db) as written:
        written.write([HistoryRow("sw1", kind, r.diagnosis.throw_index, r.diagnosis.t_end_ns, encode(message).decode())
                       for r in results for kind, message in (("diagnosis", r.diagnosis), ("health", r.health))])
    assert railswitch.read_history(db, "sw1") == [r.diagnosis for r in results]
    assert railswitch.read_history(db, "sw1", "health", limit=2) == [r.health for r in results[1:]]
    assert railswitch.read_history(db, "sw2") == []
    with pytest.raises(ValueError, match="kind 'diagnoses' is not one of diagnosis, health, alarm"):
        railswitch.read_history(db, "sw1", "diagnoses")
