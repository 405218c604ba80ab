"""Received payloads into messages, for every service that subscribes: key, schema and switch checks.

What fails is counted per reason and logged once per reason, never raised: junk on the bus
must not stop a service or flood its log.
"""
from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Container

from schemas import CHANNEL_MODELS, Message, MessageError, decode, parse_key_expr
from services.bus import SERVICE_PREFIX, Received


class Intake:
    """Decodes what a service subscribed to; `kinds` and `wanted(switch_id)` drop the rest unread."""

    def __init__(self, log: logging.Logger, kinds: Container[str] | None = None,
                 wanted: Callable[[str], bool] | None = None):
        self.log = log
        self.kinds = kinds
        self.wanted = wanted
        self.rejected: Counter[str] = Counter()

    def message(self, item: Received) -> Message | None:
        """The valid message in item, or None (counted when it was junk rather than unwanted)."""
        if item.key.startswith(SERVICE_PREFIX + "/"):
            return None  # service status and liveliness are not switch data
        try:
            switch_id, kind = parse_key_expr(item.key)
        except ValueError:
            return self.reject("key is not railswitch/<switch_id>/<kind>", item.key)
        if (self.kinds is not None and kind not in self.kinds) or (self.wanted and not self.wanted(switch_id)):
            return None
        try:
            message = decode(CHANNEL_MODELS[kind], item.payload)
        except MessageError as error:
            return self.reject(f"{kind}: {error}", item.key)
        if message.switch_id != switch_id:
            return self.reject(f"{kind}: switch_id differs from the key", item.key)
        return message

    def reject(self, reason: str, key: str) -> None:
        self.rejected[reason] += 1
        if self.rejected[reason] == 1:  # one line per kind of junk, not one per message
            self.log.warning("rejected a message on %s: %s (further ones are counted)", key, reason)
