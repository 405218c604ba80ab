"""`railswitch simulator`: simulated switches on the bus, paced in real time or faster.

Each switch computes a whole throw (or idle period) ahead with the high-fidelity plant
and then streams its samples at the sample rate (or, `--as-records`, sends each throw as
one record at its end), so the cost scales with throws, not samples. Switches' throws are
staggered evenly over the interval. FaultCommands on railswitch/<id>/inject act from the
next throw on.
"""
from __future__ import annotations

import argparse
import logging
import math
import threading
import time

from railswitch.models.plant.simulation import RecordedThrow, ReplayedSwitch
from railswitch.schemas import FaultCommand
from railswitch.schemas.scenario import Scenario
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.adapters.recordings import load_recording
from railswitch.services.adapters.zenoh_bus import BusOptions, Inbox, Publishers, StatusReporter, declare_service, open_session
from railswitch.services.commands.options import (
    add_own_arguments,
    add_service_arguments,
    bounded,
    fail,
    fault_assignment,
    run_service,
    scenario_from_args,
    switch_id,
)
from railswitch.services.core.intake import Intake
from railswitch.services.core.simulated_fleet import SwitchStream, recorded_throws, simulation

log = logging.getLogger("railswitch.simulator")

OUTAGE_S = 600.0  # how long every diagnoser may be down without a throw lost, by default (docs/contracts.md)
LEAD_S = 1.0  # samples at rest before the first throw, so subscribers see the switch settled
POLL_S = 0.2  # longest wait between looking at commands


def run_simulator(options: BusOptions, scenario: Scenario, *, speed: float, stop: threading.Event,
                  library: list[RecordedThrow] | None = None, status_s: float = 5.0, as_records: bool = False,
                  outage_s: float = OUTAGE_S) -> int:
    """Stream the scenario's switches until every plan is done or stop is set; returns messages published.

    With a library of recorded throws the switches replay those instead of running the plant. As records, each
    throw goes out as one ThrowRecord at its end and nothing between throws: a fleet costs its throws only; each
    switch's records of the last `outage_s` (simulated) seconds are kept for diagnosers that were down or start late.
    """
    session = open_session(options, stop=stop)
    try:
        publishers = Publishers(session, cached={"record": kept_records(outage_s, scenario.interval_s)})
        inbox = Inbox(session, ["railswitch/*/inject"])
        intake = Intake(log, kinds=("inject",))
        status = StatusReporter(publishers, "simulator", intake, status_s)
        token = declare_service(session, "simulator")
        plant = compiled_plant() if library is None else None
        start_ns = time.time_ns()
        count = len(scenario.switches)
        streams = {}
        for k, plan in enumerate(scenario.switches):
            if plant is None:
                sim = ReplayedSwitch(library, rate_hz=scenario.rate_hz, start_ns=start_ns, first=k)
            else:
                sim = simulation(plant, plan, scenario, k, start_ns)
            streams[plan.id] = SwitchStream.start(plan, sim, interval_s=scenario.interval_s,
                                                  offset_s=LEAD_S + k * scenario.interval_s / count,
                                                  as_records=as_records)
        log.info("simulating %d switch(es) at %g samples/s, %gx real time%s", count, scenario.rate_hz, speed,
                 ", each throw as one record" if as_records else "")
        wall0 = time.monotonic()
        while not stop.is_set():
            t_ns = min((t for stream in streams.values() if (t := stream.next_ns()) is not None), default=None)
            if t_ns is None:
                break  # every plan done
            wait_s = wall0 + (t_ns - start_ns) * 1e-9 / speed - time.monotonic()
            if wait_s > 0:
                stop.wait(min(wait_s, POLL_S))  # records leave long gaps: commands and status go on meanwhile
            else:
                for stream in streams.values():
                    for key, message in stream.due(t_ns):
                        publishers.put(key, message)
            _apply_commands(inbox, intake, streams)
            status.maybe_publish({"published": publishers.published})
        token.undeclare()
        log.info("published %d messages", publishers.published)
        return publishers.published
    finally:
        session.close()


def kept_records(outage_s: float, interval_s: float) -> int:
    """Records per switch that cover an outage of outage_s: its throws in that time, and the one under way."""
    return math.ceil(outage_s / interval_s) + 1


def _apply_commands(inbox: Inbox, intake: Intake, streams: dict[str, SwitchStream]) -> None:
    while (item := inbox.get(0.0)) is not None:
        command = intake.message(item)
        if isinstance(command, FaultCommand) and command.switch_id in streams:
            streams[command.switch_id].command(command)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser, status=True)
    parser.add_argument("--scenario", metavar="F.toml", help="schedule of switches, throws and fault changes")
    parser.add_argument("--switches", type=bounded(int, 1, 10_000), default=None, help="switches sw1 … swN")
    parser.add_argument("--switch-id", type=switch_id, action="append", default=[], help="a switch (repeatable)")
    parser.add_argument("--throws", type=bounded(int, 1, 1_000_000), default=None,
                        help="throws per switch (default: until stopped)")
    parser.add_argument("--interval", type=bounded(float, 7.5, 86_400.0, "s"), default=None,
                        help="simulated seconds between a switch's throw starts (default 10)")
    parser.add_argument("--fault", type=fault_assignment, action="append", default=[], metavar="NAME=VALUE",
                        help="fault injected in every switch from the start (repeatable)")
    add_own_arguments(parser)
    parser.add_argument("--noise", type=bounded(float, 0.0, 0.5), default=None, metavar="REL")
    parser.add_argument("--seed", type=bounded(int, 0, 2**32 - 1), default=0)
    parser.add_argument("--rate", type=bounded(float, 1.0, 1000.0, "samples/s"), default=None,
                        help="samples per second (default 50)")
    parser.add_argument("--speed", type=bounded(float, 0.01, 10_000.0, "x real time"), default=1.0)
    parser.add_argument("--as-records", action="store_true",
                        help="publish each throw as one record (railswitch/<id>/record) at its end, as trackside units "
                             "upload them, instead of samples and events; fault commands then act one throw later")
    parser.add_argument("--outage", type=bounded(float, 0.0, 30 * 86_400.0, "s"), default=OUTAGE_S, metavar="S",
                        help="with --as-records: keep each switch's records of the last S simulated seconds for "
                             f"diagnosers that were down or start late (default {OUTAGE_S:g})")
    parser.add_argument("--throws-from", metavar="F.mcap", default=None,
                        help="stream the recorded throws of F (both directions) instead of running the plant: "
                             "hundreds of switches on one core")


def run(args: argparse.Namespace) -> int:
    library = None
    if args.throws_from:
        try:
            library = recorded_throws(load_recording(args.throws_from).messages)
            ReplayedSwitch(library)  # its own check (a complete throw each way), before connecting
        except OSError as error:
            return fail(f"cannot read {args.throws_from}: {error.strerror}")
        except ValueError as error:
            return fail(f"{args.throws_from}: {error}")
    return run_service(lambda options, stop: run_simulator(options, scenario_from_args(args), speed=args.speed,
                                                           stop=stop, library=library, status_s=args.status_interval,
                                                           as_records=args.as_records, outage_s=args.outage),
                       args)
