"""Received payloads into messages, for every service that subscribes: size, key, schema,
switch and sample-order checks.

What fails is counted per reason and logged once per reason, never raised: junk on the bus
must not stop a service or flood its log.
"""
from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Container

from railswitch.schemas import CHANNEL_MODELS, Message, MessageError, MotorSample, decode, parse_key_expr
from railswitch.schemas import SERVICE_PREFIX
from railswitch.services.adapters.zenoh_bus import Received

MAX_PAYLOAD_BYTES = 1 << 20  # a throw event with the longest reference profile is under 0.5 MiB
RESYNC_AFTER = 50  # samples in a row behind a switch's clock before following the new clock


class Intake:
    """Decodes what a service subscribed to; `kinds` and `wanted(switch_id)` drop the rest unread."""

    def __init__(self, log: logging.Logger, kinds: Container[str] | None = None,
                 wanted: Callable[[str], bool] | None = None):
        self.log = log
        self.kinds = kinds
        self.wanted = wanted
        self.rejected: Counter[str] = Counter()
        self.received = 0
        self._clock: dict[str, int] = {}  # latest sample time per switch
        self._behind: Counter[str] = Counter()

    def message(self, item: Received) -> Message | None:
        """The valid message in item, or None (counted when it was junk rather than unwanted)."""
        if item.key.startswith(SERVICE_PREFIX + "/"):
            return None  # service status and liveliness are not switch data
        self.received += 1
        try:
            switch_id, kind = parse_key_expr(item.key)
        except ValueError:
            return self.reject("key is not railswitch/<switch_id>/<kind>", item.key)
        if (self.kinds is not None and kind not in self.kinds) or (self.wanted and not self.wanted(switch_id)):
            return None
        if len(item.payload) > MAX_PAYLOAD_BYTES:
            return self.reject(f"{kind}: payload over {MAX_PAYLOAD_BYTES >> 20} MiB", item.key)
        try:
            message = decode(CHANNEL_MODELS[kind], item.payload)
        except MessageError as error:
            return self.reject(f"{kind}: {error}", item.key)
        if message.switch_id != switch_id:
            return self.reject(f"{kind}: switch_id differs from the key", item.key)
        if isinstance(message, MotorSample) and not self._in_order(message):
            return self.reject("motor: time not after the previous sample's (repeated or going back)", item.key)
        return message

    def _in_order(self, sample: MotorSample) -> bool:
        """Sample times of a switch only go forward. After RESYNC_AFTER samples in a row behind,
        the stream's clock is followed instead: a restarted source, or one bad time from the future."""
        latest = self._clock.get(sample.switch_id)
        if latest is None or sample.t_ns > latest:
            self._clock[sample.switch_id] = sample.t_ns
            self._behind[sample.switch_id] = 0
            return True
        self._behind[sample.switch_id] += 1
        if self._behind[sample.switch_id] >= RESYNC_AFTER:
            self.log.warning("%s: %d samples in a row behind its clock; following the new clock",
                             sample.switch_id, RESYNC_AFTER)
            self._clock[sample.switch_id] = sample.t_ns
            self._behind[sample.switch_id] = 0
            return True
        return False

    def reject(self, reason: str, key: str) -> None:
        self.rejected[reason] += 1
        if self.rejected[reason] == 1:  # one line per kind of junk, not one per message
            self.log.warning("rejected a message on %s: %s (further ones are counted)", key, reason)
