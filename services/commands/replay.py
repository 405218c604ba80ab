"""`railswitch replay F.mcap`: republish a recording with its original timing, faster, or at once.

By default the plant's side is replayed (motor, throw, truth and record), so a fresh diagnoser
sees what a live one saw; `--with-diagnosis` adds the recorded diagnoses. Each loop
shifts times, sample numbers and throw numbers past the previous pass, so subscribers
see one continuous switch rather than time going backwards.
"""
from __future__ import annotations

import argparse
import logging
import sys
import threading
import time

from railswitch.services.adapters.csv_throws import CsvInputError, load_throws
from railswitch.services.adapters.zenoh_bus import BusOptions, Publishers, declare_service, open_session
from railswitch.services.commands.options import add_service_arguments, bounded, fail, run_service
from railswitch.services.core.replay_plan import PLANT_KINDS, ReplayPlan

log = logging.getLogger("railswitch.replay")


def run_replay(options: BusOptions, plan: ReplayPlan, *, speed: float | None, loops: int,
               stop: threading.Event) -> int:
    """Publish the plan; speed None is as fast as possible. Returns the messages published."""
    session = open_session(options, stop=stop)
    try:
        publishers = Publishers(session)
        token = declare_service(session, "replay")
        wall0 = time.monotonic()
        t0 = plan.records[0].log_time_ns if plan.records else 0
        for log_time_ns, key, message in plan.passes(loops):
            if stop.is_set():
                break
            if speed is not None:
                delay = wall0 + (log_time_ns - t0) * 1e-9 / speed - time.monotonic()
                if delay > 0 and stop.wait(delay):
                    break
            publishers.put(key, message)
        token.undeclare()
        return publishers.published
    finally:
        session.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser)
    parser.add_argument("recording", metavar="F.mcap")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=bounded(float, 0.01, 10_000.0, "x real time"), default=1.0)
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    parser.add_argument("--loop", type=bounded(int, 0, 1_000_000), default=1, metavar="N",
                        help="passes over the recording (0: until stopped)")
    parser.add_argument("--with-diagnosis", action="store_true", help="also republish recorded diagnoses")


def run(args: argparse.Namespace) -> int:
    try:
        recording = load_throws(args.recording)
    except OSError as error:
        return fail(f"cannot read {args.recording}: {error.strerror}")
    except CsvInputError as error:
        return fail(str(error))
    kinds = PLANT_KINDS + (("diagnosis",) if args.with_diagnosis else ())
    plan = ReplayPlan.of(recording.records, kinds)
    note = recording.note()
    if not plan.records:
        print(f"railswitch replay: {args.recording}: {note + '; ' if note else ''}nothing to replay", file=sys.stderr)
        return 1
    if note:
        print(f"railswitch replay: {args.recording}: {note}", file=sys.stderr)
    speed = None if args.fast else args.speed
    return run_service(lambda options, stop: run_replay(options, plan, speed=speed, loops=args.loop, stop=stop), args)
