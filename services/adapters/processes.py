"""Start `railswitch` services as child processes and stop exactly those (demo, tests, benchmarks)."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import zenoh

from railswitch.schemas import SERVICE_PREFIX
from railswitch.services.adapters.zenoh_bus import instance_name


class ServiceProcesses:
    """Child processes, each logging to <log_dir>/<name>-<n>.log; on exit SIGINT, then SIGKILL after a grace."""

    def __init__(self, log_dir: Path, *, own_session: bool = False, grace_s: float = 20.0):
        self.log_dir = Path(log_dir)
        self.own_session = own_session  # True: a terminal's Ctrl-C reaches only the parent, which stops them
        self.grace_s = grace_s
        self.started: list[tuple[str, Path, subprocess.Popen]] = []
        self.stopped: set[int] = set()  # pids we stopped on purpose
        self.killed: list[subprocess.Popen] = []  # those that outlived the grace period and were killed

    def start(self, name: str, *args: str) -> subprocess.Popen:
        path = self.log_dir / f"{name}-{len(self.started)}.log"
        with open(path, "wb") as log:
            process = subprocess.Popen([sys.executable, "-m", "railswitch", name, *args], stdin=subprocess.DEVNULL,
                                       stdout=log, stderr=subprocess.STDOUT, start_new_session=self.own_session,
                                       env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.started.append((name, path, process))
        return process

    def log(self, process: subprocess.Popen, lines: int | None = None) -> str:
        path = next(p for _, p, proc in self.started if proc is process)
        text = path.read_text(errors="replace").splitlines()
        return "\n".join(text[-lines:] if lines else text)

    def stop(self, process: subprocess.Popen, sig: int = signal.SIGINT) -> int:
        """Signal one process and wait for it (killing it after the grace period); its exit code."""
        self.stopped.add(process.pid)
        if process.poll() is None:
            process.send_signal(sig)
            self._wait(process)
        return process.returncode

    def _wait(self, process: subprocess.Popen) -> None:
        """Wait for a signalled process, killing it after the grace period."""
        if process.poll() is None:
            try:
                process.wait(self.grace_s)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
                self.killed.append(process)

    def stop_all(self) -> None:
        """Latest first, so producers stop before the recorder finishes its file."""
        running = [p for _, _, p in reversed(self.started) if p.poll() is None]
        for process in running:
            self.stopped.add(process.pid)
            process.send_signal(signal.SIGINT)
        for process in running:  # signalled once: a second SIGINT could reach a service that has finished its
            self._wait(process)  # work and given the signal back to Python, and kill it on its way out

    def failures(self, lines: int = 10) -> str:
        """One paragraph per child that failed, with its last log lines ('' when none did): one that exited with an
        error code (a crash, say, which a recorder's file does not survive) or outlived the grace period and was
        killed. Call it after stop_all."""
        return "\n".join(
            f"{self.name(p)} (pid {p.pid}) "
            + (f"did not stop within {self.grace_s:g} s of SIGINT and was killed" if p in self.killed
               else f"exited with code {p.returncode}")
            + f"; its last lines:\n{self.log(p, lines)}"
            for p in self.failed())

    def failed(self) -> list[subprocess.Popen]:
        """The children that exited with an error code or were killed."""
        return [p for _, _, p in self.started if p in self.killed or p.returncode not in (0, None)]

    def name(self, process: subprocess.Popen) -> str:
        return next(name for name, _, proc in self.started if proc is process)

    def __enter__(self) -> ServiceProcesses:
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        self.stop_all()
        if exc_type is not None and issubclass(exc_type, Exception):
            self.print_logs()

    def print_logs(self, lines: int = 30, first: int = 15) -> None:
        """The first and last lines of every child's log, on stderr: what a failed run (a test on CI, say) needs to
        be read after its scratch directory is gone (how a service started, its peers and models, and how it ended)."""
        for _, path, process in self.started:
            text = self.log(process).splitlines()
            shown = text if len(text) <= first + lines else [*text[:first], f"[... {len(text) - first - lines} "
                                                             "lines ...]", *text[-lines:]]
            print(f"--- {path.name} (pid {process.pid}, exit code {process.returncode}), first {first} and last "
                  f"{lines} lines:", *shown, sep="\n", file=sys.stderr)


def instance_of(process: subprocess.Popen) -> str:
    """A child service's instance, as it names itself on the bus (its liveliness token and status)."""
    return instance_name(process.pid)


def free_loopback_endpoint() -> str:
    """A TCP endpoint on 127.0.0.1 with a port nobody listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def services_alive(session: zenoh.Session) -> Counter[str]:
    """How many instances of each service have their liveliness token on the bus."""
    names = Counter()
    for reply in session.liveliness().get(f"{SERVICE_PREFIX}/**"):
        if reply.ok is not None:
            names[str(reply.ok.key_expr).split("/")[2]] += 1
    return names


def wait_for(condition: Callable[[], bool], timeout_s: float, what: str, poll_s: float = 0.2,
             abort: Callable[[], str | None] | None = None) -> None:
    """Poll until condition holds; TimeoutError naming `what`, or RuntimeError when abort() says why."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        reason = abort() if abort else None
        if reason:
            raise RuntimeError(reason)
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        time.sleep(poll_s)


def wait_ready(session: zenoh.Session, processes: ServiceProcesses, timeout_s: float = 300.0,
               stop: threading.Event | None = None, **counts: int) -> None:
    """Until `counts` instances of each named service are up (diagnosers: subscribed and warmed up), or stop."""
    def exited() -> str | None:
        for name, _, process in processes.started:
            if name in counts and process.pid not in processes.stopped and process.poll() is not None:
                return f"{name} exited with code {process.returncode}:\n{processes.log(process, 8)}"
        return None

    stopped = stop.is_set if stop is not None else lambda: False
    wait_for(lambda: stopped() or all(services_alive(session)[n] >= c for n, c in counts.items()), timeout_s,
             f"services {counts} to be ready", poll_s=0.5, abort=exited)
