"""`railswitch diagnoser`: diagnoses every finished throw on the bus and publishes a Diagnosis.

Zenoh callbacks only queue payloads; one worker thread decodes, cuts throws per switch
and runs the estimator. `--shard K/N` keeps the switches whose stable hash falls in
shard K, so several diagnoser processes split a fleet between them.
"""
from __future__ import annotations

import logging
import threading
import time
import zlib

from schemas import key_expr
from services.bus import BusOptions, Inbox, Publishers, Received, StatusReporter, declare_service, open_session
from services.diagnosis import Diagnoser
from services.intake import Intake
from services.throw_cutter import ThrowCutter

log = logging.getLogger("railswitch.diagnoser")

INPUT_KINDS = ("motor", "throw")


def parse_shard(text: str) -> tuple[int, int]:
    """'K/N' with 1 <= K <= N <= 1024; ValueError names the value and the range."""
    k, sep, n = text.partition("/")
    try:
        shard, shards = int(k), int(n)
    except ValueError:
        raise ValueError(f"{text!r} is not K/N (shard K of N, e.g. 1/2)") from None
    if not sep or not 1 <= shards <= 1024 or not 1 <= shard <= shards:
        raise ValueError(f"shard {text} is outside the accepted range 1/N … N/N with N in 1 … 1024")
    return shard, shards


def in_shard(switch_id: str, shard: tuple[int, int]) -> bool:
    """Stable across processes and machines (CRC-32 of the id, not Python's salted hash)."""
    k, n = shard
    return zlib.crc32(switch_id.encode()) % n == k - 1


class LiveDiagnoser:
    """Feeds received samples and events through the throw cutter into the diagnoser."""

    def __init__(self, diagnoser: Diagnoser, publishers: Publishers, shard: tuple[int, int] = (1, 1)):
        self.diagnoser = diagnoser
        self.publishers = publishers
        self.shard = shard
        self.intake = Intake(log, INPUT_KINDS, self._is_mine)
        self.cutter = ThrowCutter(on_problem=lambda switch_id, reason: self.intake.reject(
            reason, key_expr(switch_id, "throw")))
        self.diagnosed = 0
        self._mine: dict[str, bool] = {}

    def handle(self, item: Received) -> None:
        message = self.intake.message(item)
        if message is None:
            return
        throw = self.cutter.feed(message)
        if throw is None:
            return
        diagnosis = self.diagnoser.diagnose(throw).diagnosis
        latency_ms = (time.monotonic() - item.arrived_s) * 1e3  # from the end event's arrival to publication
        diagnosis = diagnosis.model_copy(update={"latency_ms": latency_ms})
        self.publishers.put(key_expr(message.switch_id, "diagnosis"), diagnosis)
        self.diagnosed += 1
        log.info("%s throw %d %s: %s (%.0f ms)%s", message.switch_id, diagnosis.throw_index, diagnosis.direction,
                 diagnosis.decision, latency_ms, f" - {diagnosis.reason}" if diagnosis.reason else "")

    def counters(self) -> dict[str, int]:
        return {"diagnosed": self.diagnosed, "switches": sum(self._mine.values())}

    def _is_mine(self, switch_id: str) -> bool:
        mine = self._mine.get(switch_id)
        if mine is None:
            mine = self._mine[switch_id] = in_shard(switch_id, self.shard)
        return mine


def run_diagnoser(options: BusOptions, *, model: str, shard: tuple[int, int], stop: threading.Event,
                  status_s: float = 5.0) -> int:
    """Diagnose until stop is set; returns the number of diagnoses published."""
    session = open_session(options, stop=stop)
    try:
        publishers = Publishers(session)
        inbox = Inbox(session, ["railswitch/*/*"])  # one subscription keeps samples and events in order
        diagnoser = Diagnoser(model)
        started = time.monotonic()
        diagnoser.warm_up()
        log.info("model %s ready in %.1f s; shard %d/%d", model, time.monotonic() - started, *shard)
        live = LiveDiagnoser(diagnoser, publishers, shard)
        token = declare_service(session, "diagnoser")  # declared once ready: waiters know throws will be served
        status = StatusReporter(publishers, "diagnoser", live.intake, status_s)
        for item in inbox.drain(stop):
            if item is not None:
                live.handle(item)
            status.maybe_publish(live.counters())
        status.maybe_publish(live.counters(), force=True)
        token.undeclare()
        log.info("published %d diagnoses; rejected %s", live.diagnosed, dict(live.intake.rejected) or "nothing")
        return live.diagnosed
    finally:
        session.close()
