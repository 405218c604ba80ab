"""Soak: the demo topology at speed for minutes, watching for loss and memory growth (issue 6).

A router, the recorder, a diagnoser and the simulator (the plant, 1 % noise, each switch
nominal for half its throws and then with one of the demo's four faults) run as separate
processes. After --minutes the simulator is stopped, the last diagnoses drain and the
recording is read back: `lost` is missing sample numbers plus ended throws without a
diagnosis. `rss_mb` is each process's VmRSS after the first minute (a third of the run
for runs under two minutes) and just before stopping; `cpu_percent` covers the same
window (100 = one core) and `others_cpu_percent` is what everything else on the machine,
this benchmark included, used then (to a few percent, so it can read slightly negative).
`achieved_speed` is simulated over wall time between the first and the last end event.

`--records` soaks the fleet topology instead: `--switches` switches (default 200) sending each throw as
one record, every `--interval` simulated seconds (default 300: a busy switch, 288 throws a day), at
`--speed` (default 10), into two elastic diagnosers and two elastic historians writing one database
(`--db`, a PostgreSQL URL, or by default an SQLite file in the scratch folder). `lost` is throws
published without a diagnosis plus diagnoses published that the database does not hold;
`stored_twice` throws it holds more than once. Memory is probed first once every switch is past its
commissioning (its state holds what its throws in service will: a commissioning switch's grows with
each throw), at the latest halfway through the run, and last just before stopping.
"""
from __future__ import annotations

import ast
import math
import os
import re
import statistics
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.common import emit, parser
from railswitch.schemas import Diagnosis, MotorSample, ThrowEvent, decode, parse_key_expr
from railswitch.services.adapters.zenoh_bus import BusOptions, Inbox, open_session
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.services.core.demo_story import INTERVAL_S, demo_scenario
from railswitch.services.adapters.recordings import RecordingReader
from railswitch.services.adapters.processes import ServiceProcesses, free_loopback_endpoint, wait_ready

# 20 switches at 2x: 4 throws/s, 2000 samples/s, about 1.4 of 2 cores, the diagnoser at 3/4 of its one
# (GIL-bound) core; at 3x it saturates (p95 latency 7 s) and at 4x its backlog and memory grow.
SPEED = 2.0
DRAIN_TIMEOUT_S = 120.0
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def soak_scenario(switches: int, throws: int) -> str:
    """The demo's scenario: switches of the population, 1 % noise, commissioned, then fault mode k mod 5."""
    return demo_scenario(switches, throws)


@dataclass(frozen=True)
class Probe:
    """Resident memory (MB) and CPU time (s) of each process, and the whole machine's busy CPU time (s)."""

    at_s: float  # monotonic
    rss_mb: dict[str, float]
    cpu_s: dict[str, float]
    machine_busy_s: float


def probe(pids: dict[str, int]) -> Probe:
    """Read /proc: VmRSS and utime + stime of each pid, and the busy time of all cores."""
    rss, cpu = {}, {}
    for name, pid in pids.items():
        status = Path(f"/proc/{pid}/status").read_text()
        rss[name] = int(re.search(r"^VmRSS:\s+(\d+) kB", status, re.M).group(1)) / 1024
        fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
        cpu[name] = (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime (proc(5) fields 14, 15)
    jiffies = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = jiffies[3] + jiffies[4]  # idle, iowait
    return Probe(time.monotonic(), rss, cpu, (sum(jiffies[:8]) - idle) / CLOCK_TICKS)


@dataclass
class LiveThrows:
    """End events and diagnoses as they arrive here (to know when the diagnoser has caught up)."""

    inbox: Inbox
    ends: dict[tuple[str, int], tuple[int, float]] = field(default_factory=dict)  # (t_ns, arrival monotonic s)
    diagnosed: set[tuple[str, int]] = field(default_factory=set)

    def collect(self, timeout_s: float) -> None:
        item = self.inbox.get(timeout_s)
        while item is not None:
            if parse_key_expr(item.key)[1] == "diagnosis":
                d = decode(Diagnosis, item.payload)
                self.diagnosed.add((d.switch_id, d.throw_index))
            else:
                event = decode(ThrowEvent, item.payload)
                if event.phase == "end":
                    self.ends[event.switch_id, event.throw_index] = (event.t_ns, item.arrived_s)
            item = self.inbox.get(0.0)

    def caught_up(self) -> bool:
        return self.ends.keys() <= self.diagnosed

    def achieved_speed(self) -> float:
        """Simulated seconds per wall second between the first and the last end event."""
        if len(self.ends) < 2:
            return float("nan")
        (t0, a0), (t1, a1) = min(self.ends.values()), max(self.ends.values())
        return (t1 - t0) / 1e9 / (a1 - a0) if a1 > a0 else float("nan")


def run_until(deadline: float, live: LiveThrows, processes: ServiceProcesses, done=lambda: False) -> None:
    """Collect live messages until the deadline (or done()); RuntimeError if a service exits meanwhile."""
    while time.monotonic() < deadline and not done():
        live.collect(min(0.5, max(0.0, deadline - time.monotonic())))
        for name, _, process in processes.started:
            if process.pid not in processes.stopped and process.poll() is not None:
                raise RuntimeError(f"{name} exited with code {process.returncode}:\n{processes.log(process, 8)}")


@dataclass
class ReadBack:
    """What the recording holds: sample numbers per switch, ended throws, diagnoses and their latency."""

    seqs: dict[str, set[int]] = field(default_factory=dict)
    ends: set[tuple[str, int]] = field(default_factory=set)
    latency_ms: dict[tuple[str, int], float] = field(default_factory=dict)
    damage: str | None = None

    @classmethod
    def of(cls, path: Path) -> ReadBack:
        """One streaming pass, so a long recording is never held in memory as messages."""
        out, reader = cls(), RecordingReader(path)
        for record in reader:
            message = record.message
            if isinstance(message, MotorSample):
                out.seqs.setdefault(message.switch_id, set()).add(message.seq)
            elif isinstance(message, ThrowEvent) and message.phase == "end":
                out.ends.add((message.switch_id, message.throw_index))
            elif isinstance(message, Diagnosis):
                out.latency_ms.setdefault((message.switch_id, message.throw_index), message.latency_ms)
        out.damage = reader.damage
        return out

    @property
    def samples(self) -> int:
        return sum(len(s) for s in self.seqs.values())

    @property
    def missing_samples(self) -> int:
        """Sample numbers absent between each switch's first and last recorded one."""
        return sum(max(s) - min(s) + 1 - len(s) for s in self.seqs.values())

    @property
    def undiagnosed(self) -> int:
        return len(self.ends - self.latency_ms.keys())


def rejected(processes: ServiceProcesses, process: subprocess.Popen) -> int:
    """Messages a service rejected, from the 'rejected {...}' of its closing log line."""
    found = re.findall(r"rejected (\{.*\}|nothing)\s*$", processes.log(process), re.M)
    return sum(ast.literal_eval(found[-1]).values()) if found and found[-1] != "nothing" else 0


def records_soak(args) -> dict:
    """The fleet topology for --minutes (see the module's docstring)."""
    from benchmarks.bus import RecordObserver, history_counts, routed_bus

    run_s = 60.0 * args.minutes
    commissioned_s = (2 * COMMISSIONING_THROWS + 1) * args.interval / args.speed
    first_s = min(max(60.0, commissioned_s), run_s / 2) if args.minutes >= 2 else run_s / 3
    with routed_bus() as (work, library, processes, endpoint, session):
        observer = RecordObserver(session)
        db = args.db or str(work / "history.sqlite")
        started = {f"diagnoser-{k}": processes.start("diagnoser", "--connect", endpoint, "--state", str(work / "state"))
                   for k in (1, 2)}
        started |= {f"historian-{k}": processes.start("historian", "--connect", endpoint, "--db", db) for k in (1, 2)}
        wait_ready(session, processes, diagnoser=2, historian=2)
        scenario = work / "fleet.toml"
        scenario.write_text(f"interval_s = {args.interval}\n" + "".join(
            f'[[switches]]\nid = "sw{k + 1}"\nthrows = 100000\n' for k in range(args.switches)))
        started["simulator"] = processes.start("simulator", "--connect", endpoint, "--as-records", "--scenario",
                                               str(scenario), "--speed", f"{args.speed:g}", "--throws-from",
                                               str(library))
        pids = {name: process.pid for name, process in started.items()}
        t0 = time.monotonic()
        time.sleep(first_s)
        first = probe(pids)
        time.sleep(max(t0 + run_s - time.monotonic(), 0.0))
        last = probe(pids)
        processes.stop(started["simulator"])
        deadline = time.monotonic() + DRAIN_TIMEOUT_S
        while observer.undiagnosed() and time.monotonic() < deadline:
            time.sleep(0.5)
        time.sleep(3.0)  # the historians' last batches
        exited = {name: process.returncode for name, process in started.items()
                  if process.pid not in processes.stopped and process.poll() is not None}
        for name in ("diagnoser-1", "diagnoser-2", "historian-1", "historian-2"):
            processes.stop(started[name])
        stored, stored_twice = history_counts(db)
    with observer.lock:
        throws, diagnosed = len(observer.records), len(observer.diagnoses)
    latencies = observer.latencies_ms()
    window_s = last.at_s - first.at_s
    return {
        "records": True, "minutes": args.minutes, "switches": args.switches, "speed": args.speed,
        "interval_s": args.interval, "first_probe_s": round(first_s, 1),
        "throws": throws, "diagnoses": diagnosed, "stored": stored, "stored_twice": stored_twice,
        "lost": observer.undiagnosed() + max(diagnosed - (stored - stored_twice), 0),
        "rss_mb": {name: [round(first.rss_mb[name], 1), round(last.rss_mb[name], 1)] for name in pids},
        "rss_growth": {name: round(100 * (last.rss_mb[name] / first.rss_mb[name] - 1), 1) for name in pids},
        "latency_ms": {"p50": round(statistics.median(latencies), 1),
                       "p95": round(float(np.percentile(latencies, 95)), 1)} if latencies else None,
        "cpu_percent": {name: round(100 * (last.cpu_s[name] - first.cpu_s[name]) / window_s) for name in pids},
        "exited": exited,
        "db": "postgresql" if db.startswith(("postgresql:", "postgres:")) else "sqlite",
    }


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--minutes", type=float, default=5.0, help="wall time with the simulator running")
    p.add_argument("--switches", type=int, default=None, help="default 20, 200 with --records")
    p.add_argument("--speed", type=float, default=None, help=f"x real time (default {SPEED:g}, 10 with --records)")
    p.add_argument("--records", action="store_true", help="the fleet topology as records (see above)")
    p.add_argument("--db", default=None, help="with --records: the historians' database")
    p.add_argument("--interval", type=float, default=300.0, help="with --records: simulated s between a switch's throws")
    args = p.parse_args()
    if args.records:
        args.switches, args.speed = args.switches or 200, args.speed or 10.0
        emit(records_soak(args), args.json)
        return
    args.switches, args.speed = args.switches or 20, args.speed or SPEED
    run_s = 60.0 * args.minutes
    first_s = 60.0 if args.minutes >= 2 else run_s / 3
    throws = math.ceil(run_s * args.speed / INTERVAL_S) + 1  # one more: still throwing when stopped
    endpoint = free_loopback_endpoint()
    with (tempfile.TemporaryDirectory(prefix="railswitch-soak-") as scratch,
          ServiceProcesses(Path(scratch)) as processes):
        work = Path(scratch)
        scenario, recording = work / "scenario.toml", work / "soak.mcap"
        scenario.write_text(soak_scenario(args.switches, throws))
        started = {"router": processes.start("router", "--listen", endpoint)}
        with open_session(BusOptions(connect=(endpoint,)), wait_s=30.0) as session:
            live = LiveThrows(Inbox(session, ["railswitch/*/throw", "railswitch/*/diagnosis"]))
            started["recorder"] = processes.start("recorder", "--connect", endpoint, "--out", str(recording))
            started["diagnoser"] = processes.start("diagnoser", "--connect", endpoint)
            wait_ready(session, processes, diagnoser=1, recorder=1)
            started["simulator"] = processes.start("simulator", "--connect", endpoint, "--scenario", str(scenario),
                                                   "--speed", str(args.speed))
            pids = {name: process.pid for name, process in started.items()}
            t0 = time.monotonic()
            run_until(t0 + first_s, live, processes)
            first = probe(pids)
            run_until(t0 + run_s, live, processes)
            last = probe(pids)
            processes.stop(started["simulator"])
            run_until(time.monotonic() + DRAIN_TIMEOUT_S, live, processes, done=live.caught_up)
            run_until(time.monotonic() + 1.0, live, processes)  # the recorder writes the last diagnoses
            processes.stop(started["diagnoser"])
            processes.stop(started["recorder"])
            live.inbox.close()
        rejections = {name: rejected(processes, started[name]) for name in ("recorder", "diagnoser")}
        back = ReadBack.of(recording)
    latencies = list(back.latency_ms.values())
    window_s = last.at_s - first.at_s
    ours_s = sum(last.cpu_s.values()) - sum(first.cpu_s.values())
    result = {
        "minutes": args.minutes,
        "throws": len(back.ends),
        "diagnoses": len(back.latency_ms),
        "lost": back.missing_samples + back.undiagnosed,
        "rss_mb": {name: [round(first.rss_mb[name], 1), round(last.rss_mb[name], 1)] for name in pids},
        "rss_growth": {name: round(100 * (last.rss_mb[name] / first.rss_mb[name] - 1), 1) for name in pids},
        "samples": back.samples,
        "missing_samples": back.missing_samples,
        "undiagnosed": back.undiagnosed,
        "speed": args.speed,
        "switches": args.switches,
        "achieved_speed": round(live.achieved_speed(), 3),
        "latency_ms": {"p50": round(statistics.median(latencies), 1),
                       "p95": round(float(np.percentile(latencies, 95)), 1)} if latencies else None,
        "cpu_percent": {name: round(100 * (last.cpu_s[name] - first.cpu_s[name]) / window_s) for name in pids},
        "others_cpu_percent": round(100 * (last.machine_busy_s - first.machine_busy_s - ours_s) / window_s),
        "rejected": rejections,
    }
    if back.damage:
        result["damage"] = back.damage
    emit(result, args.json)


if __name__ == "__main__":
    main()
