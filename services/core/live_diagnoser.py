"""A live diagnoser's core: received samples and events through the intake and throw cutter into the
fleet diagnoser, each Diagnosis published on railswitch/<id>/diagnosis."""
from __future__ import annotations

import logging
import time
from collections.abc import Callable

from railswitch.schemas import CommissionCommand, key_expr
from railswitch.services.adapters.zenoh_bus import Publishers, Received
from railswitch.services.core.fleet_diagnoser import Diagnoser
from railswitch.services.core.intake import Intake
from railswitch.services.core.shards import in_shard
from railswitch.services.core.throw_cutter import ThrowCutter

log = logging.getLogger("railswitch.diagnoser")

INPUT_KINDS = ("motor", "throw", "commission")


class LiveDiagnoser:
    """Feeds received samples and events through the throw cutter into the diagnoser."""

    def __init__(self, diagnoser: Diagnoser, publishers: Publishers, shard: tuple[int, int] = (1, 1),
                 known: Callable[[str], bool] | None = None):
        """`known(switch_id)`: whether a switch has a stored baseline (a commission command for a switch this
        diagnoser has neither seen nor stored is refused)."""
        self.diagnoser = diagnoser
        self.known = known or (lambda switch_id: False)
        self.publishers = publishers
        self.shard = shard
        self.intake = Intake(log, INPUT_KINDS, self._is_mine)
        self.cutter = ThrowCutter(on_problem=lambda switch_id, reason: self.intake.reject(
            reason, key_expr(switch_id, "throw")))
        self.diagnosed = 0
        self.commissions = 0
        self._mine: dict[str, bool] = {}

    def handle(self, item: Received) -> None:
        message = self.intake.message(item)
        if message is None:
            return
        if isinstance(message, CommissionCommand):
            self._commission(message, item.key)
            return
        throw = self.cutter.feed(message)
        if throw is None:
            return
        diagnosed = self.diagnoser.diagnose(throw)
        latency_ms = (time.monotonic() - item.arrived_s) * 1e3  # from the end event's arrival to publication
        diagnosis = diagnosed.diagnosis.model_copy(update={"latency_ms": latency_ms})
        self.publishers.put(key_expr(message.switch_id, "diagnosis"), diagnosis)
        if diagnosed.health is not None:
            self.publishers.put(key_expr(message.switch_id, "health"), diagnosed.health)
        self.diagnosed += 1
        log.info("%s throw %d %s: %s (%.0f ms)%s", message.switch_id, diagnosis.throw_index, diagnosis.direction,
                 diagnosis.decision, latency_ms, f" - {diagnosis.reason}" if diagnosis.reason else "")

    def _commission(self, command: CommissionCommand, key: str) -> None:
        if command.switch_id not in self.diagnoser.switches and not self.known(command.switch_id):
            self.intake.reject("commission: unknown switch", key)
            return
        self.diagnoser.commission(command.switch_id)
        self.commissions += 1
        log.info("%s: commissioning restarted%s", command.switch_id, f" ({command.reason})" if command.reason else "")

    def counters(self) -> dict[str, int]:
        return {"diagnosed": self.diagnosed, "switches": sum(self._mine.values()), "commissions": self.commissions}

    def _is_mine(self, switch_id: str) -> bool:
        mine = self._mine.get(switch_id)
        if mine is None:
            mine = self._mine[switch_id] = in_shard(switch_id, self.shard)
        return mine
