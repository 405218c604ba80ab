"""Command-line quirks fixed: options beside `simulate --scenario`, `train --out DIR` checked before training,
`watch --duration` counted from the start, and the help of the commands that take --db naming both stores."""
from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import pytest

from railswitch.services.adapters.zenoh_bus import BusError, BusOptions
from railswitch.services.commands import train
from railswitch.services.commands.cli import COMMANDS, main
from railswitch.services.commands.watch import run_watch

SCENARIO = "[[switches]]\nid = 'a'\nthrows = 1\n"


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("extra, named", [
    (["--throws", "3", "--fault", "left_bolt_offset=0.05"], "--throws, --fault"),
    (["--plant", "motor.supply_v=99", "--switch-id", "sw9"], "--switch-id, --plant"),
    (["--seed", "0", "--rate", "50"], "--seed, --rate"),  # a default's value, given, is refused as well
])
def test_simulate_refuses_options_beside_a_scenario_in_one_line(tmp_path, capsys, extra, named):
    scenario = tmp_path / "s.toml"
    scenario.write_text(SCENARIO)
    out = tmp_path / "x.mcap"
    assert main(["simulate", "--out", str(out), "--scenario", str(scenario), *extra]) == 2
    assert one_line(capsys.readouterr().err) == f"railswitch: error: --scenario excludes {named} (the file says it)"
    assert not out.exists()


@pytest.fixture
def trained(monkeypatch):
    """train_and_save replaced by a stub that records the directory it was given (and whether it existed)."""
    calls = []

    def stub(name, *, out_dir=None, **_):
        calls.append((name, out_dir, out_dir is not None and Path(out_dir).is_dir()))
        return Path(out_dir or ".") / f"{name}.json", 0.0
    monkeypatch.setattr(train, "train_and_save", stub)
    return calls


def test_train_creates_a_missing_out_directory_before_training(tmp_path, capsys, trained):
    out = tmp_path / "new" / "models"
    assert main(["train", "--model", "poly", "--out", str(out)]) == 0
    assert trained == [("poly", str(out), True)]  # there before training started
    capsys.readouterr()


def test_train_out_that_is_a_file_fails_at_once_in_one_line(tmp_path, capsys, trained):
    out = tmp_path / "models"
    out.write_text("not a directory")
    assert main(["train", "--model", "poly", "--out", str(out)]) == 2
    assert trained == []  # no training
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"railswitch: error: --out {out} exists and is not a directory")


def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_watch_duration_counts_from_the_start_when_no_router_answers():
    stop = threading.Event()
    safety = threading.Timer(8.0, stop.set)  # without the fix it would wait for the bus until stopped
    safety.start()
    start = time.monotonic()
    try:
        with pytest.raises(BusError, match=r"no bus within --duration 1 s: cannot open a Zenoh session"):
            run_watch(BusOptions(connect=(f"tcp/127.0.0.1:{closed_port()}",)), switch_ids=[], count=None,
                      duration_s=1.0, jsonl=False, stop=stop)
    finally:
        safety.cancel()
    assert time.monotonic() - start < 5.0  # the duration, one connection attempt (2 s) and a retry at most


@pytest.mark.parametrize("command", ["historian", "history", "report"])
def test_the_help_of_commands_with_db_names_sqlite_and_postgresql(capsys, command):
    assert "SQLite" in COMMANDS[command] and "PostgreSQL" in COMMANDS[command]
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "F.sqlite|URL" in text and "postgresql://" in text
