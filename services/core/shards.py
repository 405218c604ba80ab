"""Splitting a fleet between diagnoser (or historian) processes for good: shard K of N by a stable hash of the
switch id; and what every way of splitting it answers (Ownership)."""
from __future__ import annotations

import zlib
from typing import Protocol


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


class Ownership(Protocol):
    """Which instance serves a switch (diagnoses its throws, keeps its history): FixedShard or, elastic, Membership
    (services/core/membership.py)."""

    me: str

    @property
    def members(self) -> frozenset[str]: ...

    def serves(self, switch_id: str) -> bool: ...

    def owner(self, switch_id: str, since_s: float | None = None) -> str | None: ...

    def is_mine(self, switch_id: str) -> bool: ...


class FixedShard:
    """Shard K of N as a diagnoser's ownership (services/core/membership.py Membership is the elastic one): the
    switches of the shard are this instance's for good, the others are not even read."""

    def __init__(self, shard: tuple[int, int], me: str):
        self.shard = shard
        self.me = me
        self.members = frozenset([me])
        self._mine: dict[str, bool] = {}

    def serves(self, switch_id: str) -> bool:
        mine = self._mine.get(switch_id)
        if mine is None:
            mine = self._mine[switch_id] = in_shard(switch_id, self.shard)
        return mine

    def owner(self, switch_id: str, since_s: float | None = None) -> str | None:
        return self.me if self.serves(switch_id) else None

    def is_mine(self, switch_id: str) -> bool:
        return self.serves(switch_id)
