"""The historian's writes and history queries on a real SQLite file (issue 15).

- rows_per_s: `rows` messages of a fleet of SWITCHES switches, a Diagnosis (every hypothesis, as the
  diagnoser publishes it, about 3.5 kB) and a SwitchHealth per throw, each switch throwing every
  THROW_EVERY_S, go through the historian's own write path (intake, rows, one transaction of BATCH messages
  at a time, committed with synchronous=FULL) into a new file.
- query_p95_ms: QUERIES per-switch history queries on that file through the historian's own answer path
  (parameters parsed, rows read, the reply's JSON built), of the kinds an engineer asks: the latest 100
  throws, one day's throws, and the whole health history (the default limit of 1000).
- start_up_check_s: opening that file again, as a restarted historian does (SQLite's quick_check reads it all).
Targets: rows_per_s >= 2000, query_p95_ms <= 50. `measure()` is called by other benchmarks too.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

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


def write_rate(db: HistoryDb, items: list[Received]) -> float:
    """Messages per second through Historian.write, one transaction per BATCH."""
    historian = Historian(db)
    started = time.perf_counter()
    for k in range(0, len(items), BATCH):
        historian.write(items[k:k + BATCH])
    elapsed = time.perf_counter() - started
    assert historian.written == len(items), historian.counters()
    return len(items) / elapsed


def query_times_ms(db: HistoryDb, rng: np.random.Generator, end_ns: int) -> list[float]:
    """Milliseconds per answer of a mix of per-switch queries."""
    answers = HistoryAnswers(db, is_mine=lambda switch_id: True, historian="benchmark")
    times = []
    for k in range(QUERIES):
        switch_id = f"sw{int(rng.integers(SWITCHES)) + 1}"
        day_start = int(rng.integers(START_NS, max(START_NS + 1, end_ns - DAY_NS)))
        parameters = ({"limit": "100"}, {"since": str(day_start), "until": str(day_start + DAY_NS)},
                      {"kind": "health"})[k % 3]
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
            end_ns = START_NS + int(rows / 2 / SWITCHES * THROW_EVERY_S * 1e9)
            times = query_times_ms(db, np.random.default_rng(seed + 1), end_ns)
        size_mb = path.stat().st_size / 2**20
    return {"rows_per_s": round(rate, 1), "query_p95_ms": round(float(np.percentile(times, 95)), 2),
            "query_p50_ms": round(float(np.percentile(times, 50)), 2), "start_up_check_s": round(opened_s, 2),
            "rows": rows, "file_mb": round(size_mb, 1)}


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--rows", type=int, default=100_000)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    pin_to_one_core()
    emit(measure(args.rows, args.seed), args.json)


if __name__ == "__main__":
    main()
