"""What an elastic diagnoser keeps so that switches move between diagnosers without losing a throw or a state.

Each diagnoser cuts every switch's throws but diagnoses only its own (services/core/membership.py). A completed
throw of another's is held until its Diagnosis is seen on the bus; if its owner leaves the live set first, the new
owner diagnoses it. The latest SwitchState of every switch is cached, so whoever takes a switch over resumes its
baseline and health where the previous owner left them.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass

from railswitch.schemas import Diagnosis, SwitchState, decode, encode
from railswitch.services.core.throw_cutter import CutThrow

# Longer than any owner takes to publish a throw's diagnosis, backlog included (the benchmark's --records run says
# how long that is); a held throw older than this is dropped and counted.
GRACE_S = 60.0

ThrowKey = tuple[str, int, int]  # switch_id, throw_index, start time (ns): one throw, however it reached the bus


def throw_key(throw: CutThrow) -> ThrowKey:
    return throw.switch_id, throw.start.throw_index, throw.start.t_ns


def diagnosis_key(diagnosis: Diagnosis) -> ThrowKey:
    return diagnosis.switch_id, diagnosis.throw_index, diagnosis.t_start_ns


@dataclass(frozen=True)
class HeldThrow:
    """A completed throw of another diagnoser's switch: who owned it, when it started and ended here."""

    throw: CutThrow
    owner: str
    started_s: float  # local monotonic time its start arrived (a record: the record's arrival)
    arrived_s: float  # and its end


class HeldThrows:
    """Throws held until their Diagnosis is seen, or taken over when their owner leaves first.

    A Diagnosis seen before its throw completed here (this diagnoser is behind) is remembered, so that throw is not
    held at all. Both are forgotten after grace_s.
    """

    def __init__(self, grace_s: float = GRACE_S):
        self.grace_s = grace_s
        self._held: dict[ThrowKey, HeldThrow] = {}
        self._seen: dict[ThrowKey, float] = {}  # diagnosed before completing here, when seen

    def __len__(self) -> int:
        return len(self._held)

    def hold(self, held: HeldThrow) -> None:
        key = throw_key(held.throw)
        if self._seen.pop(key, None) is None:
            self._held[key] = held

    def seen(self, key: ThrowKey, now_s: float) -> None:
        """Its owner diagnosed this throw: nothing to take over."""
        if self._held.pop(key, None) is None:
            self._seen[key] = now_s

    def orphaned(self, members: frozenset[str]) -> list[HeldThrow]:
        """The held throws whose owner is no longer a member, in the order they completed; no longer held."""
        keys = [key for key, held in self._held.items() if held.owner not in members]
        return [self._held.pop(key) for key in keys]

    def expire(self, now_s: float) -> int:
        """Forget what is older than grace_s; the number of held throws dropped undiagnosed (as far as seen here)."""
        oldest = now_s - self.grace_s
        self._seen = {key: at_s for key, at_s in self._seen.items() if at_s >= oldest}
        stale = [key for key, held in self._held.items() if held.arrived_s < oldest]
        for key in stale:
            del self._held[key]
        return len(stale)


class StateCache:
    """The latest SwitchState of every switch seen on the bus, of one reduced model: what a diagnoser resumes a
    switch from when it takes it over. Latest is by the throw's end time, so a state that arrives late (a slower
    diagnoser's, around a handover) does not replace a newer one.

    Every diagnoser keeps every switch's of the bus, so each is kept as its JSON compressed (zlib, level 1) and
    decoded when asked for: after 32 throws a switch's state is 3.7 kB so kept, 38 kB decoded (8.9 kB of JSON), for
    0.17 ms a state put (encoded and compressed) and 0.2 ms a state asked for (a switch taken over)."""

    def __init__(self, model: str):
        self.model = model
        self._states: dict[str, tuple[int, bytes]] = {}  # per switch: its state's t_ns, its compressed payload

    def put(self, state: SwitchState) -> bool:
        """Keep state unless it is of another model or older than the one kept; whether it was kept."""
        kept = self._states.get(state.switch_id)
        if state.model != self.model or (kept is not None and state.t_ns < kept[0]):
            return False
        self._states[state.switch_id] = (state.t_ns, zlib.compress(encode(state), 1))
        return True

    def get(self, switch_id: str) -> SwitchState | None:
        return decode(SwitchState, self.payload(switch_id)) if switch_id in self._states else None

    def t_ns(self, switch_id: str) -> int | None:
        """The end of the throw the kept state of a switch follows."""
        kept = self._states.get(switch_id)
        return None if kept is None else kept[0]

    def payload(self, switch_id: str) -> bytes:
        """The kept state of a switch as it goes on the bus."""
        return zlib.decompress(self._states[switch_id][1])

    def forget(self, switch_id: str) -> None:
        self._states.pop(switch_id, None)

    def __contains__(self, switch_id: str) -> bool:
        return switch_id in self._states

    def switch_ids(self) -> list[str]:
        return list(self._states)
