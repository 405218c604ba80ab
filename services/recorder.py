"""`railswitch recorder --out F.mcap`: every switch channel on the bus into one MCAP file.

Channels, schemas and log times are those of `railswitch simulate` (DESIGN.md section 5),
plus the diagnosis and inject channels. The file is finished on SIGINT and SIGTERM; chunks
of 32 KiB are pushed to the operating system at least every second, so a killed recorder
loses only the chunk it was filling (a few seconds of one switch, less for a fleet).
"""
from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from pathlib import Path

from schemas import CHANNEL_MODELS, Diagnosis, MessageError, decode, parse_key_expr
from services.bus import SERVICE_PREFIX, BusOptions, Inbox, Received, declare_service, open_session
from services.mcap_io import RecordingWriter

log = logging.getLogger("railswitch.recorder")

FLUSH_S = 1.0


class Recorder:
    """Decodes received payloads and writes the valid ones; counts the rest by reason."""

    def __init__(self, writer: RecordingWriter):
        self.writer = writer
        self.rejected: Counter[str] = Counter()
        self._last_t_ns: dict[str, int] = {}

    def handle(self, item: Received) -> None:
        if item.key.startswith(SERVICE_PREFIX + "/"):
            return  # service status and liveliness are not switch data
        try:
            switch_id, kind = parse_key_expr(item.key)
        except ValueError:
            self._reject("key is not railswitch/<switch_id>/<kind>", item.key)
            return
        try:
            message = decode(CHANNEL_MODELS[kind], item.payload)
        except MessageError as error:
            self._reject(f"{kind}: {error}", item.key)
            return
        if message.switch_id != switch_id:
            self._reject(f"{kind}: switch_id differs from the key", item.key)
            return
        self.writer.write(item.key, message, self._log_time(switch_id, message))

    def _log_time(self, switch_id: str, message) -> int:
        """The message's own time; a diagnosis its throw's end; a command the switch's latest time."""
        if isinstance(message, Diagnosis):
            return message.t_end_ns
        t_ns = getattr(message, "t_ns", None)
        if t_ns is None:
            return self._last_t_ns.get(switch_id, time.time_ns())
        self._last_t_ns[switch_id] = max(t_ns, self._last_t_ns.get(switch_id, 0))
        return t_ns

    def _reject(self, reason: str, key: str) -> None:
        self.rejected[reason] += 1
        if self.rejected[reason] == 1:
            log.warning("rejected a message on %s: %s (further ones are counted)", key, reason)


def output_path(pattern: str) -> Path:
    """--out with `{time}` replaced by the UTC start time, so a restarted recorder never overwrites."""
    return Path(pattern.replace("{time}", time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())))


def run_recorder(options: BusOptions, out: str, *, stop: threading.Event) -> int:
    """Record until stop is set; the file is finished in every case. Returns the messages written."""
    with RecordingWriter(output_path(out), atomic=False) as writer:  # fails here, before connecting, if out is unwritable
        session = open_session(options, stop=stop)
        try:
            inbox = Inbox(session, ["railswitch/**"])
            token = declare_service(session, "recorder")
            recorder = Recorder(writer)
            log.info("recording railswitch/** to %s", writer.path)
            flushed = time.monotonic()
            for item in inbox.drain(stop):
                if item is not None:
                    recorder.handle(item)
                if time.monotonic() - flushed > FLUSH_S:
                    writer.flush()
                    flushed = time.monotonic()
            token.undeclare()
        finally:
            session.close()
        log.info("wrote %d messages to %s; rejected %s", writer.message_count, writer.path,
                 dict(recorder.rejected) or "nothing")
        return writer.message_count
