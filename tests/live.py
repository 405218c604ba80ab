"""Real processes and a real Zenoh router on loopback, for the end-to-end tests.

Every process started here is stopped at the end of its `with` block (SIGINT, then
SIGKILL after a grace period), by its own id.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from schemas import Diagnosis, decode
from services.bus import BusOptions, open_session
from services.demo import free_loopback_endpoint

ROOT = Path(__file__).resolve().parents[1]


class Services:
    """Starts `railswitch` commands as processes, logs each to a file, stops them all on exit."""

    def __init__(self, log_dir: Path):
        self.log_dir = log_dir
        self.processes: list[tuple[str, subprocess.Popen]] = []

    def start(self, name: str, *args: str) -> subprocess.Popen:
        log = open(self.log_dir / f"{name}-{len(self.processes)}.log", "wb")
        process = subprocess.Popen([sys.executable, "-m", "services.cli", name, *args], cwd=ROOT,
                                   stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.processes.append((name, process))
        return process

    def log(self, process: subprocess.Popen) -> str:
        index = next(i for i, (_, p) in enumerate(self.processes) if p is process)
        name = self.processes[index][0]
        return (self.log_dir / f"{name}-{index}.log").read_text(errors="replace")

    def __enter__(self) -> Services:
        return self

    def __exit__(self, *exc) -> None:
        for _, process in reversed(self.processes):
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for _, process in self.processes:
            try:
                process.wait(20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def start_router(services: Services) -> str:
    """A `railswitch router` process on a free loopback port; returns its endpoint."""
    endpoint = free_loopback_endpoint()
    services.start("router", "--listen", endpoint)
    return endpoint


def client(endpoint: str) -> zenoh.Session:
    """An independent Zenoh client session of the test itself."""
    return open_session(BusOptions(connect=(endpoint,)), wait_s=30.0)


def wait_for(condition: Callable[[], bool], timeout_s: float, what: str, poll_s: float = 0.2) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        time.sleep(poll_s)


def services_alive(session: zenoh.Session) -> set[str]:
    """Names of the services whose liveliness token is declared on the bus."""
    return {str(reply.ok.key_expr).split("/")[2] for reply in session.liveliness().get("railswitch/service/**")
            if reply.ok is not None}


def wait_ready(session: zenoh.Session, *names: str, timeout_s: float = 300.0) -> None:
    wait_for(lambda: set(names) <= services_alive(session), timeout_s, f"services {names} to be ready", poll_s=0.5)


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
