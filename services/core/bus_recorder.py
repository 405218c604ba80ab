"""What the recorder writes: every valid payload on its channel, with the log time of docs/contracts.md
section 4 (the message's own time; a diagnosis or a record its throw's end; a command the switch's latest time), and
the recent throws of each switch's sample stream it keeps for diagnosers that were not listening (recent_throws.py)."""
from __future__ import annotations

import logging
import time

from railswitch.schemas import Diagnosis, ThrowRecord
from railswitch.services.ports import Received, RecordingSink
from railswitch.services.core.intake import Intake
from railswitch.services.core.recent_throws import RecentThrows

log = logging.getLogger("railswitch.recorder")


class Recorder:
    """Decodes received payloads and writes the valid ones as they arrived (fields a newer publisher added
    stay in the file); counts the rest by reason."""

    def __init__(self, writer: RecordingSink, recent: RecentThrows | None = None):
        self.writer = writer
        self.recent = recent
        self.intake = Intake(log)
        self._last_t_ns: dict[str, int] = {}

    def handle(self, item: Received) -> None:
        message = self.intake.message(item)
        if message is not None:
            self.writer.write(item.key, message, self._log_time(message.switch_id, message), payload=item.payload)
            if self.recent is not None:
                self.recent.feed(message)

    def _log_time(self, switch_id: str, message) -> int:
        """The message's own time; a diagnosis or a record its throw's end; a command the switch's latest time."""
        if isinstance(message, Diagnosis):
            return message.t_end_ns
        t_ns = message.t_end_ns if isinstance(message, ThrowRecord) else getattr(message, "t_ns", None)
        if t_ns is None:
            return self._last_t_ns.get(switch_id, time.time_ns())
        self._last_t_ns[switch_id] = max(t_ns, self._last_t_ns.get(switch_id, 0))
        return t_ns
