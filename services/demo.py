"""`railswitch demo`: the whole product on one machine, ending with a summary.

An embedded Zenoh router runs in this process; the diagnoser, recorder and simulator run
as separate `railswitch` processes connected to it. Every switch throws nominally for the
first half of its throws and then with one fault mode (cycling through the four), so the
summary can hold each decision against the injected truth.
"""
from __future__ import annotations

import logging
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console
from rich.live import Live
from rich.table import Table

from models.diagnosis import DRIVING_BOLT
from schemas import Diagnosis, FaultTruth, MessageError, decode, parse_key_expr
from services.bus import BusError, BusOptions, Inbox, configure_logging, open_session, stop_on_signals
from services.mcap_io import RecordingPathError, check_writable
from services.watch import diagnosis_line, diagnosis_table

log = logging.getLogger("railswitch.demo")

DEMO_FAULTS = (  # the paper's four scenarios
    {"left_bolt_offset": 0.05},
    {"right_bolt_offset": 0.20},
    {"bearing_friction": 5000.0},
    {"obstacle_friction": 1.0e5, "obstacle_position": 1.10},
)
INTERVAL_S = 10.0
READY_TIMEOUT_S = 300.0  # a diagnoser on a machine without the compiled-model cache needs a while
DRAIN_TIMEOUT_S = 60.0


def demo_scenario(switches: int, throws: int) -> str:
    """TOML for `railswitch simulator --scenario`: nominal first half, then fault mode k mod 4."""
    lines = [f"interval_s = {INTERVAL_S}", ""]
    for k in range(switches):
        faults = DEMO_FAULTS[k % len(DEMO_FAULTS)]
        values = ", ".join(f"{name} = {value!r}" for name, value in faults.items())
        lines += ["[[switches]]", f'id = "sw{k + 1}"', f"throws = {throws}", "",
                  "[[switches.changes]]", f"throw = {throws // 2}", f"set = {{ {values} }}", ""]
    return "\n".join(lines)


def free_loopback_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def connect_endpoint(listen: str) -> str:
    """Where local processes reach a router listening on `listen` (any-address becomes loopback)."""
    proto, _, address = listen.partition("/")
    host, _, port = address.rpartition(":")
    if host in ("0.0.0.0", "[::]", "::", ""):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"


@dataclass
class Outcome:
    """What the demo saw: the diagnoses and the truth messages, per switch."""

    diagnoses: list[Diagnosis] = field(default_factory=list)
    truths: dict[str, list[FaultTruth]] = field(default_factory=dict)

    def truth_at(self, switch_id: str, t_ns: int) -> FaultTruth | None:
        earlier = [t for t in self.truths.get(switch_id, []) if t.t_ns <= t_ns]
        return max(earlier, key=lambda t: t.t_ns) if earlier else None

    def injected(self, diagnosis: Diagnosis) -> list[str]:
        truth = self.truth_at(diagnosis.switch_id, diagnosis.t_start_ns)
        return list(truth.active_modes()) if truth else []

    def expected(self) -> dict[tuple[str, int], str]:
        """The decision each throw should get: its injected mode, where a bolt counts once a throw
        it drives (left bolt: left to right) has run with it, since the other direction cannot see it."""
        out, seen = {}, {}
        for d in sorted(self.diagnoses, key=lambda d: (d.switch_id, d.throw_index)):
            modes = self.injected(d)
            driven = DRIVING_BOLT[d.direction]
            seen[d.switch_id] = {m for m in seen.get(d.switch_id, set()) if m in modes} | (
                {driven} if driven in modes else set())
            visible = [m for m in modes if m not in DRIVING_BOLT.values() or m in seen[d.switch_id]]
            out[d.switch_id, d.throw_index] = "+".join(visible) or "nominal"
        return out

    def summary(self) -> tuple[Table, int]:
        table = Table(title="demo summary: decision of each throw against the injected fault")
        for column in ("switch", "throw", "direction", "injected", "expected", "decided", ""):
            table.add_column(column)
        correct, expected = 0, self.expected()
        for d in sorted(self.diagnoses, key=lambda d: (d.switch_id, d.throw_index)):
            want = expected[d.switch_id, d.throw_index]
            ok = d.decision == want
            correct += ok
            table.add_row(d.switch_id, str(d.throw_index), d.direction, "+".join(self.injected(d)) or "none", want,
                          d.decision, "[green]✓[/]" if ok else "[red]✗[/]")
        return table, correct


class _Processes:
    """The services the demo started; all of them stop (SIGINT, then kill) when it ends."""

    def __init__(self, log_dir: Path):
        self.log_dir = log_dir
        self.running: dict[str, subprocess.Popen] = {}

    def start(self, name: str, *args: str) -> subprocess.Popen:
        stderr = open(self.log_dir / f"{name}.log", "wb")
        process = subprocess.Popen([sys.executable, "-m", "services.cli", name, *args], stdout=subprocess.DEVNULL,
                                   stderr=stderr, start_new_session=True)  # Ctrl-C reaches only us; we stop them
        self.running[name] = process
        return process

    def stop(self, name: str, timeout_s: float = 20.0) -> int | None:
        process = self.running.pop(name, None)
        if process is None:
            return None
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        return process.returncode

    def stop_all(self) -> None:
        for name in ("simulator", "diagnoser", "recorder"):
            self.stop(name)

    def tail(self, name: str, lines: int = 5) -> str:
        text = (self.log_dir / f"{name}.log").read_text(errors="replace").splitlines()
        return "\n".join(text[-lines:])


def _wait_ready(session, names: tuple[str, ...], processes: _Processes, stop: threading.Event) -> None:
    """Until every named service has declared its liveliness token (it is subscribed and warmed up)."""
    deadline = time.monotonic() + READY_TIMEOUT_S
    while not stop.is_set():
        alive = {str(reply.ok.key_expr).split("/")[2] for reply in session.liveliness().get("railswitch/service/**")
                 if reply.ok is not None}
        if all(name in alive for name in names):
            return
        for name in names:
            if processes.running[name].poll() is not None:
                raise RuntimeError(f"{name} exited early:\n{processes.tail(name)}")
        if time.monotonic() > deadline:
            raise RuntimeError(f"services not ready after {READY_TIMEOUT_S:.0f} s: {sorted(set(names) - alive)}")
        stop.wait(0.5)


def run_demo(args) -> int:
    configure_logging(False)
    console = Console()
    try:
        out = check_writable(args.out)
    except RecordingPathError as error:
        print(f"railswitch: error: {error}", file=sys.stderr)
        return 2
    listen = args.listen or free_loopback_endpoint()
    connect = connect_endpoint(listen)
    with tempfile.TemporaryDirectory(prefix="railswitch-demo-") as scratch, stop_on_signals() as stop:
        scratch_dir = Path(scratch)
        scenario = scratch_dir / "scenario.toml"
        scenario.write_text(demo_scenario(args.switches, args.throws))
        try:
            router = open_session(BusOptions(mode="router", listen=(listen,)), retry=False)
        except BusError as error:
            print(f"railswitch: error: {error}", file=sys.stderr)
            return 2
        processes = _Processes(scratch_dir)
        outcome = Outcome()
        try:
            inbox = Inbox(router, ["railswitch/*/diagnosis", "railswitch/*/truth"])
            console.print(f"router on {listen}; starting diagnoser ({args.model}) and recorder ({out})")
            processes.start("diagnoser", "--connect", connect, "--model", args.model)
            processes.start("recorder", "--connect", connect, "--out", str(out))
            _wait_ready(router, ("diagnoser", "recorder"), processes, stop)
            console.print(f"simulating {args.switches} switches x {args.throws} throws at {args.speed:g}x real time")
            simulator = processes.start("simulator", "--connect", connect, "--scenario", str(scenario),
                                        "--speed", str(args.speed))
            expected = args.switches * args.throws
            _follow(inbox, outcome, console, simulator, expected, stop)
        except RuntimeError as error:
            print(f"railswitch demo: {error}", file=sys.stderr)
            return 1
        finally:
            processes.stop_all()
            router.close()
        table, correct = outcome.summary()
        console.print(table)
        missing = args.switches * args.throws - len(outcome.diagnoses)
        console.print(f"{correct} of {len(outcome.diagnoses)} throws decided as expected"
                      + (f"; {missing} throws without a diagnosis" if missing > 0 else "")
                      + ("; stopped early" if stop.is_set() else ""))
        console.print(f"recording: {out.resolve()}")
        return 130 if stop.is_set() else 0


def _follow(inbox: Inbox, outcome: Outcome, console: Console, simulator: subprocess.Popen, expected: int,
            stop: threading.Event) -> None:
    """Show diagnoses as they come, until every throw has one (or the simulator failed, or stop)."""
    latest: dict[str, Diagnosis] = {}
    drain_deadline = None
    live = console.is_terminal
    with Live(diagnosis_table(latest), console=console, auto_refresh=False) if live else nullcontext() as table:
        while not stop.is_set() and len(outcome.diagnoses) < expected:
            if simulator.poll() is not None:
                if simulator.returncode != 0:
                    raise RuntimeError(f"simulator failed with exit code {simulator.returncode}")
                drain_deadline = drain_deadline or time.monotonic() + DRAIN_TIMEOUT_S
                if time.monotonic() > drain_deadline:
                    break
            item = inbox.get(0.2)
            if item is None:
                continue
            try:
                _, kind = parse_key_expr(item.key)
                message = decode(Diagnosis if kind == "diagnosis" else FaultTruth, item.payload)
            except (ValueError, MessageError):
                continue
            if isinstance(message, FaultTruth):
                outcome.truths.setdefault(message.switch_id, []).append(message)
                continue
            outcome.diagnoses.append(message)
            latest[message.switch_id] = message
            if live:
                table.update(diagnosis_table(latest), refresh=True)
            else:
                console.print(diagnosis_line(message), highlight=False)
