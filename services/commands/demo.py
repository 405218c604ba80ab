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
from pathlib import Path

from rich.console import Console
from rich.live import Live

from railswitch.schemas import Diagnosis
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
from railswitch.services.core.demo_story import DemoOutcome, connect_endpoint, demo_scenario, fresh_history_file
from railswitch.services.core.tables import diagnosis_line, diagnosis_table, health_line

log = logging.getLogger("railswitch.demo")

READY_TIMEOUT_S = 300.0  # a diagnoser on a machine without the compiled-model cache needs a while
DRAIN_TIMEOUT_S = 60.0
HEALTH_SETTLE_S = 1.0  # the health messages published right after the last diagnoses arrive within this


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
        outcome = DemoOutcome()
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


def _follow(inbox: Inbox, outcome: DemoOutcome, console: Console, simulator: subprocess.Popen, expected: int,
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
