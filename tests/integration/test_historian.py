"""The historian's file, its answers to bad queries and junk, damaged files, and the history command: a real
SQLite file, a real router and historian, watch and history processes."""
from __future__ import annotations

import json
import re
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from railswitch.schemas import (
    MAX_LIMIT,
    Alarm,
    Diagnosis,
    ParameterHealth,
    ServiceStatus,
    SwitchHealth,
    decode,
    encode,
    history_key,
    key_expr,
)
from railswitch.services.adapters.history_db import HistoryDb, HistoryRow
from railswitch.services.adapters.zenoh_bus import Received
from railswitch.schemas.history import format_time
from railswitch.services.core.historian import DAY_NS, HOLD_S, Historian
from railswitch.services.core.membership import Membership, rendezvous_owner
from tests.history_bus import (
    T0_NS,
    THROW_NS,
    ask,
    diagnosis,
    health,
    publish_throws,
    rows,
    start_historian,
    stored,
    stored_alarm,
    throw_end,
    wait_for_rows,
)
from tests.live import ROOT, ServiceProcesses, client, start_router, wait_for


def railswitch(*args: str, cwd: Path = ROOT, timeout_s: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "railswitch", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout_s)


# -- the file --------------------------------------------------------------------------------------
def test_the_file_keeps_every_row_across_reopening_and_a_message_delivered_twice_is_one_row(tmp_path):
    path = tmp_path / "history.sqlite"
    with HistoryDb(path) as db:
        assert db.write([stored("sw1", kind, k) for kind in ("diagnosis", "health") for k in range(5)]) == 10
        assert db.write([stored("sw1", "diagnosis", 4), stored("sw1", "diagnosis", 5)]) == 1  # 4 again: kept once
    with HistoryDb(path) as db:
        payloads, truncated = db.latest("sw1", "diagnosis", None, None, limit=10)
        assert [decode(Diagnosis, p).throw_index for p in payloads] == [0, 1, 2, 3, 4, 5]
        assert not truncated and db.count() == 11
        window, _ = db.latest("sw1", "health", throw_end(1), throw_end(3), limit=10)  # since <= t < until
        assert [decode(SwitchHealth, p).throw_index for p in window] == [1, 2]
    with sqlite3.connect(path) as direct:
        assert direct.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert direct.execute("SELECT version FROM schema_version").fetchone()[0] == 2
        indexed = direct.execute("SELECT name FROM pragma_index_info('history_by_switch_time')").fetchall()
        assert [name for (name,) in indexed][:2] == ["switch_id", "t_ns"]


def test_rows_older_than_keep_days_by_their_own_time_are_pruned(tmp_path):
    throws_per_day = DAY_NS // THROW_NS  # 144
    with HistoryDb(tmp_path / "history.sqlite") as db:
        db.write([stored(s, kind, k) for s in ("sw1", "sw2") for kind in ("diagnosis", "health")
                  for k in range(3 * throws_per_day)])  # three days of throws
        historian = Historian(db)
        now_ns = T0_NS + 3 * DAY_NS  # just after the last throw
        assert historian.prune(now_ns, keep_days=1.0) == 2 * 2 * 2 * throws_per_day
        kept, _ = db.latest("sw1", "diagnosis", None, None, limit=MAX_LIMIT)
        assert min(decode(Diagnosis, p).t_end_ns for p in kept) >= now_ns - DAY_NS
        assert historian.counters()["pruned"] == 8 * throws_per_day


def worn(switch_id: str, throw: int) -> SwitchHealth:
    """A switch whose bearing friction grows 40 N·s/m a throw towards its limit of 5000."""
    level = 1000.0 + 40.0 * throw
    bearing = ParameterHealth(name="bearing_friction", level=level, level_std=150.0, slope_per_100=4000.0,
                              slope_std_per_100=400.0, limit=5000.0, throws_to_limit=(5000.0 - level) / 40.0,
                              throws_to_limit_low=(5000.0 - level) / 50.0, throws_to_limit_high=(5000.0 - level) / 30.0)
    return SwitchHealth(switch_id=switch_id, throw_index=throw, t_ns=throw_end(throw), model="poly", state="ok",
                        worst="bearing_friction", throws_to_limit=bearing.throws_to_limit, parameters=[bearing])


def test_report_draws_each_switchs_health_from_a_history_file_one_picture_per_switch(tmp_path):
    with HistoryDb(tmp_path / "history.sqlite") as db:
        db.write([HistoryRow(s, "health", k, throw_end(k), encode(worn(s, k)).decode())
                  for k in range(20) for s in ("sw1", "sw2")])
        db.write([stored("sw1", "diagnosis", k) for k in range(20)])  # diagnoses are not what it draws
    result = railswitch("report", "--db", str(tmp_path / "history.sqlite"), "--out", str(tmp_path / "pictures"))
    assert result.returncode == 0, result.stderr
    pictures = sorted(p.name for p in (tmp_path / "pictures").glob("*.png"))
    assert pictures == ["sw1_health.png", "sw2_health.png"]
    assert result.stdout.split() == [str(tmp_path / "pictures" / name) for name in pictures]
    assert all((tmp_path / "pictures" / name).stat().st_size > 10_000 for name in pictures)


class FullOnce(HistoryDb):
    """A history file whose disk is full for the first write."""

    full = True

    def write(self, rows):
        if self.full:
            self.full = False
            return super().write([*rows, tuple(rows[0])[:4]])  # a last row SQLite cannot take, after the others
        return super().write(rows)


def test_a_batch_is_one_transaction_and_one_the_file_refused_is_kept_and_written_with_the_next(tmp_path):
    with FullOnce(tmp_path / "history.sqlite") as db:
        historian = Historian(db)
        first = [Received(key_expr("sw1", "diagnosis"), encode(diagnosis("sw1", k)), 0.0) for k in range(3)]
        assert historian.write(first) == 0 and db.count() == 0  # all or none: the good rows went back too
        assert historian.counters() | {"pending": 3, "write_failures": 1} == historian.counters()
        second = [Received(key_expr("sw1", "health"), encode(health("sw1", 0)), 0.0)]
        assert historian.write(second) == 4 and db.count() == 4  # the kept rows and the new one, one transaction
        assert historian.counters()["pending"] == 0 and historian.counters()["batches"] == 1


def received(switch_id: str, kind: str, throw: int, arrived_s: float) -> Received:
    message = diagnosis(switch_id, throw) if kind == "diagnosis" else health(switch_id, throw)
    return Received(key_expr(switch_id, kind), encode(message), arrived_s)


def test_an_elastic_historian_writes_its_own_switches_and_those_of_one_that_left_within_the_hold(tmp_path):
    switches = [f"sw{k}" for k in range(40)]
    members = ["hist-a", "hist-b", "hist-c"]
    ours = {s for s in switches if rendezvous_owner(s, members) == "hist-a"}
    bs = {s for s in switches if rendezvous_owner(s, members) == "hist-b"}
    after_b = {s for s in bs if rendezvous_owner(s, ["hist-a", "hist-c"]) == "hist-a"}
    assert ours and bs and after_b and after_b != bs  # b's switches go to both a and c
    now = [100.0]
    membership = Membership("hist-a")
    for member in members:
        membership.join(member, 0.0)
    with HistoryDb(tmp_path / "history.sqlite") as db:
        historian = Historian(db, membership, clock=lambda: now[0])
        historian.write([received(s, "diagnosis", 0, 100.0) for s in switches])
        assert {row[0] for row in stored_rows(db)} == ours  # only its own; b's and c's held
        now[0] = 100.0 + HOLD_S + 1.0
        historian.write([received(s, "diagnosis", 1, now[0]) for s in switches])  # throw 0's held rows expire
        membership.leave("hist-b")
        assert historian.rebalance() == len(after_b)  # b left before writing throw 1: a writes its part
        historian.write([])
        assert set(stored_rows(db)) == {(s, 0) for s in ours} | {(s, 1) for s in ours | after_b}
        assert historian.counters()["taken_over"] == len(after_b)
        # Throw 1 of c's switches and of b's that are c's now: held for c.
        assert historian.counters()["members"] == 2
        assert historian.counters()["held"] == len(switches) - len(ours | after_b)


def stored_rows(db: HistoryDb) -> list[tuple[str, int]]:
    return [(switch_id, throw) for switch_id in db.switches()
            for throw in (decode(Diagnosis, p).throw_index
                          for p in db.latest(switch_id, "diagnosis", None, None, MAX_LIMIT)[0])]


# -- bad queries and junk on a live historian ---------------------------------------------------------
@pytest.fixture(scope="module")
def historian_bus(tmp_path_factory):
    """A router, a historian holding sw1's throws 0-4, the processes and the test's own session."""
    work = tmp_path_factory.mktemp("historian")
    with ServiceProcesses(work) as services:
        endpoint = start_router(services)
        session = client(endpoint)
        try:
            start_historian(services, session, endpoint, work / "history.sqlite")
            publish_throws(session, ["sw1"], range(5))
            wait_for_rows(session, 10)
            yield session, endpoint, work / "history.sqlite", services
        finally:
            session.close()


@pytest.mark.parametrize("selector, words", [
    ("railswitch/sw1/history?limit=0", f"limit 0 is outside the accepted range 1 … {MAX_LIMIT}"),
    (f"railswitch/sw1/history?limit={MAX_LIMIT + 1}", "is outside the accepted range"),
    ("railswitch/sw1/history?limit=lots", "limit 'lots' is not an integer"),
    ("railswitch/sw1/history?since=yesterday", "since 'yesterday' is neither ISO-8601"),
    ("railswitch/sw1/history?until=-5", "until -5 is outside the accepted range"),
    ("railswitch/sw1/history?since=2024-02-01;until=2024-01-01", "is not before until"),
    ("railswitch/sw1/history?kind=motor", "kind 'motor' is not one of diagnosis, health"),
    ("railswitch/sw1/history?limt=5", "unknown query parameter 'limt'"),
    ("railswitch/nosuchswitch/history", "unknown switch nosuchswitch: no history stored"),
])
def test_a_bad_history_query_gets_an_error_reply_naming_the_problem(historian_bus, selector, words):
    session = historian_bus[0]
    replies, errors = ask(session, selector)
    assert replies == [] and len(errors) == 1
    assert words in errors[0]
    assert len(rows(ask(session, history_key("sw1"))[0])) == 10  # and the historian goes on answering


def junk(kind: str) -> list[bytes]:
    """Payloads a historian must refuse on railswitch/junky/<kind>: not UTF-8, fields missing, a value out of
    range, another switch's message, and a time past SQLite's 64-bit integers."""
    valid = diagnosis("junky", 1) if kind == "diagnosis" else health("junky", 1)
    out_of_range = json.dumps({**json.loads(encode(valid)), "throw_index": -1}).encode()
    other = diagnosis("sw2", 1) if kind == "diagnosis" else health("sw2", 1)
    out = [b"\xff\xfe not json", b'{"switch_id": "junky"}', out_of_range, encode(other)]
    if kind == "health":
        out.append(encode(valid.model_copy(update={"t_ns": 2**64})))  # passes the schema (no upper bound)
    return out


def test_junk_diagnosis_and_health_payloads_are_counted_once_per_reason_and_never_stored(historian_bus):
    session, _, db, _ = historian_bus
    statuses: list[ServiceStatus] = []
    subscriber = session.declare_subscriber("railswitch/@service/historian/*/status",
                                            lambda s: statuses.append(decode(ServiceStatus, s.payload.to_bytes())))
    try:
        for kind in ("diagnosis", "health"):
            for payload in junk(kind):
                session.put(key_expr("junky", kind), payload)
        session.put(key_expr("junky", "health"), encode(health("junky", 0)))  # and one good message
        wait_for(lambda: (len(rows(ask(session, history_key("junky"))[0])) == 1
                          and statuses and sum(statuses[-1].rejected.values()) >= 9), 30, "the junk counted")
    finally:
        subscriber.undeclare()
    rejected = statuses[-1].rejected
    assert rejected["diagnosis: not utf-8"] == rejected["health: not utf-8"] == 1
    assert rejected["diagnosis: switch_id differs from the key"] == rejected["health: switch_id differs from the key"]
    assert rejected["health: time or throw index beyond 64 bits"] == 1
    assert sum(rejected.values()) == 9
    with sqlite3.connect(db) as direct:
        kept = direct.execute("SELECT switch_id, kind, throw_index FROM history WHERE switch_id != 'sw1'").fetchall()
    assert kept == [("junky", "health", 0)]


def test_watch_shows_each_switchs_health_state_and_its_worst_parameters_throws_to_limit(historian_bus):
    session, endpoint, _, services = historian_bus
    watch = services.start("watch", "--connect", endpoint, "--count", "1", "--duration", "60")
    expected = "sw9 health after throw 3: watch - bearing_friction: 120 throws (60–300)"

    def shown() -> bool:
        session.put(key_expr("sw9", "health"), encode(worn_health()))  # again until watch has subscribed
        return expected in services.log(watch)

    wait_for(shown, 60, "watch to show sw9's health", poll_s=0.5)
    session.put(key_expr("sw9", "diagnosis"), encode(diagnosis("sw9", 3)))  # --count 1: it exits after this
    assert watch.wait(30) == 0
    assert "sw9 throw 3 right_to_left: nominal" in services.log(watch)


def worn_health() -> SwitchHealth:
    bearing = ParameterHealth(name="bearing_friction", level=3000.0, level_std=200.0, limit=5000.0,
                              throws_to_limit=120.0, throws_to_limit_low=60.0, throws_to_limit_high=300.0,
                              state="watch")
    return SwitchHealth(switch_id="sw9", throw_index=3, t_ns=throw_end(3), model="poly", state="watch",
                        worst="bearing_friction", throws_to_limit=120.0, parameters=[bearing])


def test_the_history_command_prints_a_switchs_history_from_the_bus_and_from_the_file(historian_bus):
    _, endpoint, db, _ = historian_bus
    over_bus = railswitch("history", "sw1", "--connect", endpoint, "--json", "--limit", "2")
    from_file = railswitch("history", "sw1", "--db", str(db), "--json", "--since", format_time(throw_end(3)))
    table = railswitch("history", "sw1", "--connect", endpoint, "--until", str(throw_end(2)))
    assert over_bus.returncode == from_file.returncode == table.returncode == 0, over_bus.stderr + from_file.stderr
    lines = [json.loads(line) for line in over_bus.stdout.splitlines()]
    assert [(line["throw_index"], "decision" in line) for line in lines] == [(3, True), (3, False), (4, True),
                                                                             (4, False)]
    assert from_file.stdout == over_bus.stdout
    assert "history of sw1" in table.stdout and "2 diagnoses, 2 health messages" in table.stdout


def test_the_historians_status_counts_what_it_wrote_and_answered(historian_bus):
    session = historian_bus[0]
    statuses: list[ServiceStatus] = []
    subscriber = session.declare_subscriber("railswitch/@service/historian/*/status",
                                            lambda s: statuses.append(decode(ServiceStatus, s.payload.to_bytes())))
    try:
        wait_for(lambda: bool(statuses), 10, "a status message")
    finally:
        subscriber.undeclare()
    assert statuses[-1].service == "historian"
    assert statuses[-1].counters["written"] >= 10 and statuses[-1].counters["queries"] >= 1


# -- damaged files --------------------------------------------------------------------------------------
def damaged_copy(tmp_path: Path, damage: str) -> tuple[Path, int]:
    """A history file of 2000 rows, cut in half, with its header overwritten or with a few pages overwritten by
    garbage (a bad sector); its row count."""
    path = tmp_path / f"{damage}.sqlite"
    with HistoryDb(path) as db:
        db.write([stored(f"sw{k % 4}", kind, k) for k in range(1000) for kind in ("diagnosis", "health")])
    data = bytearray(path.read_bytes())
    if damage == "truncated":
        data = data[:len(data) // 2]
    elif damage == "garbage-header":
        data[:96] = b"\x00garbage" * 12
    else:
        for page in (20, 21, 60):  # pages of 4096 bytes, SQLite's default
            data[page * 4096:(page + 1) * 4096] = b"\xa5" * 4096
    path.write_bytes(bytes(data))
    return path, 2000


@pytest.mark.parametrize("damage", ["truncated", "garbage-header", "corrupt-pages"])
def test_a_damaged_file_stops_the_historian_in_one_line_with_the_rows_that_salvage_then_recovers(tmp_path, damage):
    path, written = damaged_copy(tmp_path, damage)
    before = path.read_bytes()
    refused = railswitch("historian", "--db", str(path), "--connect", "tcp/127.0.0.1:9")  # stops before the bus
    reading = railswitch("history", "sw1", "--db", str(path))
    assert refused.returncode == reading.returncode == 2
    line = refused.stderr.strip()
    assert len(line.splitlines()) == 1 and f"history database {path} is damaged" in line, refused.stderr
    readable = int(re.search(r"; (\d+) rows are readable: `railswitch history --db .* --salvage", line)[1])
    assert (readable == written) if damage == "garbage-header" else (0 < readable < written)
    assert path.read_bytes() == before  # refused, not touched
    salvaged = railswitch("history", "--db", str(path), "--salvage", str(tmp_path / "new.sqlite"))
    assert salvaged.returncode == 0 and f"copied {readable} rows" in salvaged.stdout, salvaged.stderr
    with HistoryDb(tmp_path / "new.sqlite") as fresh:
        assert fresh.count() == readable


# -- bad command-line values ------------------------------------------------------------------------------
@pytest.mark.parametrize("args, words", [
    (["historian", "--db", "h.sqlite", "--shard", "3/2"], "shard 3/2 is outside the accepted range"),
    (["historian", "--db", "h.sqlite", "--keep-days", "0"], "0 is outside the accepted range 0.01 … 36500 days"),
    (["historian", "--db", "/nonexistent-dir/h.sqlite"], "directory /nonexistent-dir does not exist"),
    (["historian", "--db", "."], "it is a directory"),
    (["historian", "--db", "other.sqlite"], "is not a railswitch history database"),
    (["history", "sw1", "--limit", "0"], f"0 is outside the accepted range 1 … {MAX_LIMIT}"),
    (["history", "sw1", "--limit", str(MAX_LIMIT + 1)], "is outside the accepted range"),
    (["history", "sw1", "--since", "yesterday"], "since 'yesterday' is neither ISO-8601"),
    (["history", "sw1", "--since", "2024-02-01", "--until", "2024-01-01", "--db", "h.sqlite"], "is not before until"),
    (["history", "not a switch!"], "must be 1 to 64 letters"),
    (["history", "sw1", "--db", "missing.sqlite"], "history database missing.sqlite does not exist"),
    (["history", "--salvage", "new.sqlite"], "--salvage needs --db"),
    (["report", "--out", "pictures"], "give a recording (F.mcap or F.csv) or a history store (--db F.sqlite or --db postgresql://…)"),
])
def test_bad_historian_and_history_values_give_one_line_and_exit_2(tmp_path, args, words):
    with sqlite3.connect(tmp_path / "other.sqlite") as other:
        other.execute("CREATE TABLE photos (name TEXT)")
    result = railswitch(*args, "--connect", "tcp/127.0.0.1:9", cwd=tmp_path) if args[0] != "report" else \
        railswitch(*args, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    assert words in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert not (tmp_path / "h.sqlite").exists()  # refused before anything was created


def test_a_version_1_file_is_read_as_it_is_and_migrated_by_a_historian_to_keep_alarms(tmp_path):
    path = tmp_path / "history.sqlite"
    with sqlite3.connect(path) as direct:  # the layout of version 1: no alarm rows
        direct.executescript("""
            CREATE TABLE schema_version (version INTEGER NOT NULL); INSERT INTO schema_version VALUES (1);
            CREATE TABLE history (switch_id TEXT NOT NULL, kind TEXT NOT NULL CHECK (kind IN ('diagnosis', 'health')),
                                  throw_index INTEGER NOT NULL, t_ns INTEGER NOT NULL, payload TEXT NOT NULL);
            CREATE UNIQUE INDEX history_by_switch_time ON history (switch_id, t_ns, kind, throw_index);""")
        direct.execute("INSERT INTO history VALUES (?, ?, ?, ?, ?)", stored("sw1", "diagnosis", 0))
    direct.close()
    with HistoryDb(path, create=False) as reader:  # a reader reads it and changes nothing
        assert reader.count() == 1
    with sqlite3.connect(path) as direct:
        assert direct.execute("SELECT version FROM schema_version").fetchone()[0] == 1
    direct.close()
    with HistoryDb(path) as db:  # a historian migrates it, keeping its rows
        assert db.write([stored_alarm("sw1", 1), stored_alarm("sw1", 2)]) == 2 and db.count() == 3
        assert [decode(Alarm, p).change for p in db.latest("sw1", "alarm", None, None, 10)[0]] == [
            "raised", "acknowledged"]
    with sqlite3.connect(path) as direct:
        assert direct.execute("SELECT version FROM schema_version").fetchone()[0] == 2
        assert direct.execute("SELECT count(*) FROM pragma_index_info('history_by_switch_time')").fetchone()[0] == 4
    direct.close()
