"""The recorder's answer to a diagnoser that was not listening: each switch's recent throws cut from its sample stream,
kept as records (docs/contracts.md section 3, Catching up).

A stream's throws are cut as they arrive (services/core/throw_cutter.py); a diagnoser that was down, restarting or
cut off from the router did not hear them, and Zenoh's caches cannot replay them in order (samples and events are two
keys, and a cache sized for ten minutes of samples at 50 Hz would hold 30 000 of them per switch). The recorder
hears every throw anyway: it cuts each switch's stream too and keeps the complete throws that ended within the last
`keep_s` of the switch's own time (at most MAX_KEPT), as the records a unit that cuts its throws itself would upload (records.py
record_of_throw), and answers queries on railswitch/<id>/recent with them. Throws that came as records are left to
their publishers' caches. A throw the recorder did not hear whole (cut short, with lost samples) is not kept: the
diagnoser would only decide it unknown.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Mapping

from railswitch.schemas import Message, MotorSample, ThrowEvent, encode, recent_key
from railswitch.services.core.records import record_of_throw
from railswitch.services.core.throw_cutter import ThrowCutter

MAX_KEPT = 256  # throws per switch at most, whatever its clock says (a switch thrown every few seconds in a test)


class RecentThrows:
    """Each switch's complete throws of the last keep_s seconds of its own time, as encoded records."""

    def __init__(self, keep_s: float, max_kept: int = MAX_KEPT):
        self.keep_ns = int(keep_s * 1e9)
        self.cutter = ThrowCutter()
        self._kept: dict[str, deque[tuple[int, bytes]]] = {}  # switch -> (end ns, record payload), in order
        self._max_kept = max_kept
        self.not_kept = 0  # throws heard incomplete, with lost samples or too long for a record
        self.bad_queries = 0

    def feed(self, message: Message) -> None:
        """A decoded message of the bus; a sample stream's completed throw is kept."""
        if self.keep_ns <= 0 or not isinstance(message, (MotorSample, ThrowEvent)):
            return
        throw = self.cutter.feed(message)
        if throw is None:
            return
        try:
            if not throw.complete or throw.missing_samples or len(throw.t_s) < 2:
                raise ValueError("incomplete")
            record = record_of_throw(throw)
        except ValueError:  # cut short, lost samples, or more than a record holds
            self.not_kept += 1
            return
        kept = self._kept.setdefault(throw.switch_id, deque(maxlen=self._max_kept))
        kept.append((record.t_end_ns, encode(record)))
        while kept and kept[0][0] < record.t_end_ns - self.keep_ns:
            kept.popleft()

    def __len__(self) -> int:
        return sum(len(kept) for kept in self._kept.values())

    def replies(self, parameters: Mapping[str, str]) -> list[tuple[str, bytes]]:
        """(railswitch/<id>/recent, record payload) of every switch's kept throws, each switch's in order; with
        `after_ns`, only those that ended after it (what a diagnoser whose state has seen a switch's throws up to
        then lacks). A query whose after_ns is not a whole number gets nothing and is counted."""
        try:
            after_ns = int(parameters["after_ns"]) if "after_ns" in parameters else None
        except ValueError:
            self.bad_queries += 1
            return []
        return [(recent_key(switch_id), payload) for switch_id, kept in sorted(self._kept.items())
                for end_ns, payload in kept if after_ns is None or end_ns > after_ns]
