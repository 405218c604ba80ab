"""The live services under fleet load (issue 5), with real processes on loopback.

1. Fleet: a router, the recorder and one diagnoser; the simulator streams K switches at
   50 Hz, each throwing once every 30 s (staggered), replaying recorded throws so the
   plant's cost does not cap the fleet. This process subscribes to throw events and
   diagnoses: latency runs from a throw's end event arriving here to its Diagnosis
   arriving here. `lost` is missing sample numbers in the recording plus throws
   without a diagnosis.
2. Shards: the fleet's throws (all switches by default, 300 throws: a long window, so
   the ratio does not hang on a few seconds), without the idle samples between them,
   replayed as fast as possible into one diagnoser and then into two shards; the
   throws per second each clears once the replay has finished (the backlog) give
   `shard_speedup`.

`--records` measures instead a fleet sending each throw as one record (`simulator --as-records`)
into two elastic diagnosers (no recorder), every switch throwing once per 15 simulated minutes (a
real switch throws about 100 times a day):

1. Capacity: each of `--burst` switches at once throws `--commissioning` throws and then
   `--burst-throws` more (a switch's throws in order). The first are its commissioning (a new switch's
   baseline: COMMISSIONING_THROWS each way), the rest are throws in service, where the diagnoser knows
   the switch's baseline and its previous throw in the same direction, as it does for every throw of
   a switch in service but its first. For each phase: the throws per second the two diagnosers clear,
   and per CPU second they spend (decoding everything, holding others' throws, diagnosing their own).
   `switches_per_core`, the fleet one core serves at 100 throws a day, is the service phase's; the
   commissioning phase's is reported beside it (`--commissioning 0` times a new fleet's first throws
   alone, as the capacity run did before it had phases). The service phase is 16 throws a switch, some
   30 s: with 4 (8 s) two runs of the same code gave 24 756 and 30 802 switches per core, as this
   machine's speed drifts from one minute to the next; with 16, two gave 25 877 and 25 477.
2. Paced: `--fleet` switches sped up to `--load` times the measured capacity, for `--paced-s`
   seconds: `lost` (throws without a diagnosis) and the latency from a record's arrival to its
   diagnosis's. With `--elastic` a third diagnoser joins mid-run and one of the first two is then
   killed with -9; `settle_s` is how long after each event every live diagnoser reports the new
   live set (status every 0.2 s), and the throws it held in flight must be diagnosed by the others.

`--records --outage S` measures catching up instead (docs/contracts.md section 3): `--fleet` switches
(default 200) throwing as real switches do, every switch once per 15 simulated minutes, sped up
`--speed` times (default 30), into two elastic diagnosers sharing one state folder (one host's) and a
historian (`--db`, default an SQLite file in the scratch folder). After a quarter of `--paced-s`, every
diagnoser is killed with -9; S simulated seconds later (S / speed of wall time) two new ones start.
`undiagnosed` counts the throws published that no diagnosis followed, `stored_twice` the throws the
history holds more than one diagnosis of, `missed` what the diagnosers reported missed (throws older
than the simulator's cache, which it sizes from S); `down_simulated_s` is the whole outage, from the
kill to the new diagnosers' readiness, in the switches' time. `catch_up_s` runs from that readiness to
the diagnosis of the last throw published while they were down, and `cleared_per_s` is those throws
over it.
"""
from __future__ import annotations

import math
import os
import signal
import statistics
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import zenoh

from benchmarks.common import emit, parser
from railswitch.schemas import Diagnosis, MotorSample, ServiceStatus, ThrowEvent, ThrowRecord, decode
from railswitch.services.adapters.zenoh_bus import BusOptions, open_session
from railswitch.services.adapters.history_store import open_history
from railswitch.services.adapters.recordings import RecordingWriter, load_recording
from railswitch.services.adapters.processes import (
    ServiceProcesses,
    free_loopback_endpoint,
    instance_of,
    wait_for,
    wait_ready,
)
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.services.commands.simulate import simulate_to_mcap

RATE_HZ = 50.0
INTERVAL_S = 30.0


class Observer:
    """Arrival times (monotonic s) of motor samples, end events and diagnoses, without decoding samples."""

    def __init__(self, session):
        self.lock = threading.Lock()
        self.motor_per_second: dict[int, int] = {}
        self.ends: dict[tuple[str, int], float] = {}
        self.diagnoses: dict[tuple[str, int], float] = {}
        self._subscribers = [session.declare_subscriber("railswitch/*/motor", self._motor),
                             session.declare_subscriber("railswitch/*/throw", self._throw),
                             session.declare_subscriber("railswitch/*/diagnosis", self._diagnosis)]

    def _motor(self, sample) -> None:
        second = int(time.monotonic())
        with self.lock:
            self.motor_per_second[second] = self.motor_per_second.get(second, 0) + 1

    def _throw(self, sample) -> None:
        now = time.monotonic()
        event = decode(ThrowEvent, sample.payload.to_bytes())
        if event.phase == "end":
            self.ends[event.switch_id, event.throw_index] = now

    def _diagnosis(self, sample) -> None:
        now = time.monotonic()
        diagnosis = decode(Diagnosis, sample.payload.to_bytes())
        self.diagnoses.setdefault((diagnosis.switch_id, diagnosis.throw_index), now)

    def samples_per_s(self) -> float:
        """Median samples per wall-clock second while the whole fleet streams (first and last seconds cut)."""
        counts = [self.motor_per_second[s] for s in sorted(self.motor_per_second)[1:-1]]
        return float(statistics.median(counts)) if counts else 0.0

    def reset(self) -> None:
        with self.lock:
            self.motor_per_second.clear()
            self.ends.clear()
            self.diagnoses.clear()


def missing_seqs(path: Path) -> tuple[int, int]:
    """(samples recorded, sample numbers missing between each switch's first and last)."""
    seqs: dict[str, list[int]] = {}
    for message in load_recording(path).messages:
        if isinstance(message, MotorSample):
            seqs.setdefault(message.switch_id, []).append(message.seq)
    count = sum(len(s) for s in seqs.values())
    missing = sum(max(s) - min(s) + 1 - len(set(s)) for s in seqs.values())
    return count, missing


def backlog_recording(source: Path, out: Path, switches: int) -> int:
    """The throws (start to end, no idle samples) of the first `switches` switches; returns their count."""
    records = load_recording(source).records
    keep_ids = sorted({r.switch_id for r in records}, key=lambda s: int(s[2:]))[:switches]
    windows: dict[str, list[tuple[int, int]]] = {s: [] for s in keep_ids}
    starts: dict[str, int] = {}
    for r in records:
        if isinstance(r.message, ThrowEvent) and r.switch_id in windows:
            if r.message.phase == "start":
                starts[r.switch_id] = r.message.t_ns
            elif r.switch_id in starts:
                windows[r.switch_id].append((starts.pop(r.switch_id), r.message.t_ns))
    with RecordingWriter(out) as writer:
        for r in records:
            if r.switch_id not in windows or r.kind not in ("motor", "throw"):
                continue
            if r.kind == "motor" and not any(a <= r.message.t_ns <= b for a, b in windows[r.switch_id]):
                continue
            writer.write(r.key, r.message)
    return sum(len(w) for w in windows.values())


def clear_rate(processes: ServiceProcesses, session, observer: Observer, endpoint: str, backlog: Path, throws: int,
               shards: int) -> float:
    """Throws per second that `shards` diagnosers clear after a fast replay has queued the backlog."""
    observer.reset()
    diagnosers = [processes.start("diagnoser", "--connect", endpoint, "--shard", f"{k}/{shards}")
                  for k in range(1, shards + 1)]
    wait_ready(session, processes, diagnoser=shards)
    replay = processes.start("replay", str(backlog), "--connect", endpoint, "--fast")
    replay.wait(600)
    replay_end = time.monotonic()
    wait_for(lambda: len(observer.diagnoses) >= throws, 900, f"{throws} diagnoses of the backlog")
    after = sorted(t for t in observer.diagnoses.values() if t > replay_end)
    for process in diagnosers:
        processes.stop(process)
    if len(after) < 2:
        return float("nan")
    return (len(after) - 1) / (after[-1] - replay_end)


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--switches", type=int, default=100)
    p.add_argument("--throws", type=int, default=3, help="throws per switch in the fleet run")
    p.add_argument("--backlog-switches", type=int, default=100, help="switches whose throws form the backlog")
    p.add_argument("--records", action="store_true", help="throws as records into elastic diagnosers (see above)")
    p.add_argument("--elastic", action="store_true", help="with --records: a diagnoser joins, then one is killed")
    p.add_argument("--burst", type=int, default=100, help="with --records: switches of the capacity run")
    p.add_argument("--commissioning", type=int, default=2 * COMMISSIONING_THROWS,
                   help="with --records: each capacity switch's commissioning throws, timed apart")
    p.add_argument("--burst-throws", type=int, default=16,
                   help="with --records: throws per switch in service in the capacity run")
    p.add_argument("--fleet", type=int, default=2000, help="with --records: switches of the paced run")
    p.add_argument("--load", type=float, default=0.4, help="with --records: paced load, fraction of capacity")
    p.add_argument("--paced-s", type=float, default=None, help="with --records: paced run (default 40 s, 60 elastic)")
    p.add_argument("--outage", type=float, default=None, metavar="S",
                   help="with --records: every diagnoser down for S simulated seconds, then back (see above)")
    p.add_argument("--speed", type=float, default=30.0, help="with --outage: the fleet's speed-up")
    p.add_argument("--db", default=None, help="with --outage: the historian's database (default a scratch SQLite file)")
    args = p.parse_args()
    for wrong, message in ((args.elastic and not args.records, "--elastic needs --records"),
                           (args.outage is not None and not args.records, "--outage needs --records"),
                           (args.outage is not None and not 0 < args.outage <= 86_400,
                            f"--outage {args.outage} is outside the accepted range 0 to 86400 s"),
                           (args.commissioning < 0, f"--commissioning {args.commissioning} is outside the accepted range"
                                                    " 0 or more throws per switch"),
                           (args.burst_throws < 1, f"--burst-throws {args.burst_throws} is outside the accepted range"
                                                   " 1 or more throws per switch")):
        if wrong:
            p.exit(2, f"{p.prog}: error: {message}\n")  # one line, as the services' commands give
    if args.records and args.outage is not None:
        emit(outage_benchmark(args), args.json)
        return
    if args.records:
        emit(records_benchmark(args), args.json)
        return
    with routed_bus() as (work, library, processes, endpoint, session):
        observer = Observer(session)
        recording = work / "fleet.mcap"
        recorder = processes.start("recorder", "--connect", endpoint, "--out", str(recording))
        diagnoser = processes.start("diagnoser", "--connect", endpoint)
        wait_ready(session, processes, diagnoser=1, recorder=1)
        simulator = processes.start("simulator", "--connect", endpoint, "--switches", str(args.switches),
                                    "--throws", str(args.throws), "--interval", str(INTERVAL_S),
                                    "--rate", str(RATE_HZ), "--throws-from", str(library))
        simulator.wait()
        expected = args.switches * args.throws
        try:
            wait_for(lambda: len(observer.diagnoses) >= expected, 120, "every throw's diagnosis")
        except TimeoutError:
            pass
        time.sleep(1.0)
        processes.stop(recorder)
        processes.stop(diagnoser)
        samples, missing = missing_seqs(recording)
        latencies = [1e3 * (observer.diagnoses[k] - observer.ends[k]) for k in observer.diagnoses if k in observer.ends]
        rate = observer.samples_per_s()
        undiagnosed = expected - len(observer.diagnoses)

        backlog = work / "backlog.mcap"
        backlog_throws = backlog_recording(recording, backlog, args.backlog_switches)
        one = clear_rate(processes, session, observer, endpoint, backlog, backlog_throws, 1)
        two = clear_rate(processes, session, observer, endpoint, backlog, backlog_throws, 2)
    result = {
        "switches": args.switches,
        "samples_per_s": round(rate, 1),
        "throws": expected,
        "lost": int(missing + undiagnosed),
        "latency_ms": {"p50": round(statistics.median(latencies), 1),
                       "p95": round(float(np.percentile(latencies, 95)), 1)},
        "shard_speedup": round(two / one, 3),
        "samples_recorded": samples,
        "missing_samples": int(missing),
        "throws_without_diagnosis": int(undiagnosed),
        "backlog_throws": backlog_throws,
        "clear_rate_throws_per_s": {"one_shard": round(one, 2), "two_shards": round(two, 2)},
    }
    emit(result, args.json)


# -- throws as records into elastic diagnosers ------------------------------------------------------
RECORD_INTERVAL_S = 900.0  # a real switch throws about 100 times a day
THROWS_PER_DAY = 100
STATUS_S = "0.2"


class RecordObserver:
    """Arrival times (monotonic s) of records and diagnoses per throw, every diagnoser status, and the live
    diagnosers as liveliness shows them."""

    def __init__(self, session):
        self.lock = threading.Lock()
        self.records: dict[tuple[str, int], float] = {}
        self.diagnoses: dict[tuple[str, int], float] = {}
        self.duplicates = 0
        self.statuses: list[tuple[float, ServiceStatus]] = []
        self.joined: dict[str, float] = {}
        self._subscribers = [
            session.declare_subscriber("railswitch/*/record", self._record),
            session.declare_subscriber("railswitch/*/diagnosis", self._diagnosis),
            session.declare_subscriber("railswitch/@service/diagnoser/*/status", self._status),
            session.liveliness().declare_subscriber("railswitch/@service/diagnoser/*", self._live, history=True)]

    def _record(self, sample) -> None:
        now = time.monotonic()
        record = decode(ThrowRecord, sample.payload.to_bytes())
        with self.lock:
            self.records[record.switch_id, record.throw_index] = now

    def _diagnosis(self, sample) -> None:
        now = time.monotonic()
        diagnosis = decode(Diagnosis, sample.payload.to_bytes())
        with self.lock:
            key = diagnosis.switch_id, diagnosis.throw_index
            self.duplicates += key in self.diagnoses
            self.diagnoses.setdefault(key, now)

    def _status(self, sample) -> None:
        now = time.monotonic()
        with self.lock:
            self.statuses.append((now, decode(ServiceStatus, sample.payload.to_bytes())))

    def _live(self, sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self.joined.setdefault(str(sample.key_expr).rsplit("/", 1)[-1], time.monotonic())

    def reset(self) -> None:
        with self.lock:
            self.records.clear()
            self.diagnoses.clear()
            self.duplicates = 0

    def diagnosed_before(self, index: int) -> int:
        """Throws diagnosed whose index in their switch's life is below `index`."""
        with self.lock:
            return sum(throw < index for _, throw in self.diagnoses)

    def undiagnosed(self) -> int:
        with self.lock:
            return len(set(self.records) - set(self.diagnoses))

    def latencies_ms(self) -> list[float]:
        with self.lock:
            return [1e3 * (t - self.records[k]) for k, t in self.diagnoses.items() if k in self.records]

    def latest_counters(self, instance: str) -> dict[str, int]:
        with self.lock:
            return next((s.counters for _, s in reversed(self.statuses) if s.instance == instance), {})

    def settled_after(self, event_s: float, live: list[str]) -> float:
        """Seconds from event_s until every live diagnoser had reported the live set's size (nan if never)."""
        with self.lock:
            firsts = [next((t for t, s in self.statuses if t > event_s and s.instance == instance
                            and s.counters.get("members") == len(live)), math.nan) for instance in live]
        return max(firsts) - event_s


def cpu_s(pid: int) -> float:
    """User and system CPU seconds a process has used (/proc/<pid>/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def record_fleet(processes: ServiceProcesses, endpoint: str, library: Path, name: str, switches: int, speed: float,
                 throws: int):
    """A simulator sending records of switches <name>1 … <name>N: each run its own switches, since a switch's
    records must go forward in time and a sped-up run's times run ahead of the clock."""
    scenario = processes.log_dir / f"{name}.toml"
    scenario.write_text(f"interval_s = {RECORD_INTERVAL_S}\n" + "".join(
        f'[[switches]]\nid = "{name}{k + 1}"\nthrows = {throws}\n' for k in range(switches)))
    return processes.start("simulator", "--connect", endpoint, "--as-records", "--scenario", str(scenario),
                           "--speed", f"{speed:g}", "--throws-from", str(library), "--status-interval", "5")


def capacity_run(processes, observer: RecordObserver, endpoint: str, library: Path, diagnosers, burst: int,
                 commissioning: int, throws: int) -> dict:
    """`commissioning` and then `throws` throws of each of `burst` switches at once: how fast, and at what CPU
    cost, the diagnosers clear each phase. A switch's throws arrive 0.09 s apart and every switch's at once, so
    the diagnosers' backlog runs in throw order: the commissioning phase ends when its last throw is diagnosed
    (the diagnosers may have begun one throw of service each by then, under 1 % of it)."""
    observer.reset()
    phases: list[dict] = []
    cpu, start = sum(cpu_s(d.pid) for d in diagnosers), time.monotonic()

    def phase(name: str, count: int) -> None:
        nonlocal cpu, start
        now_cpu, now = sum(cpu_s(d.pid) for d in diagnosers), time.monotonic()
        per_cpu_s = count / (now_cpu - cpu)
        phases.append({"phase": name, "throws": count, "throws_per_switch": count // burst,
                       "throws_per_s_cleared": round(count / (now - start), 2), "diagnoser_cpu_s": round(now_cpu - cpu, 1),
                       "throws_per_cpu_s": round(per_cpu_s, 2), "switches_per_core": int(per_cpu_s * 86_400 / THROWS_PER_DAY)})
        cpu, start = now_cpu, now

    fleet = record_fleet(processes, endpoint, library, "burst", burst, 10_000.0, commissioning + throws)
    if commissioning:
        wait_for(lambda: observer.diagnosed_before(commissioning) >= burst * commissioning, 900,
                 "the commissioning throws' diagnoses", poll_s=0.01)
        phase("commissioning", burst * commissioning)
    fleet.wait(300)
    total = burst * (commissioning + throws)
    wait_for(lambda: len(observer.records) >= total and observer.undiagnosed() == 0, 900, "the burst's diagnoses",
             poll_s=0.01)
    phase("service", burst * throws)
    return {"switches": burst, **phases[-1], "phases": phases}


def paced_run(processes, session, observer: RecordObserver, endpoint: str, library: Path, work: Path, diagnosers,
              fleet_size: int, rate: float, paced_s: float, elastic: bool) -> dict:
    """The fleet at `rate` throws per second for paced_s; with elastic, a third diagnoser joins at a quarter of it
    and one of the first two is killed with -9 once the third has settled."""
    observer.reset()
    speed = rate * RECORD_INTERVAL_S / fleet_size
    fleet = record_fleet(processes, endpoint, library, "sw", fleet_size, speed, 1_000)
    start = time.monotonic()
    out: dict = {"fleet": fleet_size, "speed": round(speed, 2), "offered_throws_per_s": round(rate, 2)}
    if elastic:
        time.sleep(paced_s / 4)
        third = processes.start("diagnoser", "--connect", endpoint, "--state", str(work / "state-3"),
                                "--status-interval", STATUS_S)
        wait_ready(session, processes, diagnoser=3)
        wait_for(lambda: instance_of(third) in observer.joined, 30, "the third diagnoser's token")
        joined_s = observer.joined[instance_of(third)]
        live = [instance_of(d) for d in (*diagnosers, third)]
        wait_for(lambda: not math.isnan(observer.settled_after(joined_s, live)), 30, "the join to settle")
        time.sleep(3.0)
        victim = diagnosers[0]
        killed_s = time.monotonic()
        processes.stop(victim, signal.SIGKILL)
        survivors = live[1:]
        wait_for(lambda: not math.isnan(observer.settled_after(killed_s, survivors)), 30, "the kill to settle")
        out.update(join_settle_s=round(observer.settled_after(joined_s, live), 2),
                   kill_settle_s=round(observer.settled_after(killed_s, survivors), 2))
        time.sleep(max(start + paced_s - time.monotonic(), 10.0))  # throws after the kill, 10 s of them at least
    else:
        time.sleep(paced_s)
    processes.stop(fleet)
    try:
        wait_for(lambda: observer.undiagnosed() == 0, 300, "every throw's diagnosis")
    except TimeoutError:
        pass
    latencies = observer.latencies_ms()  # none where a short run's staggered fleet threw nothing (then null)
    out.update(throws=len(observer.records), lost=observer.undiagnosed(), duplicates=observer.duplicates,
               latency_ms={"p50": round(statistics.median(latencies), 1),
                           "p95": round(float(np.percentile(latencies, 95)), 1)} if latencies else None)
    if elastic:
        counters = {name: observer.latest_counters(name) for name in survivors}
        out.update(taken_over=sum(c.get("taken_over", 0) for c in counters.values()),
                   held_expired=sum(c.get("held_expired", 0) for c in counters.values()),
                   switches_owned=[c.get("switches", 0) for c in counters.values()],
                   third_diagnosed=counters[instance_of(third)].get("diagnosed", 0))
    return out


@contextmanager
def routed_bus():
    """A scratch folder with a library of recorded throws, a router on a free loopback port and a session on it:
    (work folder, library, processes, endpoint, session); every process stopped and the session closed after."""
    endpoint = free_loopback_endpoint()
    with tempfile.TemporaryDirectory(prefix="railswitch-bus-") as scratch, ServiceProcesses(Path(scratch)) as processes:
        work = Path(scratch)
        library = work / "library.mcap"
        # eight throws, four each way: a switch's throws in one direction differ (noise), as a real switch's do
        simulate_to_mcap(library, throws=8, noise_rel=0.01, seed=1)
        processes.start("router", "--listen", endpoint)
        session = open_session(BusOptions(connect=(endpoint,)), wait_s=30.0)
        try:
            yield work, library, processes, endpoint, session
        finally:
            session.close()


def records_benchmark(args) -> dict:
    paced_s = args.paced_s or (60.0 if args.elastic else 40.0)
    with routed_bus() as (work, library, processes, endpoint, session):
        observer = RecordObserver(session)
        diagnosers = [processes.start("diagnoser", "--connect", endpoint, "--state", str(work / f"state-{k}"),
                                      "--status-interval", STATUS_S) for k in (1, 2)]
        wait_ready(session, processes, diagnoser=2)
        capacity = capacity_run(processes, observer, endpoint, library, diagnosers, args.burst, args.commissioning,
                                args.burst_throws)
        rate = args.load * capacity["throws_per_s_cleared"]
        paced = paced_run(processes, session, observer, endpoint, library, work, diagnosers, args.fleet, rate,
                          paced_s, args.elastic)
    result = {"records": True, "elastic": args.elastic, "throws_per_s_cleared": capacity["throws_per_s_cleared"],
              "switches_per_core": capacity["switches_per_core"], "lost": paced["lost"],
              "latency_ms": paced["latency_ms"]}
    if args.elastic:
        result["settle_s"] = {"join": paced["join_settle_s"], "kill": paced["kill_settle_s"]}
    return {**result, "capacity": capacity, "paced": paced}


def outage_benchmark(args) -> dict:
    fleet_size = args.fleet if args.fleet != 2000 else 200  # the paced run's default is a capacity fleet
    run_s = args.paced_s or 60.0
    with routed_bus() as (work, library, processes, endpoint, session):
        observer = RecordObserver(session)
        db = args.db or str(work / "history.sqlite")
        state = str(work / "state")

        def diagnosers() -> list:
            started = [processes.start("diagnoser", "--connect", endpoint, "--state", state, "--status-interval",
                                       STATUS_S) for _ in range(2)]
            wait_ready(session, processes, diagnoser=2)
            return started

        first = diagnosers()
        processes.start("historian", "--connect", endpoint, "--db", db)
        wait_ready(session, processes, historian=1)
        scenario = processes.log_dir / "outage.toml"
        scenario.write_text(f"interval_s = {RECORD_INTERVAL_S}\n" + "".join(
            f'[[switches]]\nid = "sw{k + 1}"\nthrows = 1000\n' for k in range(fleet_size)))
        fleet = processes.start("simulator", "--connect", endpoint, "--as-records", "--scenario", str(scenario),
                                "--speed", f"{args.speed:g}", "--throws-from", str(library), "--outage",
                                f"{args.outage:g}", "--status-interval", "5")
        time.sleep(run_s / 4)
        killed_s = time.monotonic()
        for process in first:
            processes.stop(process, signal.SIGKILL)
        time.sleep(max(args.outage / args.speed - (time.monotonic() - killed_s), 0.0))
        second = diagnosers()
        ready_s = time.monotonic()
        with observer.lock:
            while_down = [k for k, at_s in observer.records.items() if killed_s <= at_s <= ready_s]
        try:
            wait_for(lambda: all(k in observer.diagnoses for k in while_down), 300, "the outage's throws diagnosed")
        except TimeoutError:
            pass
        with observer.lock:
            caught = [observer.diagnoses[k] for k in while_down if k in observer.diagnoses]
        catch_up_s = max(caught, default=ready_s) - ready_s
        time.sleep(max(killed_s + run_s * 3 / 4 - time.monotonic(), 5.0))
        processes.stop(fleet)
        try:
            wait_for(lambda: observer.undiagnosed() == 0, 120, "every throw's diagnosis")
        except TimeoutError:
            pass
        time.sleep(2.0)  # the historian's last batch
        counters = [observer.latest_counters(instance_of(d)) for d in second]
        stored, stored_twice = history_counts(db)
        return {"records": True, "outage_s": args.outage, "fleet": fleet_size, "speed": args.speed,
                "throws": len(observer.records), "undiagnosed": observer.undiagnosed(),
                "stored": stored, "stored_twice": stored_twice, "diagnosed_twice_on_bus": observer.duplicates,
                "missed": sum(c.get("missed", 0) for c in counters),
                "missed_samples": sum(c.get("missed_samples", 0) for c in counters),
                "already_diagnosed": sum(c.get("already_diagnosed", 0) for c in counters),
                "down_simulated_s": round((ready_s - killed_s) * args.speed, 1),
                "throws_while_down": len(while_down), "catch_up_s": round(catch_up_s, 2),
                "cleared_per_s": round(len(while_down) / catch_up_s, 2) if catch_up_s > 0 else None}


def history_counts(db: str) -> tuple[int, int]:
    """(diagnoses stored, throws with more than one stored diagnosis) in the historian's database (a file or a
    postgresql:// URL)."""
    with open_history(db, create=False) as history:
        rows = [(switch_id, index) for switch_id in history.switches()
                for index in history.throw_indices(switch_id, "diagnosis")]
    return len(rows), len(rows) - len(set(rows))


if __name__ == "__main__":
    main()
