"""Real processes and a real Zenoh router on loopback, for the end-to-end tests."""
from __future__ import annotations

import json
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import zenoh

from railswitch.schemas import SERVICE_PREFIX, Diagnosis, MotorSample, ServiceStatus, ThrowEvent, ThrowRecord, decode
from railswitch.services.adapters.recordings import load_recording
from railswitch.services.adapters.zenoh_bus import BusOptions, open_session
from railswitch.services.adapters.processes import (
    ServiceProcesses,
    free_loopback_endpoint,
    instance_of,
    wait_for,
    wait_ready,
)
from railswitch.services.core.records import record_of_throw
from railswitch.services.core.throw_cutter import cut_throws

ROOT = Path(__file__).resolve().parents[1]
__all__ = ["ROOT", "DiagnosisCollector", "RecordSource", "ServiceProcesses", "ServiceWatch", "ThrowWatcher", "client", "instance_of",
           "jsonl_decisions", "live_bus", "motor_sample", "start_router", "throw_event", "wait_for", "wait_ready"]
FLAT_PROFILE = {"reference_t_s": [0.0, 7.0], "reference_velocity_rad_s": [0.0, 0.0]}


def motor_sample(seq: int, t_ns: int, switch_id: str = "sw1") -> MotorSample:
    """A motor sample at rest."""
    return MotorSample(switch_id=switch_id, seq=seq, t_ns=t_ns, current_a=0.0, angle_rad=0.0, velocity_rad_s=0.0)


def throw_event(phase: str, index: int, t_ns: int, switch_id: str = "sw1") -> ThrowEvent:
    """A left-to-right throw event with a flat reference profile."""
    return ThrowEvent(switch_id=switch_id, throw_index=index, direction="left_to_right", phase=phase, t_ns=t_ns,
                      **FLAT_PROFILE)


def start_router(services: ServiceProcesses) -> str:
    """A `railswitch router` process on a free loopback port; returns its endpoint."""
    endpoint = free_loopback_endpoint()
    services.start("router", "--listen", endpoint)
    return endpoint


def client(endpoint: str) -> zenoh.Session:
    """An independent Zenoh client session of the test itself."""
    return open_session(BusOptions(connect=(endpoint,)), wait_s=30.0)


class DiagnosisCollector:
    """Subscribes to every switch's diagnosis topic and keeps what arrives."""

    def __init__(self, session: zenoh.Session):
        self.received: list[Diagnosis] = []
        self._subscriber = session.declare_subscriber("railswitch/*/diagnosis", self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self.received.append(decode(Diagnosis, sample.payload.to_bytes()))

    def decisions(self) -> dict[tuple[str, int], str]:
        return {(d.switch_id, d.throw_index): d.decision for d in self.received}

    def features(self) -> dict[tuple[str, int], dict]:
        """Each throw's features as its diagnosis carried them."""
        return {(d.switch_id, d.throw_index): d.features.model_dump() for d in self.received if d.features is not None}

    def counts(self) -> Counter[tuple[str, int]]:
        """How many diagnoses each throw (switch, throw index) got."""
        return Counter((d.switch_id, d.throw_index) for d in list(self.received))


class ThrowWatcher:
    """The throw events and motor sample times of the bus, as the test's own subscriber sees them."""

    def __init__(self, session: zenoh.Session):
        self.starts: list[int] = []  # throw indices, in the order their start events arrived
        self.started: list[tuple[str, int]] = []  # the same with their switch
        self.last_sample_ns = 0
        self.samples = 0  # motor samples seen
        self._subscribers = [session.declare_subscriber("railswitch/*/throw", self._throw),
                             session.declare_subscriber("railswitch/*/motor", self._motor)]

    def _throw(self, sample: zenoh.Sample) -> None:
        event = decode(ThrowEvent, sample.payload.to_bytes())
        if event.phase == "start":
            self.starts.append(event.throw_index)
            self.started.append((event.switch_id, event.throw_index))

    def _motor(self, sample: zenoh.Sample) -> None:
        self.last_sample_ns = max(self.last_sample_ns, decode(MotorSample, sample.payload.to_bytes()).t_ns)
        self.samples += 1


class ServiceWatch:
    """The instances of one service as the bus shows them: when each one's liveliness token appeared (monotonic s,
    as this process saw it) and every ServiceStatus each published, with its arrival."""

    def __init__(self, session: zenoh.Session, service: str):
        self._lock = threading.Lock()
        self.appeared: dict[str, float] = {}
        self.statuses: list[tuple[float, ServiceStatus]] = []
        self._subscribers = [
            session.declare_subscriber(f"{SERVICE_PREFIX}/{service}/*/status", self._status),
            session.liveliness().declare_subscriber(f"{SERVICE_PREFIX}/{service}/*", self._token, history=True)]

    def _status(self, sample: zenoh.Sample) -> None:
        now = time.monotonic()
        status = decode(ServiceStatus, sample.payload.to_bytes())
        with self._lock:
            self.statuses.append((now, status))

    def _token(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            with self._lock:
                self.appeared.setdefault(str(sample.key_expr).rsplit("/", 1)[-1], time.monotonic())

    def latest(self, instance: str, after_s: float = float("-inf")) -> ServiceStatus | None:
        """The instance's latest status, if one arrived after after_s."""
        with self._lock:
            return next((s for t, s in reversed(self.statuses) if s.instance == instance and t > after_s), None)

    def first(self, instance: str, condition: Callable[[ServiceStatus], bool],
              after_s: float = float("-inf")) -> float | None:
        """When the first status of the instance that meets condition arrived (after after_s)."""
        with self._lock:
            return next((t for t, s in self.statuses if t > after_s and s.instance == instance and condition(s)),
                        None)


    def drained(self, instance: str, timeout_s: float = 30.0, what: str = "") -> None:
        """Until two consecutive statuses of the instance, both arriving after now, count the same payloads
        received. A service publishes its status from its loop, which takes a queued payload whenever there is one:
        a loop that took none between two statuses found its queue empty, so everything sent to it before had been
        handled (written, stored, diagnosed) or refused."""
        since = time.monotonic()

        def quiet() -> bool:
            with self._lock:
                counts = [s.received for t, s in self.statuses if t > since and s.instance == instance]
            return any(a == b for a, b in zip(counts, counts[1:]))

        wait_for(quiet, timeout_s, what or f"{instance} to handle everything it was sent")


class RecordSource:
    """The complete throws of a recording as ThrowRecords of any switch: each switch's throws go on in the
    recording's order (directions alternating), 10 s apart from a common start, indexed 0, 1, … per switch."""

    START_NS = 1_700_000_000 * 10**9
    INTERVAL_NS = 10 * 10**9

    def __init__(self, recording: Path = ROOT / "recordings" / "nominal.mcap"):
        self.records = [record_of_throw(t) for t in cut_throws(load_recording(recording).messages) if t.complete]
        self.sent: Counter[str] = Counter()

    def next(self, switch_id: str) -> ThrowRecord:
        """The switch's next throw."""
        index = self.sent[switch_id]
        self.sent[switch_id] += 1
        record = self.records[index % len(self.records)]
        start_ns = self.START_NS + index * self.INTERVAL_NS
        return record.model_copy(update={"switch_id": switch_id, "throw_index": index, "t_start_ns": start_ns,
                                         "t_end_ns": start_ns + record.t_end_ns - record.t_start_ns})


def jsonl_decisions(text: str) -> dict[tuple[str, int], str]:
    rows = [json.loads(line) for line in text.splitlines() if line.strip()]
    return {(r["switch_id"], r["throw_index"]): r["decision"] for r in rows}


@contextmanager
def live_bus(log_dir: Path) -> Iterator[tuple[ServiceProcesses, str, zenoh.Session, DiagnosisCollector]]:
    """A router process, the test's own session and a diagnosis collector; everything stops on exit."""
    with ServiceProcesses(log_dir) as services:
        endpoint = start_router(services)
        session = client(endpoint)
        try:
            yield services, endpoint, session, DiagnosisCollector(session)
        finally:
            session.close()
