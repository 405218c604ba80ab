"""The history in PostgreSQL: a real server (tests/postgres.py), historians writing it at once, the same answers as
from an SQLite file, and one line with exit code 2 for a database that cannot be used."""
from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import psycopg
import pytest

from railswitch.schemas import encode, key_expr
from railswitch.services.adapters.history_db import HistoryDb
from railswitch.services.adapters.history_store import HistoryDbError, HistoryRow, open_history
from railswitch.services.adapters.zenoh_bus import Received
from railswitch.services.commands.report import health_from_db
from railswitch.services.core.historian import Historian, message_time
from tests.history_bus import diagnosis, health, stored, stored_alarm
from tests.live import ROOT

SWITCHES = [f"sw{k}" for k in range(1, 7)]


def railswitch(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "railswitch", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=120)


def messages(switches: list[str], throws: range) -> list[Received]:
    return [Received(key_expr(s, kind), encode(make(s, k)), 0.0) for k in throws for s in switches
            for kind, make in (("diagnosis", diagnosis), ("health", health))]


def stored_keys(url: str) -> list[tuple]:
    with psycopg.connect(url) as db:
        return db.execute("SELECT switch_id, kind, throw_index, t_ns FROM railswitch_history").fetchall()


def test_two_historians_writing_the_same_rows_at_once_store_each_once_and_lose_none(pg_url):
    """Each historian has its own connection and writes every message (as two historians of shard 1/1 do), in
    batches of different sizes, one in the other's reverse order: every row ends up stored once, every write is
    taken (none refused and kept pending), and between them they wrote each row once."""
    items = messages(SWITCHES, range(60))
    opened: list = []
    barrier = threading.Barrier(2)

    def run(order: list[Received], batch: int) -> None:
        barrier.wait()  # the two create the tables at once too
        with open_history(pg_url) as db:
            historian = Historian(db)
            for k in range(0, len(order), batch):
                historian.write(order[k:k + batch])
            opened.append(historian.counters())

    threads = [threading.Thread(target=run, args=(items, 50)), threading.Thread(target=run, args=(items[::-1], 37))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(120)
    assert len(opened) == 2, "a historian failed"
    keys = stored_keys(pg_url)
    assert len(keys) == len(set(keys)) == len(items)
    assert all(c["pending"] == 0 and c["write_failures"] == 0 for c in opened), opened
    assert all(c["written"] + c["duplicates"] == len(items) for c in opened), opened
    assert sum(c["written"] for c in opened) == len(items)


def test_a_diagnosis_with_every_hypothesis_is_stored_whole_and_uncompressed(pg_url):
    """A diagnosis as large as the diagnoser's (every hypothesis filled in, some 4 kB) stays in its row as it came,
    through the batch's temporary table too: reading a switch's latest diagnoses decompresses nothing."""
    from benchmarks.historian import fleet_payloads

    items = fleet_payloads(20, seed=0)
    assert min(len(i.payload) for i in items if i.key.endswith("/diagnosis")) > 3000  # beyond PostgreSQL's 2 kB
    with open_history(pg_url) as db:
        assert Historian(db).write(items) == len(items)
    with psycopg.connect(pg_url) as db:
        stored = db.execute("SELECT kind, pg_column_compression(payload), octet_length(payload) = "
                            "pg_column_size(payload) - 4 FROM railswitch_history").fetchall()
    assert len(stored) == len(items)
    assert all(compression is None and whole for _, compression, whole in stored), stored


def test_the_history_command_answers_the_same_from_postgresql_as_from_sqlite(tmp_path, pg_url):
    items = messages(SWITCHES[:2], range(30))
    for target in (tmp_path / "history.sqlite", pg_url):
        with open_history(target) as db:
            Historian(db).write(items)
            Historian(db).write(items[:10])  # delivered twice: kept once
    queries = [["sw1", "--json"], ["sw2", "--json", "--limit", "5", "--kind", "health"],
               ["sw1", "--json", "--since", str(message_time(diagnosis("sw1", 10))),
                "--until", str(message_time(diagnosis("sw1", 20)))]]
    for query in queries:
        from_sqlite = railswitch("history", *query, "--db", str(tmp_path / "history.sqlite"))
        from_postgres = railswitch("history", *query, "--db", pg_url)
        assert from_sqlite.returncode == from_postgres.returncode == 0, from_postgres.stderr
        assert from_postgres.stdout == from_sqlite.stdout and from_sqlite.stdout.count("\n") >= 5
    assert health_from_db(pg_url) == health_from_db(str(tmp_path / "history.sqlite")) != []  # what report draws


def test_rows_older_than_keep_days_are_pruned_from_postgresql_as_from_sqlite(tmp_path, pg_url):
    rows = [HistoryRow(s, "health", k, message_time(health(s, k)), encode(health(s, k)).decode())
            for s in SWITCHES[:2] for k in range(10)]
    before_ns = message_time(health("sw1", 4))
    deleted = []
    for target in (tmp_path / "history.sqlite", pg_url):
        with open_history(target) as db:
            db.write(rows)
            deleted.append((db.prune(before_ns), db.count()))
    assert deleted == [(8, 12), (8, 12)]  # throws 0-3 of two switches gone


def test_a_database_holding_other_tables_gets_ours_and_a_half_layout_or_another_version_is_refused(pg_url):
    with psycopg.connect(pg_url, autocommit=True) as db:
        db.execute("CREATE TABLE photos (name text)")  # a shared server: other programs' tables are fine
    with open_history(pg_url) as history:
        assert history.count() == 0
    with psycopg.connect(pg_url, autocommit=True) as db:
        db.execute("UPDATE railswitch_schema_version SET version = 3")
    with pytest.raises(HistoryDbError, match="has history schema version 3; this railswitch reads version 2"):
        open_history(pg_url)
    with psycopg.connect(pg_url, autocommit=True) as db:
        db.execute("DROP TABLE railswitch_schema_version")
    with pytest.raises(HistoryDbError, match="is not a railswitch history database"):
        open_history(pg_url)


def test_a_newer_schema_version_stops_historian_history_and_report_in_one_line(tmp_path, pg_url):
    open_history(pg_url).close()
    with psycopg.connect(pg_url, autocommit=True) as db:
        db.execute("UPDATE railswitch_schema_version SET version = 3")
    for command in (["historian", "--connect", "tcp/127.0.0.1:9"], ["history", "sw1"], ["report", "--out", "p"]):
        result = railswitch(*command, "--db", pg_url, cwd=tmp_path)
        assert result.returncode == 2, result.stderr
        assert result.stderr.strip().splitlines() == [
            f"railswitch: error: {pg_url} has history schema version 3; this railswitch reads version 2"]


def test_history_from_a_database_without_our_tables_is_refused_and_creates_nothing(pg_url):
    result = railswitch("history", "sw1", "--db", pg_url)
    assert result.returncode == 2 and "holds no railswitch history" in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    with psycopg.connect(pg_url) as db:
        assert db.execute("SELECT to_regclass('railswitch_history')").fetchone()[0] is None


@pytest.mark.parametrize("url, words", [
    ("postgresql://railswitch@[::1/history", "cannot use history database postgresql://railswitch@[::1/history"),
    ("postgresql://railswitch@127.0.0.1:5432/history?colour=blue", 'invalid URI query parameter: "colour"'),
    ("postgresql://railswitch@nosuchhost.invalid/history", "failed to resolve host 'nosuchhost.invalid'"),
    ("postgresql://railswitch:s3cret@127.0.0.1:9/history",
     "cannot connect to history database postgresql://railswitch:***@127.0.0.1:9/history"),
    ("mysql://railswitch@127.0.0.1/history", "a URL must start with postgresql://"),
])
@pytest.mark.parametrize("command", ["historian", "history", "report"])
def test_a_bad_database_url_stops_historian_history_and_report_in_one_line_with_exit_2(tmp_path, command, url, words):
    args = {"historian": ["historian", "--connect", "tcp/127.0.0.1:9"], "history": ["history", "sw1"],
            "report": ["report", "--out", "pictures"]}[command]
    result = railswitch(*args, "--db", url, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and words in result.stderr, result.stderr
    assert "s3cret" not in result.stderr and list(tmp_path.iterdir()) == []


def test_a_database_url_without_psycopg_installed_says_which_extra_to_install(tmp_path):
    blocked = ("import sys; sys.modules['psycopg'] = None; sys.argv = ['railswitch', 'history', 'sw1', '--db', "
               "'postgresql://railswitch@127.0.0.1:9/history']; from railswitch.services.commands.cli import main; "
               "sys.exit(main())")
    result = subprocess.run([sys.executable, "-c", blocked], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines() == [
        "railswitch: error: history database postgresql://railswitch@127.0.0.1:9/history needs psycopg, which is "
        "not installed: pip install 'railswitch[postgres]'"]


def test_salvage_is_refused_for_a_database_url_in_one_line(tmp_path):
    result = railswitch("history", "--db", "postgresql://railswitch@127.0.0.1:9/history", "--salvage",
                        "new.sqlite", cwd=tmp_path)
    assert result.returncode == 2 and "--salvage reads and writes SQLite files only" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and list(tmp_path.iterdir()) == []


def test_a_history_file_path_still_means_sqlite(tmp_path):
    with open_history(tmp_path / "history.sqlite") as db:
        assert isinstance(db, HistoryDb)


def test_a_version_1_database_is_read_as_it_is_and_migrated_by_a_historian_to_keep_alarms(pg_url):
    with open_history(pg_url) as history:
        history.write([stored("sw1", "diagnosis", 0)])
    with psycopg.connect(pg_url, autocommit=True) as db:  # the layout of version 1: no alarm rows
        db.execute("ALTER TABLE railswitch_history DROP CONSTRAINT railswitch_history_kind_check")
        db.execute("ALTER TABLE railswitch_history ADD CONSTRAINT railswitch_history_kind_check "
                   "CHECK (kind IN ('diagnosis', 'health'))")
        db.execute("UPDATE railswitch_schema_version SET version = 1")
    with open_history(pg_url, create=False) as reader:  # a reader reads it and changes nothing
        assert reader.count() == 1
    with psycopg.connect(pg_url, autocommit=True) as db:
        assert db.execute("SELECT version FROM railswitch_schema_version").fetchone()[0] == 1
    with open_history(pg_url) as history:  # a historian migrates it
        assert history.write([stored_alarm("sw1", 1)]) == 1 and history.count() == 2
    with psycopg.connect(pg_url, autocommit=True) as db:
        assert db.execute("SELECT version FROM railswitch_schema_version").fetchone()[0] == 2
