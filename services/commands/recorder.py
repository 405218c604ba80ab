"""`railswitch recorder --out F.mcap`: every switch channel on the bus into one MCAP file.

Channels, schemas and log times are those of `railswitch simulate` (docs/contracts.md section 4),
plus the diagnosis and inject channels. The file is finished on SIGINT and SIGTERM; the
chunk in progress is closed and handed to the operating system every second, so a killed
recorder loses at most about a second, and `railswitch recover` turns what it left into a
complete file. Closing chunks by time rather than by a small size keeps the writer's
in-memory chunk index small over long recordings.

The recorder also keeps each switch's sample-stream throws of the last `--keep S` seconds as records and answers
queries on railswitch/<id>/recent with them, for diagnosers that were not listening (docs/contracts.md section 3,
Catching up).
"""
from __future__ import annotations

import argparse
import logging
import shutil
import threading
import time
from pathlib import Path

from railswitch.services.adapters.recordings import RecordingPathError, RecordingWriter
from railswitch.schemas import recent_key
from railswitch.services.adapters.zenoh_bus import (
    BusOptions,
    Inbox,
    Publishers,
    QueryInbox,
    StatusReporter,
    declare_service,
    open_session,
)
from railswitch.services.commands.options import add_service_arguments, bounded, run_service
from railswitch.services.core.bus_recorder import Recorder
from railswitch.services.core.recent_throws import RecentThrows

log = logging.getLogger("railswitch.recorder")

FLUSH_S = 1.0
CHUNK_BYTES = 1 << 20  # a chunk also closes every FLUSH_S, so few chunks (and index entries) even for a fleet
MIN_FREE_BYTES = 64 * 2**20
KEEP_S = 600.0  # the outage a stream's throws are kept for: 10 minutes, as the simulator's record caches


def output_path(pattern: str) -> Path:
    """--out with `{time}` replaced by the UTC start time, so a restarted recorder never overwrites."""
    return Path(pattern.replace("{time}", time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())))


def check_space(path: Path, needed: int = MIN_FREE_BYTES) -> None:
    """A recorder must not find out after an hour that its disk is full."""
    free = shutil.disk_usage(path.parent).free
    if free < needed:
        raise RecordingPathError(f"cannot record to {path}: only {free / 2**20:.0f} MiB free on its disk "
                                 f"(at least {needed / 2**20:.0f} MiB needed)")


def run_recorder(options: BusOptions, out: str, *, stop: threading.Event, status_s: float = 5.0,
                 keep_s: float = KEEP_S) -> int:
    """Record until stop is set; the file is finished in every case. Returns the messages written.

    An unwritable path or a full disk fails here, before connecting.
    """
    path = output_path(out)
    with RecordingWriter(path, atomic=False, chunk_size=CHUNK_BYTES) as writer:
        check_space(writer.path)
        try:
            writer.flush()  # the header reaches the disk now: a full device fails at start
        except OSError as error:
            raise RecordingPathError(f"cannot write recording {path}: {error.strerror}") from None
        session = open_session(options, stop=stop)
        try:
            inbox = Inbox(session, ["railswitch/**"])
            recent = RecentThrows(keep_s)
            queries = QueryInbox(session, recent_key("*"))
            token = declare_service(session, "recorder")
            recorder = Recorder(writer, recent)
            status = StatusReporter(Publishers(session), "recorder", recorder.intake, status_s)
            log.info("recording railswitch/** to %s", writer.path)
            flushed = time.monotonic()

            def counters() -> dict[str, int]:
                return {"written": writer.message_count, "recent_throws": len(recent),
                        "recent_not_kept": recent.not_kept, "recent_bad_queries": recent.bad_queries}

            for item in inbox.drain(stop):
                if item is not None:
                    recorder.handle(item)
                queries.answer(lambda key, parameters: recent.replies(parameters))
                if time.monotonic() - flushed > FLUSH_S:
                    writer.flush()
                    flushed = time.monotonic()
                status.maybe_publish(counters)
            status.maybe_publish(counters(), force=True)
            writer.finish()  # before the session closes, which can take long enough to be killed for
            log.info("wrote %d messages to %s; rejected %s", writer.message_count, writer.path,
                     dict(recorder.intake.rejected) or "nothing")
            token.undeclare()
        finally:
            session.close()
        return writer.message_count


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser, status=True)
    parser.add_argument("--out", required=True, metavar="F.mcap",
                        help="file to write; {time} in the name becomes the UTC start time")
    parser.add_argument("--keep", type=bounded(float, 0.0, 86_400.0, "s"), default=KEEP_S, metavar="S",
                        help="keep each switch's sample-stream throws of the last S seconds (its own time) for "
                             f"diagnosers that were not listening; 0: none (default {KEEP_S:g})")


def run(args: argparse.Namespace) -> int:
    return run_service(lambda options, stop: run_recorder(options, args.out, stop=stop, status_s=args.status_interval,
                                                          keep_s=args.keep), args)
