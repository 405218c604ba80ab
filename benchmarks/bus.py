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
"""
from __future__ import annotations

import statistics
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from benchmarks.common import emit, parser
from railswitch.schemas import Diagnosis, MotorSample, ThrowEvent, decode
from railswitch.services.adapters.zenoh_bus import BusOptions, open_session
from railswitch.services.adapters.recordings import RecordingWriter, load_recording
from railswitch.services.adapters.processes import ServiceProcesses, free_loopback_endpoint, wait_for, wait_ready
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
    args = p.parse_args()
    endpoint = free_loopback_endpoint()
    with tempfile.TemporaryDirectory(prefix="railswitch-bus-") as scratch, ServiceProcesses(Path(scratch)) as processes:
        work = Path(scratch)
        library = work / "library.mcap"
        simulate_to_mcap(library, throws=2, noise_rel=0.01, seed=1)
        processes.start("router", "--listen", endpoint)
        session = open_session(BusOptions(connect=(endpoint,)), wait_s=30.0)
        try:
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
        finally:
            session.close()
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


if __name__ == "__main__":
    main()
