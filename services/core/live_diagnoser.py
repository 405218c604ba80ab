"""A live diagnoser's core: received samples and events through the intake and throw cutter into the
fleet diagnoser, each Diagnosis published on railswitch/<id>/diagnosis."""
from __future__ import annotations

import logging
import time

from railswitch.schemas import key_expr
from railswitch.services.adapters.zenoh_bus import Publishers, Received
from railswitch.services.core.fleet_diagnoser import Diagnoser
from railswitch.services.core.intake import Intake
from railswitch.services.core.shards import in_shard
from railswitch.services.core.throw_cutter import ThrowCutter

log = logging.getLogger("railswitch.diagnoser")

INPUT_KINDS = ("motor", "throw")


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
