"""Which live instance of a service serves a switch: rendezvous (highest-random-weight) hashing over the live set.

Every instance computes the same owner from the same live set with no coordinator, and when one joins or leaves
only the switches it gains or held move (Thaler and Ravishankar, "Using name-based mappings to increase hit
rates", IEEE/ACM Trans. Networking 6(1), 1998). The live set comes from Zenoh liveliness
(services/adapters/zenoh_bus.py LiveSet); this module is pure, so the diagnoser and the historian share it and it
is tested without a bus.
"""
from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable


def weight(member: str, key: str) -> int:
    """A 64-bit pseudo-random weight of (member, key), the same in every process and on every machine (BLAKE2b,
    not Python's salted hash)."""
    return int.from_bytes(hashlib.blake2b(f"{member}\x00{key}".encode(), digest_size=8).digest(), "big")


def rendezvous_owner(key: str, members: Iterable[str]) -> str | None:
    """The member of highest weight for key (ties, astronomically rare, to the greater name); None without members."""
    return max(members, key=lambda member: (weight(member, key), member), default=None)


class Membership:
    """The live instances of a service as this one sees them, each with when it joined, and who owns a switch.

    A member owns the throws that started after it joined (as seen here): one that joined mid-throw has not seen
    the throw's start, so the throw stays with those that were there. A throw no live member was there for (this
    instance started alone, or all of them left) goes to the live set as a whole. This instance also keeps a throw
    that reached it before it joined if its switch is its own now: the others may have seen its token before the
    throw (each judges by its own arrival times), and would then leave the throw to it. Times are local monotonic
    seconds; members found present on start-up joined at -inf.
    """

    def __init__(self, me: str):
        self.me = me
        self.joined: dict[str, float] = {}
        # The live set and each switch's owner over it, replaced whole on a change: another thread (a historian's
        # queries) may ask owner() while this one's changes the set, and reads one set and its own owners.
        self._view: tuple[frozenset[str], dict[str, str | None]] = (frozenset(), {})
        self._last_join = -math.inf

    @property
    def members(self) -> frozenset[str]:
        return self._view[0]

    def join(self, member: str, at_s: float = -math.inf) -> bool:
        """Add a member (the earlier time wins for one already known); whether the live set changed."""
        known = member in self.joined
        self.joined[member] = min(at_s, self.joined.get(member, math.inf))
        if not known:
            self._changed()
        return not known

    def leave(self, member: str) -> bool:
        """Remove a member; whether the live set changed. This instance never leaves its own set: it runs, so it is
        live, and its own token seen gone means it is cut off from the bus (a router restarting, say). Leaving
        would make a lone instance the owner of nothing, and the throws that reach it meanwhile would go to no one;
        the others take its switches either way."""
        if member == self.me or self.joined.pop(member, None) is None:
            return False
        self._changed()
        return True

    def _changed(self) -> None:
        self._view = (frozenset(self.joined), {})
        self._last_join = max(self.joined.values(), default=-math.inf)

    def owner(self, switch_id: str, since_s: float | None = None) -> str | None:
        """The member serving switch_id; with since_s (when a throw started here), among those that had joined by
        then, if any had."""
        if since_s is None or since_s >= self._last_join:
            live, owners = self._view
            if switch_id not in owners:
                owners[switch_id] = rendezvous_owner(switch_id, live)
            return owners[switch_id]
        there = [member for member, at_s in self.joined.items() if at_s <= since_s]
        if there and self.me not in there and self.owner(switch_id) == self.me:
            return self.me  # diagnosed twice at worst, by the owner of then as well
        return rendezvous_owner(switch_id, there or self.joined)

    def is_mine(self, switch_id: str) -> bool:
        """Whether this instance serves switch_id now (the historian's and the diagnoser's "is mine")."""
        return self.owner(switch_id) == self.me

    def serves(self, switch_id: str) -> bool:
        """Every switch's stream is read: ownership can move to this instance at any throw."""
        return True
