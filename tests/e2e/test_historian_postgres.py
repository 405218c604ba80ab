"""Historians as real processes on one PostgreSQL database (a real server, tests/postgres.py): two of them receiving
the same messages store each once, and one whose server goes away keeps its rows and writes them when it is back."""
from __future__ import annotations

import psycopg

from railswitch.schemas import history_key
from railswitch.services.adapters.processes import instance_of
from tests.history_bus import ask, publish_throws, rows, start_historian
from tests.live import ServiceWatch, live_bus, wait_for
from tests.postgres import PostgresServer

SWITCHES = [f"sw{k}" for k in range(1, 7)]


def stored(url: str) -> list[tuple[str, str, int]]:
    """(switch, kind, throw) of every row, or [] while the server is away."""
    try:
        with psycopg.connect(url, connect_timeout=5) as db:
            return db.execute("SELECT switch_id, kind, throw_index FROM railswitch_history").fetchall()
    except psycopg.OperationalError:
        return []


def every_row(throws: range) -> set[tuple[str, str, int]]:
    return {(s, kind, k) for s in SWITCHES for kind in ("diagnosis", "health") for k in throws}


def test_two_historians_receiving_the_same_messages_store_each_row_once_in_one_database(tmp_path, pg_url):
    """Both keep every switch (shard 1/1): every message reaches both, and both write it."""
    with live_bus(tmp_path) as (services, endpoint, session, _):
        watch = ServiceWatch(session, "historian")
        pair = [start_historian(services, session, endpoint, pg_url, "--shard", "1/1") for _ in range(2)]
        publish_throws(session, SWITCHES, range(20))
        expected = every_row(range(20))
        wait_for(lambda: len(stored(pg_url)) >= len(expected), 60, "every row stored")
        names = [instance_of(p) for p in pair]
        wait_for(lambda: all((s := watch.latest(n)) and s.counters["written"] + s.counters["duplicates"]
                             == len(expected) for n in names), 30, "both historians to count every row")
        counters = [watch.latest(n).counters for n in names]
        replies, errors = ask(session, history_key("sw1"))
    keys = stored(pg_url)
    assert len(keys) == len(set(keys)) and set(keys) == expected
    assert sum(c["written"] for c in counters) == len(expected)  # between them each row written once
    assert all(c["pending"] == 0 and c["write_failures"] == 0 for c in counters), counters
    assert errors == [] and len(replies) == 2  # both answer for sw1 from the one database
    assert all(set(rows([r])) == {r for r in expected if r[0] == "sw1"} for r in replies)


def test_a_historian_whose_server_goes_away_keeps_its_rows_and_writes_them_when_it_is_back(tmp_path, postgres):
    with PostgresServer(postgres.bin_dir) as server, live_bus(tmp_path) as (services, endpoint, session, _):
        url = server.new_database()
        watch = ServiceWatch(session, "historian")
        historian = start_historian(services, session, endpoint, url)
        name = instance_of(historian)
        publish_throws(session, SWITCHES, range(5))
        wait_for(lambda: len(stored(url)) == len(every_row(range(5))), 60, "throws 0-4 stored")
        server.stop()
        publish_throws(session, SWITCHES, range(5, 10))
        wait_for(lambda: (s := watch.latest(name)) and s.counters["pending"] == len(every_row(range(5, 10))),
                 30, "throws 5-9 kept pending")
        away = watch.latest(name).counters
        server.start()
        publish_throws(session, SWITCHES, range(10, 12))
        wait_for(lambda: len(stored(url)) == len(every_row(range(12))), 60, "every row stored after the restart")
        wait_for(lambda: (s := watch.latest(name)) and s.counters["pending"] == 0, 30, "nothing pending")
        assert historian.poll() is None  # it served on throughout
        log = services.log(historian)
        final = stored(url)
    assert len(final) == len(set(final)) and set(final) == every_row(range(12))  # none lost, none twice
    assert away["write_failures"] >= 1 and away["written"] == len(every_row(range(5)))
    assert log.count("cannot write the history store") == 1 and "Traceback" not in log, log
    assert "the history store takes rows again" in log
