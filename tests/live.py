"""Real processes and a real Zenoh router on loopback, for the end-to-end tests."""
from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import zenoh

from railswitch.schemas import Diagnosis, MotorSample, ThrowEvent, decode
from railswitch.services.adapters.zenoh_bus import BusOptions, open_session
from railswitch.services.adapters.processes import ServiceProcesses, free_loopback_endpoint, wait_for, wait_ready

ROOT = Path(__file__).resolve().parents[1]
__all__ = ["ROOT", "DiagnosisCollector", "ServiceProcesses", "client", "jsonl_decisions", "live_bus", "motor_sample",
           "start_router", "throw_event", "wait_for", "wait_ready"]
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
