"""`railswitch demo`: the whole product on one machine, ending with a summary.

An embedded Zenoh router runs in this process; the diagnoser, recorder, historian and simulator
run as separate `railswitch` processes connected to it. The historian's file lies next to the
recording (demo.mcap: demo.sqlite), replaced at each run as the recording is. Every switch is drawn from the population
of real switches (not the model's twin) and throws healthily until commissioned, then with one
fault mode (cycling through the five), so the summary can hold each decision against the
injected truth, and show each switch's health after its last throw.
"""
from __future__ import annotations

import argparse
import logging
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

from railswitch.models.diagnosis.estimation import DRIVING_BOLT
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.schemas import FAULT_PARAMETERS, Diagnosis, FaultTruth, SwitchHealth
from railswitch.services.adapters.zenoh_bus import (
    BusError,
    BusOptions,
    Inbox,
    configure_logging,
    open_session,
    stop_on_signals,
)
from railswitch.services.adapters.recordings import RecordingPathError, check_writable
from railswitch.services.core.intake import Intake
from railswitch.services.adapters.processes import ServiceProcesses, free_loopback_endpoint, wait_ready
from railswitch.services.commands.options import add_model_argument, bounded
from railswitch.services.commands.watch import diagnosis_line, diagnosis_table, health_line, state_markup, to_limit

log = logging.getLogger("railswitch.demo")

DEMO_FAULTS = (  # the paper's four scenarios, and a worn point machine
    {"left_bolt_offset": 0.05},
    {"right_bolt_offset": 0.20},
    {"bearing_friction": 5000.0},
    {"obstacle_friction": 1.0e5, "obstacle_position": 1.10},
    {"drive_friction_nm": 0.1},
)
NOISE = 0.01
INTERVAL_S = 10.0
READY_TIMEOUT_S = 300.0  # a diagnoser on a machine without the compiled-model cache needs a while
DRAIN_TIMEOUT_S = 60.0
HEALTH_SETTLE_S = 1.0  # the health messages published right after the last diagnoses arrive within this


def fault_onset(throws: int) -> int:
    """The throw the demo's faults start at: once the switches are commissioned, when there are throws enough."""
    commissioning = 2 * COMMISSIONING_THROWS
    return commissioning if throws > commissioning else throws // 2


def demo_scenario(switches: int, throws: int) -> str:
    """TOML for `railswitch simulator --scenario`: switches drawn from the population, 1 % noise, healthy until
    fault_onset, then fault mode k mod 5."""
    lines = [f"interval_s = {INTERVAL_S}", f"noise = {NOISE}", ""]
    for k in range(switches):
        faults = DEMO_FAULTS[k % len(DEMO_FAULTS)]
        values = ", ".join(f"{name} = {value!r}" for name, value in faults.items())
        lines += ["[[switches]]", f'id = "sw{k + 1}"', f"throws = {throws}", f"vary = {k + 1}", "",
                  "[[switches.changes]]", f"throw = {fault_onset(throws)}", f"set = {{ {values} }}", ""]
    return "\n".join(lines)


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
    health: dict[str, SwitchHealth] = field(default_factory=dict)  # each switch's latest

    def take(self, message: Diagnosis | SwitchHealth | FaultTruth, latest: dict[str, Diagnosis]) -> bool:
        """Keep a message; whether it is one to show (a diagnosis or health message)."""
        if isinstance(message, FaultTruth):
            self.truths.setdefault(message.switch_id, []).append(message)
            return False
        if isinstance(message, SwitchHealth):
            self.health[message.switch_id] = message
        else:
            self.diagnoses.append(message)
            latest[message.switch_id] = message
        return True

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
            decided = "+".join(d.faults) if d.faults else d.decision  # every present fault
            ok = set(decided.split("+")) == set(want.split("+"))
            correct += ok
            table.add_row(d.switch_id, str(d.throw_index), d.direction, "+".join(self.injected(d)) or "none", want,
                          decided, "[green]✓[/]" if ok else "[red]✗[/]")
        return table, correct

    def health_table(self) -> Table:
        """Each switch's health after its last throw: state, and its worst parameter's level and throws to limit."""
        table = Table(title="health of each switch after its last throw")
        for column in ("switch", "throw", "state", "worst parameter level", "worst: throws to limit"):
            table.add_column(column)
        for switch_id, health in sorted(self.health.items()):
            worst = next((p for p in health.parameters if p.name == health.worst), None)
            level = "" if worst is None else (
                f"{worst.level:.4g}" + ("" if worst.level_std is None else f" ± {worst.level_std:.2g}")
                + f" {FAULT_PARAMETERS[worst.name].unit} (limit {worst.limit:g})")
            table.add_row(switch_id, str(health.throw_index), state_markup(health.state), level, to_limit(health))
        return table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--switches", type=bounded(int, 1, 50), default=5)
    parser.add_argument("--throws", type=bounded(int, 2, 1000), default=12,
                        help="throws per switch (the first 8 commission it, when there are more)")
    parser.add_argument("--speed", type=bounded(float, 0.1, 1000.0, "x real time"), default=2.0)
    parser.add_argument("--out", default="demo.mcap", metavar="F.mcap",
                        help="the recording; the history file goes next to it (F.sqlite)")
    parser.add_argument("--listen", default=None, metavar="ENDPOINT",
                        help="endpoint of the embedded router (default: a free loopback port)")
    add_model_argument(parser)


def run(args: argparse.Namespace) -> int:
    configure_logging(False)
    console = Console()
    try:
        out = check_writable(args.out)
    except RecordingPathError as error:
        print(f"railswitch: error: {error}", file=sys.stderr)
        return 2
    history = fresh_history_file(out)
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
        processes = ServiceProcesses(scratch_dir, own_session=True)
        outcome = Outcome()
        try:
            inbox = Inbox(router, ["railswitch/*/diagnosis", "railswitch/*/health", "railswitch/*/truth"])
            console.print(f"router on {listen}; starting diagnoser ({args.model}), recorder ({out}) "
                          f"and historian ({history})")
            processes.start("diagnoser", "--connect", connect, "--model", args.model,
                            "--state", str(scratch_dir / "baselines"))  # each demo commissions its switches afresh
            processes.start("recorder", "--connect", connect, "--out", str(out))
            processes.start("historian", "--connect", connect, "--db", str(history))
            wait_ready(router, processes, READY_TIMEOUT_S, stop=stop, diagnoser=1, recorder=1, historian=1)
            if not stop.is_set():
                console.print(f"simulating {args.switches} switches x {args.throws} throws "
                              f"at {args.speed:g}x real time")
                simulator = processes.start("simulator", "--connect", connect, "--scenario", str(scenario),
                                            "--speed", str(args.speed))
                _follow(inbox, outcome, console, simulator, args.switches * args.throws, stop)
                if simulator.returncode:
                    raise RuntimeError(f"simulator failed:\n{processes.log(simulator, 8)}")
        except (RuntimeError, TimeoutError) as error:
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
        console.print(outcome.health_table())
        console.print(f"recording: {out.resolve()}", soft_wrap=True)
        console.print(f"history: {history.resolve()} (railswitch history sw1 --db {history})", highlight=False,
                      soft_wrap=True)
        if failures := processes.failures():
            print(f"railswitch demo: {failures}", file=sys.stderr)
        if any(processes.name(p) == "recorder" for p in processes.failed()):
            return 1  # a recorder that crashed or was killed may have left its file unfinished; a historian's rows
            # are committed batch by batch, so its file is whole however it ended
        return 130 if stop.is_set() else 0


def fresh_history_file(recording: Path) -> Path:
    """The demo's history file next to its recording, emptied: each demo starts its history afresh."""
    history = recording.with_suffix(".sqlite")
    if history == recording:  # --out x.sqlite: the recorder's file is not the historian's
        history = recording.with_name(f"{recording.name}.history.sqlite")
    for leftover in (history, Path(f"{history}-wal"), Path(f"{history}-shm")):
        leftover.unlink(missing_ok=True)
    return history


def _follow(inbox: Inbox, outcome: Outcome, console: Console, simulator: subprocess.Popen, expected: int,
            stop: threading.Event) -> None:
    """Show diagnoses and health as they come, until every throw has a diagnosis (or the simulator failed, or
    stop); then a moment more for the health messages that follow the last diagnoses."""
    latest: dict[str, Diagnosis] = {}
    intake = Intake(log, kinds=("diagnosis", "health", "truth"))
    drain_deadline = settled = None
    live = console.is_terminal
    with Live(diagnosis_table(latest), console=console, auto_refresh=False) if live else nullcontext() as table:
        while not stop.is_set() and (settled is None or time.monotonic() < settled):
            if len(outcome.diagnoses) >= expected:
                settled = settled or time.monotonic() + HEALTH_SETTLE_S
            if simulator.poll() is not None:
                if simulator.returncode != 0:
                    return
                drain_deadline = drain_deadline or time.monotonic() + DRAIN_TIMEOUT_S
                if time.monotonic() > drain_deadline:
                    break
            item = inbox.get(0.2)
            message = None if item is None else intake.message(item)
            if message is None or not outcome.take(message, latest):
                continue
            if live:
                table.update(diagnosis_table(latest, outcome.health), refresh=True)
            else:
                console.print(diagnosis_line(message) if isinstance(message, Diagnosis) else health_line(message),
                              highlight=False)
