"""The historian's writes and history queries on a real SQLite file (issue 15), and on PostgreSQL (issue 39).

- rows_per_s: `rows` messages of a fleet of SWITCHES switches, a Diagnosis (every hypothesis, as the
  diagnoser publishes it, about 3.5 kB) and a SwitchHealth per throw, each switch throwing every
  THROW_EVERY_S, go through the historian's own write path (intake, rows, one transaction of BATCH messages
  at a time, committed with synchronous=FULL) into a new file.
- query_p95_ms: QUERIES per-switch history queries on that file through the historian's own answer path
  (parameters parsed, rows read, the reply's JSON built), of the kinds an engineer asks: the latest 100
  throws, one day's throws, and the whole health history (the default limit of 1000).
- start_up_check_s: opening that file again, as a restarted historian does (SQLite's quick_check reads it all).
- last_1000_p95_ms: one switch's latest 1000 diagnoses (the largest rows), through the same answer path.
Targets: rows_per_s >= 2000, query_p95_ms <= 50. `measure()` is called by other benchmarks too.

With `--db postgresql://…` the same rows also go into PostgreSQL, in a schema of their own that is dropped at the
end (the database's other tables are left alone), written by two historian processes at once with their own
connections, on every core the benchmark was given:
- pg_rows_per_s: each of the two writes the whole fleet's messages (as two historians of shard 1/1, or elastic ones
  around a hand-over, do), so every row is written twice and stored once: distinct rows stored per second of wall
  time, from both starting to both done.
- pg_split_rows_per_s: each writes half the switches (as elastic historians split a fleet).
- pg_store_rows_per_s: as pg_rows_per_s, with the rows already built: what the database takes, without the
  historian's intake (decoding and checking each message, the same work for SQLite) in the way.
- pg_query_p95_ms, pg_last_1000_p95_ms: the queries above, on PostgreSQL.
Targets: pg_rows_per_s >= 10000, pg_last_1000_p95_ms <= 20.
"""
from __future__ import annotations

import multiprocessing
import os
import tempfile
import time
import uuid
from pathlib import Path
from urllib.parse import quote

import numpy as np

from benchmarks.common import emit, parser, pin_to_one_core
from railswitch.schemas import (
    FAULT_PARAMETERS,
    MODE_PARAMETERS,
    Commissioning,
    Diagnosis,
    FaultEstimate,
    Hypothesis,
    ParameterHealth,
    SwitchHealth,
    encode,
    key_expr,
)
from railswitch.services.adapters.history_db import HistoryDb
from railswitch.services.adapters.history_store import HistoryRow, HistoryStore, open_history
from railswitch.services.adapters.zenoh_bus import Received
from railswitch.services.core.historian import DAY_NS, Historian, HistoryAnswers

SWITCHES = 50
THROW_EVERY_S = 900.0  # a busy switch: four throws an hour
BATCH = 256  # messages per transaction: a backlog, as after a restart or under a burst
QUERIES = 300
START_NS = 1_700_000_000 * 10**9
NUISANCE = {"motor.coulomb_friction_nm": 0.12, "motor.resistance_ohm": 9.5, "motor.supply_v": 110.0,
            "motor.torque_constant_nm_a": 0.2, "rail.chair_friction_coefficient": 0.02}
TRACKED = ("left_bolt_offset", "right_bolt_offset", "bearing_friction", "obstacle_friction", "drive_friction_nm")


def diagnosis(rng: np.random.Generator, switch_id: str, throw: int, t_ns: int) -> Diagnosis:
    """A nominal throw's diagnosis with every hypothesis filled in, as large as the diagnoser's."""
    def hypothesis(mode: str, names: tuple[str, ...]) -> Hypothesis:
        params = {n: float(rng.normal(0.0, 0.01 * FAULT_PARAMETERS[n].high)) for n in names}
        return Hypothesis(mode=mode, params=params, std={n: abs(v) + 1e-3 for n, v in params.items()},
                          mse=float(rng.uniform(1e-4, 4e-4)),
                          nuisance={k: v * float(rng.uniform(0.9, 1.1)) for k, v in NUISANCE.items()})

    hypotheses = [hypothesis("nominal", ())] + [hypothesis(m, tuple(p)) for m, p in MODE_PARAMETERS.items()]
    direction = "left_to_right" if throw % 2 == 0 else "right_to_left"
    return Diagnosis(switch_id=switch_id, throw_index=throw, direction=direction, t_start_ns=t_ns - 7 * 10**9,
                     t_end_ns=t_ns, model="poly", decision="nominal", hypotheses=hypotheses,
                     joint=hypothesis("joint", tuple(n for p in MODE_PARAMETERS.values() for n in p)),
                     estimate=FaultEstimate(mode="missing_bearing", params={"bearing_friction": 100.0},
                                            std={"bearing_friction": 50.0}, throws=3, since_throw=max(0, throw - 2)),
                     commissioning=Commissioning(state="commissioned", throws={"left_to_right": 4, "right_to_left": 4},
                                                 needed=4),
                     latency_ms=float(rng.uniform(50, 300)))


def health(rng: np.random.Generator, switch_id: str, throw: int, t_ns: int) -> SwitchHealth:
    """Every tracked parameter's trend after a throw."""
    parameters = [ParameterHealth(name=n, level=float(rng.normal()), level_std=1.0, slope_per_100=0.1,
                                  slope_std_per_100=0.05, limit=10.0, throws_to_limit=float(rng.uniform(100, 900)),
                                  throws_to_limit_low=50.0, throws_to_limit_high=2000.0) for n in TRACKED]
    return SwitchHealth(switch_id=switch_id, throw_index=throw, t_ns=t_ns, model="poly", state="ok",
                        worst=TRACKED[2], throws_to_limit=parameters[2].throws_to_limit, parameters=parameters)


def fleet_payloads(rows: int, seed: int) -> list[Received]:
    """`rows` received payloads, a throw's diagnosis and health message together, switch after switch in time."""
    rng = np.random.default_rng(seed)
    items = []
    for k in range((rows + 1) // 2):
        throw, switch = divmod(k, SWITCHES)
        switch_id = f"sw{switch + 1}"
        t_ns = START_NS + int((throw * THROW_EVERY_S + switch * THROW_EVERY_S / SWITCHES) * 1e9)
        items.append(Received(key_expr(switch_id, "diagnosis"), encode(diagnosis(rng, switch_id, throw, t_ns)), 0.0))
        items.append(Received(key_expr(switch_id, "health"), encode(health(rng, switch_id, throw, t_ns)), 0.0))
    return items[:rows]


def write_rate(db: HistoryStore, items: list[Received]) -> float:
    """Messages per second through Historian.write, one transaction per BATCH."""
    historian = Historian(db)
    started = time.perf_counter()
    for k in range(0, len(items), BATCH):
        historian.write(items[k:k + BATCH])
    elapsed = time.perf_counter() - started
    assert historian.written == len(items), historian.counters()
    return len(items) / elapsed


def query_times_ms(db: HistoryStore, rng: np.random.Generator, end_ns: int, last_1000: bool = False) -> list[float]:
    """Milliseconds per answer of a mix of per-switch queries (last_1000: of the latest 1000 diagnoses only)."""
    answers = HistoryAnswers(db, is_mine=lambda switch_id: True, historian="benchmark")
    times = []
    for k in range(QUERIES):
        switch_id = f"sw{int(rng.integers(SWITCHES)) + 1}"
        day_start = int(rng.integers(START_NS, max(START_NS + 1, end_ns - DAY_NS)))
        parameters = ({"limit": "100"}, {"since": str(day_start), "until": str(day_start + DAY_NS)},
                      {"kind": "health"})[k % 3] if not last_1000 else {"kind": "diagnosis", "limit": "1000"}
        started = time.perf_counter()
        answer = answers.answer(f"railswitch/{switch_id}/history", parameters, lambda s: True)
        times.append((time.perf_counter() - started) * 1e3)
        assert answer.error is None and answer.replies, answer.error
    return times


def measure(rows: int = 100_000, seed: int = 0) -> dict:
    """Insert throughput of the historian's write path into a new SQLite file, and the 95th percentile of
    per-switch history queries on it."""
    items = fleet_payloads(rows, seed)
    with tempfile.TemporaryDirectory(prefix="railswitch-historian-") as scratch:
        path = Path(scratch) / "history.sqlite"
        with HistoryDb(path) as db:
            rate = write_rate(db, items)
        started = time.perf_counter()
        with HistoryDb(path) as db:  # reopened, as a restarted historian does: its start-up check reads the file
            opened_s = time.perf_counter() - started
            times, last = query_percentiles(db, rows, seed)
        size_mb = path.stat().st_size / 2**20
    return {"rows_per_s": round(rate, 1), "query_p95_ms": p95(times),
            "query_p50_ms": round(float(np.percentile(times, 50)), 2), "start_up_check_s": round(opened_s, 2),
            "last_1000_p95_ms": p95(last), "rows": rows, "file_mb": round(size_mb, 1)}


def query_percentiles(db: HistoryStore, rows: int, seed: int) -> tuple[list[float], list[float]]:
    """Times of the query mix and of the latest-1000 queries on a store holding fleet_payloads(rows, seed)."""
    end_ns = START_NS + int(rows / 2 / SWITCHES * THROW_EVERY_S * 1e9)
    return (query_times_ms(db, np.random.default_rng(seed + 1), end_ns),
            query_times_ms(db, np.random.default_rng(seed + 2), end_ns, last_1000=True))


def p95(times_ms: list[float]) -> float:
    return round(float(np.percentile(times_ms, 95)), 2)


def in_own_schema(url: str) -> tuple[str, str]:
    """The URL with a new schema first on its search path (the tables go there), and the schema's name."""
    schema = f"railswitch_bench_{uuid.uuid4().hex[:8]}"
    options = quote(f"-c search_path={schema}")
    return f"{url}{'&' if '?' in url else '?'}options={options}", schema


def _historian_process(url: str, items: list[Received] | list[HistoryRow], cores: set[int], go, done) -> None:
    """One historian writing its items once `go` is set, through its whole write path (received payloads) or
    straight into the store (rows already built); its counters go to `done`."""
    os.sched_setaffinity(0, cores)
    with open_history(url) as db:
        done.put("ready")
        go.wait()
        historian = Historian(db)
        for k in range(0, len(items), BATCH):
            if isinstance(items[0], HistoryRow):
                historian.written += db.write(items[k:k + BATCH])
            else:
                historian.write(items[k:k + BATCH])
        done.put(historian.counters())


def two_historians_rate(url: str, shares: list[list[Received]], cores: set[int]) -> tuple[float, list[dict]]:
    """Distinct rows stored per second by two historian processes writing their shares at once (forked: the
    payloads are theirs without a copy), and each one's counters."""
    context = multiprocessing.get_context("fork")
    go, done = context.Event(), context.Queue()
    workers = [context.Process(target=_historian_process, args=(url, share, cores, go, done)) for share in shares]
    for worker in workers:
        worker.start()
    assert [done.get(timeout=120) for _ in workers] == ["ready"] * len(workers)
    started = time.perf_counter()
    go.set()
    counters = [done.get(timeout=3600) for _ in workers]
    elapsed = time.perf_counter() - started
    for worker in workers:
        worker.join()
    assert all(c["pending"] == 0 and c["write_failures"] == 0 for c in counters), counters
    return sum(c["written"] for c in counters) / elapsed, counters


def measure_postgres(url: str, rows: int, seed: int, cores: set[int]) -> dict:
    """Two historians into PostgreSQL (each the whole fleet, then each half of it, then the whole fleet's rows
    straight into the store) and the queries on it."""
    import psycopg

    items = fleet_payloads(rows, seed)
    halves = [[i for i in items if (int(i.key.split("/")[1][2:]) % 2) == part] for part in (0, 1)]
    built = [Historian(None).row(item) for item in items]
    result = {}
    with psycopg.connect(url, autocommit=True) as admin:
        for name, shares in (("pg_rows_per_s", [items, items]), ("pg_split_rows_per_s", halves),
                             ("pg_store_rows_per_s", [built, built])):
            own, schema = in_own_schema(url)
            admin.execute(f"CREATE SCHEMA {schema}")
            try:
                rate, counters = two_historians_rate(own, shares, cores)
                assert sum(c["written"] for c in counters) == len(items), counters
                result[name] = round(rate, 1)
                if name == "pg_rows_per_s":
                    with open_history(own, check=False) as db:
                        times, last = query_percentiles(db, rows, seed)
                    result |= {"pg_query_p95_ms": p95(times), "pg_last_1000_p95_ms": p95(last)}
            finally:
                admin.execute(f"DROP SCHEMA {schema} CASCADE")
    return result | {"pg_targets": {"pg_rows_per_s": 10_000, "pg_last_1000_p95_ms": 20}}


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--rows", type=int, default=100_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--db", default=None, metavar="URL",
                   help="also measure PostgreSQL: postgresql://user@host:port/db (a schema of its own, dropped after)")
    args = p.parse_args()
    cores = os.sched_getaffinity(0)
    pin_to_one_core()  # SQLite: one historian on one core, as its target is stated
    result = measure(args.rows, args.seed)
    if args.db:
        result |= measure_postgres(args.db, args.rows, args.seed, cores)
    emit(result, args.json)


if __name__ == "__main__":
    main()
