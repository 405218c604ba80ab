"""The historian as a real process: an outside Zenoh client gets a switch's history from one historian and from
two shards at once, elastic historians split the fleet and hand it over, a historian killed with -9 loses no
committed row and goes on with its file, and one told to keep D days prunes its file at start-up."""
from __future__ import annotations

import signal
import sqlite3
import time
from collections import Counter
from pathlib import Path

from railswitch.schemas import encode, history_key
from railswitch.services.adapters.history_db import HistoryDb, HistoryRow
from railswitch.services.core.historian import DAY_NS, message_time
from railswitch.services.adapters.processes import instance_of
from railswitch.services.adapters.zenoh_bus import ELASTIC_LEASE_MS
from railswitch.services.core.membership import rendezvous_owner
from railswitch.services.core.shards import in_shard
from tests.history_bus import ask, diagnosis, health, publish_throws, rows, start_historian, wait_for_rows
from tests.live import ServiceWatch, live_bus, wait_for

SWITCHES = [f"sw{k}" for k in range(1, 9)]  # crc32 puts four in each of two shards
SETTLE_S = 5.0  # the target: a join or a leave moves ownership within 5 s
LEASE_S = ELASTIC_LEASE_MS / 1000  # how long a hung historian's token stays


def test_an_outside_client_gets_a_switchs_history_from_a_live_historian(tmp_path):
    with live_bus(tmp_path) as (services, endpoint, session, _):
        start_historian(services, session, endpoint, tmp_path / "history.sqlite")
        publish_throws(session, ["sw1", "sw2"], range(5))
        wait_for_rows(session, 20)
        replies, errors = ask(session, f"{history_key('sw1')}?limit=3")
    assert errors == []
    assert [r.switch_id for r in replies] == ["sw1"]
    assert [d.throw_index for d in replies[0].diagnoses] == [2, 3, 4]  # the latest three, oldest first
    assert [h.throw_index for h in replies[0].health] == [2, 3, 4]
    assert replies[0].truncated


def test_two_sharded_historians_answer_one_query_with_every_row_exactly_once(tmp_path):
    assert {in_shard(s, (1, 2)) for s in SWITCHES} == {True, False}  # both shards hold switches
    with live_bus(tmp_path) as (services, endpoint, session, _):
        start_historian(services, session, endpoint, tmp_path / "shard1.sqlite", "--shard", "1/2")
        start_historian(services, session, endpoint, tmp_path / "shard2.sqlite", "--shard", "2/2")
        publish_throws(session, SWITCHES, range(4))
        wait_for_rows(session, 2 * 4 * len(SWITCHES))
        everything, errors = ask(session, "railswitch/*/history")
        one_by_one = [ask(session, history_key(s)) for s in SWITCHES]
    expected = Counter((s, kind, k) for s in SWITCHES for kind in ("diagnosis", "health") for k in range(4))
    assert errors == []
    assert Counter(rows(everything)) == expected  # each row once: no shard stores another's switches
    assert len({r.historian for r in everything}) == 2  # both shards answered the one query
    assert all(errs == [] and len(replies) == 1 for replies, errs in one_by_one)  # the other shard stays silent
    assert Counter(row for replies, _ in one_by_one for row in rows(replies)) == expected
    for shard in ("shard1", "shard2"):
        with sqlite3.connect(tmp_path / f"{shard}.sqlite") as db:
            stored = {s for (s,) in db.execute("SELECT DISTINCT switch_id FROM history")}
        assert stored == {s for s in SWITCHES if in_shard(s, (int(shard[-1]), 2))}


def stored_switches(db: Path, throws: range) -> set[str]:
    with sqlite3.connect(db) as direct:
        return {s for (s,) in direct.execute("SELECT DISTINCT switch_id FROM history WHERE throw_index >= ? AND "
                                             "throw_index < ?", (throws.start, throws.stop))}


def every_row(switches: list[str], throws: range) -> set[tuple[str, str, int]]:
    return {(s, kind, k) for s in switches for kind in ("diagnosis", "health") for k in throws}


def test_elastic_historians_split_the_fleet_take_a_newcomers_share_and_write_a_hung_ones_rows(tmp_path):
    """Elastic (no --shard): each historian keeps the switches rendezvous hashing over the live set gives it. A
    third one takes its share within 5 s; one that hangs (SIGSTOP: silent, its token kept until its lease ends) and is
    then killed loses no row published meanwhile, because the others held those rows and write them once it has
    left. Restarted on its file, it answers for what it stored before, and one gathered query holds every row. One
    killed with -9 leaves within 5 s, and the rows published right after are kept by the other two."""
    # Enough switches that each of three historians owns some whatever its process id (rendezvous hashing over
    # host-pid names): with 12, one of three owned none in about 1 run in 40 (3 (2/3)^12), and the hung one's rows
    # were then none (seen once in ten runs); with 48, about 1 in 10^8.
    switches = [f"el{k}" for k in range(48)]
    dbs = [tmp_path / f"h{k}.sqlite" for k in range(3)]
    with live_bus(tmp_path) as (services, endpoint, session, _):
        watch = ServiceWatch(session, "historian")

        def all_see(instances: list[str], members: int, after_s: float = float("-inf")) -> list[float | None]:
            return [watch.first(i, lambda status: status.counters["members"] == members, after_s) for i in instances]

        pair = [start_historian(services, session, endpoint, db) for db in dbs[:2]]
        names = [instance_of(p) for p in pair]
        wait_for(lambda: None not in all_see(names, 2), 10, "both historians to see each other")
        publish_throws(session, switches, range(4))
        wait_for_rows(session, len(every_row(switches, range(4))))
        split = [stored_switches(db, range(4)) for db in dbs[:2]]

        third = start_historian(services, session, endpoint, dbs[2])
        names.append(instance_of(third))
        wait_for(lambda: None not in all_see(names, 3), 10, "all three to see the third")
        settled = [t - watch.appeared[names[2]] for t in all_see(names[:2], 3)]
        publish_throws(session, switches, range(4, 8))
        wait_for_rows(session, len(every_row(switches, range(8))))
        share = [stored_switches(db, range(4, 8)) for db in dbs]

        pair[0].send_signal(signal.SIGSTOP)
        hung_s = time.monotonic()
        publish_throws(session, switches, range(8, 12))
        wait_for(lambda: None not in all_see(names[1:], 2, hung_s), 20, "the others to see the hung one leave")
        left = [t - hung_s for t in all_see(names[1:], 2, hung_s)]
        services.stop(pair[0], signal.SIGKILL)
        wait_for(lambda: every_row(switches, range(8, 12)) <= set(rows(ask(session, "railswitch/*/history")[0])),
                 30, "every row of throws 8 to 11 answered by the two left")
        answered_s = time.monotonic()
        wait_for(lambda: all(watch.latest(i, answered_s) for i in names[1:]), 10, "statuses after that")
        taken = sum(watch.latest(i).counters["taken_over"] for i in names[1:])
        back = start_historian(services, session, endpoint, dbs[0])  # back on its file
        everything, errors = ask(session, "railswitch/*/history")

        after = [instance_of(back), names[2]]
        wait_for(lambda: None not in all_see([names[1], *after], 3), 10, "all three to see the restarted one")
        services.stop(pair[1], signal.SIGKILL)  # killed: its connection closes, its token goes at once
        killed_s = time.monotonic()
        publish_throws(session, switches, range(12, 16))
        wait_for(lambda: None not in all_see(after, 2, killed_s), 10, "the others to see the killed one leave")
        gone = [t - killed_s for t in all_see(after, 2, killed_s)]
        wait_for(lambda: every_row(switches, range(12, 16)) <= set(rows(ask(session, "railswitch/*/history")[0])),
                 30, "every row of throws 12 to 15 answered by the two left")
    first = {s for s in switches if rendezvous_owner(s, names[:2]) == names[0]}
    assert split == [first, set(switches) - first]  # each switch in exactly one file
    assert share[2] == {s for s in switches if rendezvous_owner(s, names) == names[2]} != set()  # the third's share
    assert share[0] | share[1] == set(switches) - share[2] and not share[0] & share[1]
    assert all(t <= SETTLE_S for t in settled), settled
    assert all(t <= LEASE_S + SETTLE_S for t in left), left
    hung = sorted(s for s in switches if rendezvous_owner(s, names) == names[0])
    # Its rows of throws 8 to 11, held by the others and written once it left (and some older ones still held).
    assert taken >= len(every_row(hung, range(8, 12))) > 0
    assert stored_switches(dbs[0], range(8, 12)) == set()
    assert errors == [] and set(rows(everything)) == every_row(switches, range(12))
    assert all(t <= SETTLE_S for t in gone), gone
    assert stored_switches(dbs[1], range(12, 16)) == set()  # throws 12 to 15 were kept by the other two


def test_a_historian_killed_with_9_loses_no_committed_row_and_goes_on_with_its_file(tmp_path):
    db = tmp_path / "history.sqlite"
    with live_bus(tmp_path) as (services, endpoint, session, _):
        first = start_historian(services, session, endpoint, db)
        publish_throws(session, ["sw1", "sw2"], range(10))
        wait_for_rows(session, 40)  # answered: committed
        committed = Counter(rows(ask(session, "railswitch/*/history")[0]))
        services.stop(first, signal.SIGKILL)
        with sqlite3.connect(db) as direct:  # the file as the killed process left it, WAL included
            assert direct.execute("SELECT count(*) FROM history").fetchone()[0] == 40
        start_historian(services, session, endpoint, db)
        after_restart = Counter(rows(ask(session, "railswitch/*/history")[0]))
        publish_throws(session, ["sw1", "sw2"], range(10, 15))
        wait_for_rows(session, 60)
        resumed = Counter(rows(ask(session, "railswitch/*/history")[0]))
    assert first.returncode == -signal.SIGKILL
    assert after_restart == committed
    assert resumed == committed + Counter((s, kind, k) for s in ("sw1", "sw2") for kind in ("diagnosis", "health")
                                          for k in range(10, 15))


def test_a_historian_keeping_30_days_prunes_older_rows_of_its_file_at_start_up_by_their_own_time(tmp_path):
    db = tmp_path / "history.sqlite"
    recent_ns = time.time_ns() - DAY_NS  # yesterday: kept
    old = [diagnosis("sw1", k) for k in range(5)] + [health("sw1", k) for k in range(5)]  # November 2023
    recent = [diagnosis("sw2", k).model_copy(update={"t_start_ns": recent_ns + k, "t_end_ns": recent_ns + k})
              for k in range(3)] + [health("sw2", k).model_copy(update={"t_ns": recent_ns + k}) for k in range(3)]
    with HistoryDb(db) as history:
        history.write([HistoryRow(m.switch_id, "diagnosis" if hasattr(m, "decision") else "health", m.throw_index,
                                  message_time(m), encode(m).decode()) for m in old + recent])

    def stored() -> list[str]:
        with sqlite3.connect(db) as direct:
            return sorted(s for (s,) in direct.execute("SELECT switch_id FROM history"))

    with live_bus(tmp_path) as (services, endpoint, session, _):
        start_historian(services, session, endpoint, db, "--keep-days", "30")
        wait_for(lambda: stored() == ["sw2"] * 6, 30, "the rows older than 30 days pruned")
        sw1, sw1_errors = ask(session, history_key("sw1"))
        sw2, sw2_errors = ask(session, history_key("sw2"))
    assert sw1 == [] and sw1_errors == ["unknown switch sw1: no history stored"]
    assert sw2_errors == [] and Counter(rows(sw2)) == Counter(
        ("sw2", kind, k) for kind in ("diagnosis", "health") for k in range(3))
