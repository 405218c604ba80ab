"""Received payloads into messages, for every service that subscribes: size, key, schema,
switch, 64-bit and sample-order checks.

What fails is counted per reason and logged once per reason, never raised: junk on the bus
must not stop a service or flood its log. What a newer publisher added (fields, a newer contract)
is read past, counted per name and logged once per name (docs/contracts.md, "Changing the contract").
"""
from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Container
from functools import cache

from railswitch.schemas import (CHANNEL_MODELS, Counted, Message, MessageError, MotorSample, ThrowRecord,
                               decode_counted, parse_key_expr)
from railswitch.schemas import SERVICE_PREFIX
from railswitch.services.ports import Received

MAX_PAYLOAD_BYTES = 1 << 20  # a throw event with the longest reference profile is under 0.5 MiB
# A record of MAX_RECORD_SAMPLES samples with three signals and the longest profile is under 2.5 MiB as JSON.
MAX_PAYLOAD_BYTES_OF = {"record": 4 << 20}
RESYNC_AFTER = {"motor": 50, "record": 3}  # in a row behind a switch's clock before following the new clock
MAX_INT64 = 2**63 - 1  # times (ns: up to the year 2262) and counters beyond it fit no array, file or database
COUNTS = ("t_ns", "t_start_ns", "t_end_ns", "throw_index", "seq")  # a record's offsets are within its times


@cache
def counts_of(model_cls: type[Message]) -> tuple[str, ...]:
    """The COUNTS a kind of message has (asking a pydantic model for a field it lacks costs more than its check)."""
    return tuple(name for name in COUNTS if name in model_cls.model_fields)


class Intake:
    """Decodes what a service subscribed to; `kinds` and `wanted(switch_id)` drop the rest unread."""

    def __init__(self, log: logging.Logger, kinds: Container[str] | None = None,
                 wanted: Callable[[str], bool] | None = None):
        self.log = log
        self.kinds = kinds
        self.wanted = wanted
        self.rejected: Counter[str] = Counter()
        self.ignored: Counter[str] = Counter()  # what accepted payloads held that this version does not know
        self.received = 0
        self._clock: dict[tuple[str, str], int] = {}  # latest sample (and record) time per kind and switch
        self._behind: Counter[tuple[str, str]] = Counter()

    def message(self, item: Received) -> Message | None:
        """The valid message in item, or None (counted when it was junk rather than unwanted)."""
        read = self.read(item)
        return None if read is None else read.message

    def read(self, item: Received) -> Counted | None:
        """The valid message in item with its encoding, or None (counted when it was junk rather than unwanted)."""
        if item.key.startswith(SERVICE_PREFIX + "/"):
            return None  # service status and liveliness are not switch data
        self.received += 1
        try:
            switch_id, kind = parse_key_expr(item.key)
        except ValueError:
            return self.reject("key is not railswitch/<switch_id>/<kind>", item.key)
        if (self.kinds is not None and kind not in self.kinds) or (self.wanted and not self.wanted(switch_id)):
            return None
        limit = MAX_PAYLOAD_BYTES_OF.get(kind, MAX_PAYLOAD_BYTES)
        if len(item.payload) > limit:
            return self.reject(f"{kind}: payload over {limit >> 20} MiB", item.key)
        try:
            read = decode_counted(CHANNEL_MODELS[kind], item.payload)
        except MessageError as error:
            return self.reject(f"{kind}: {error}", item.key)
        message = read.message
        if message.switch_id != switch_id:
            return self.reject(f"{kind}: switch_id differs from the key", item.key)
        if any((getattr(message, name) or 0) > MAX_INT64 for name in counts_of(type(message))):
            return self.reject(f"{kind}: time or throw index beyond 64 bits", item.key)
        if isinstance(message, MotorSample) and not self._in_order("motor", switch_id, message.t_ns):
            return self.reject("motor: time not after the previous sample's (repeated or going back)", item.key)
        if isinstance(message, ThrowRecord) and not self._in_order("record", switch_id, message.t_start_ns):
            return self.reject("record: start not after the previous record's (repeated or going back)", item.key)
        for name in read.unknown:  # a newer publisher's: read past, counted per name
            self._count_once(self.ignored, f"{kind}: {name}", item.key,
                             "ignoring what this version does not know on %s: %s (further ones are counted)")
        return read

    def _in_order(self, kind: str, switch_id: str, t_ns: int) -> bool:
        """Sample (and record) times of a switch only go forward: a repeated record is a unit's retried upload.
        After RESYNC_AFTER[kind] in a row behind, the switch's clock is followed instead: a restarted source, or
        one bad time from the future."""
        clock = (kind, switch_id)
        latest = self._clock.get(clock)
        if latest is None or t_ns > latest:
            self._clock[clock] = t_ns
            self._behind[clock] = 0
            return True
        self._behind[clock] += 1
        if self._behind[clock] >= RESYNC_AFTER[kind]:
            self.log.warning("%s: %d %s messages in a row behind its clock; following the new clock",
                             switch_id, RESYNC_AFTER[kind], kind)
            self._clock[clock] = t_ns
            self._behind[clock] = 0
            return True
        return False

    def reject(self, reason: str, key: str) -> None:
        self._count_once(self.rejected, reason, key, "rejected a message on %s: %s (further ones are counted)")

    def _count_once(self, counter: Counter[str], name: str, key: str, text: str) -> None:
        """Count name; log text (key, name) the first time only: one line per kind of junk or newer field,
        not one per message."""
        counter[name] += 1
        if counter[name] == 1:
            self.log.warning(text, key, name)
