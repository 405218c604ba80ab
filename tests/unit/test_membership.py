"""Elastic shards without a bus: rendezvous hashing over the live set, who owns a throw around a join, and what a
diagnoser holds for a handover (services/core/membership.py, services/core/handover.py)."""
from __future__ import annotations

import gc
import math
import subprocess
import sys
import tracemalloc
from collections import Counter

import numpy as np
import pytest

from railswitch.schemas import Diagnosis, SwitchState, ThrowEvent, decode, encode
from railswitch.services.core.handover import HeldThrow, HeldThrows, StateCache, diagnosis_key, throw_key
from railswitch.services.core.membership import Membership, rendezvous_owner, weight
from railswitch.services.core.throw_cutter import CutThrow
from railswitch.models.plant.signals import MotorSignals

SWITCHES = [f"sw{k}" for k in range(3000)]
MEMBERS = ["vm-1201", "vm-1202", "vm-1203"]


def owners(members: list[str]) -> dict[str, str | None]:
    return {switch: rendezvous_owner(switch, members) for switch in SWITCHES}


def test_the_owner_is_the_same_in_another_process_and_whatever_the_order_of_the_members():
    code = ("from railswitch.services.core.membership import rendezvous_owner as o;"
            f"print(','.join(o(f'sw{{k}}', {MEMBERS!r}) for k in range(50)))")
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert other.split(",") == [rendezvous_owner(f"sw{k}", MEMBERS) for k in range(50)]
    assert owners(MEMBERS) == owners(list(reversed(MEMBERS)))
    assert weight("vm-1201", "sw1") == weight("vm-1201", "sw1") != weight("vm-1202", "sw1")


def test_three_members_each_own_a_third_of_3000_switches():
    counts = Counter(owners(MEMBERS).values())
    # Each switch lands on a member with probability 1/3: binomial std sqrt(3000 * 1/3 * 2/3) = 25.8; 5 std allowed.
    assert set(counts) == set(MEMBERS)
    assert all(abs(n - 1000) <= 5 * 25.8 for n in counts.values()), counts


def test_a_member_joining_takes_only_switches_it_now_owns_and_about_a_quarter():
    before, after = owners(MEMBERS), owners([*MEMBERS, "vm-1204"])
    moved = [s for s in SWITCHES if before[s] != after[s]]
    assert all(after[s] == "vm-1204" for s in moved)
    # A quarter of 3000 each way: binomial std sqrt(3000 * 1/4 * 3/4) = 23.7; 5 std allowed.
    assert abs(len(moved) - 750) <= 5 * 23.7, len(moved)


def test_a_member_leaving_hands_over_only_its_own_switches():
    before, after = owners(MEMBERS), owners(MEMBERS[1:])
    moved = {s for s in SWITCHES if before[s] != after[s]}
    assert moved == {s for s in SWITCHES if before[s] == "vm-1201"}
    assert rendezvous_owner("sw1", []) is None


def test_a_throw_that_started_before_a_member_joined_stays_with_the_members_that_were_there():
    membership = Membership("vm-1201")
    membership.join("vm-1201", -math.inf)
    membership.join("vm-1202", 100.0)
    moved = next(s for s in SWITCHES if rendezvous_owner(s, ["vm-1201", "vm-1202"]) == "vm-1202")
    assert membership.owner(moved, since_s=99.0) == "vm-1201"  # started before vm-1202 joined
    assert membership.owner(moved, since_s=100.0) == "vm-1202"
    assert membership.owner(moved) == "vm-1202" and not membership.is_mine(moved)
    assert membership.leave("vm-1202") and membership.owner(moved) == "vm-1201"
    assert not membership.leave("vm-1202")


def test_a_throw_that_reached_a_member_before_it_joined_is_its_own_if_its_switch_now_is():
    # The others may have seen the newcomer's token before this throw (each judges by its own arrival times) and
    # leave the throw to it, so it keeps it too: diagnosed twice at worst, never not at all.
    membership = Membership("vm-1202")
    membership.join("vm-1201", -math.inf)
    membership.join("vm-1202", 100.0)
    mine = next(s for s in SWITCHES if rendezvous_owner(s, ["vm-1201", "vm-1202"]) == "vm-1202")
    theirs = next(s for s in SWITCHES if rendezvous_owner(s, ["vm-1201", "vm-1202"]) == "vm-1201")
    assert membership.owner(mine, since_s=99.0) == "vm-1202"
    assert membership.owner(theirs, since_s=99.0) == "vm-1201"


def test_a_throw_no_live_member_was_there_for_goes_to_the_live_set():
    membership = Membership("vm-1201")
    membership.join("vm-1201", 50.0)  # started alone, after the throw had started
    assert membership.owner("sw1", since_s=10.0) == "vm-1201"


def test_an_instance_that_sees_its_own_token_go_keeps_serving_its_switches():
    # Its own token seen gone means it is cut off from the router, not dead: a lone diagnoser that left its own set
    # would own nothing and drop every throw until its token came back.
    membership = Membership("vm-1201")
    membership.join("vm-1201", 10.0)
    membership.join("vm-1202", 10.0)
    assert not membership.leave("vm-1201") and membership.members == {"vm-1201", "vm-1202"}
    assert membership.leave("vm-1202") and membership.members == {"vm-1201"}
    assert membership.owner("sw1", since_s=20.0) == "vm-1201" and membership.is_mine("sw1")


def test_joining_twice_keeps_the_earlier_time_and_changes_nothing():
    membership = Membership("vm-1201")
    assert membership.join("vm-1202", 5.0)
    assert not membership.join("vm-1202", 9.0)
    assert membership.joined["vm-1202"] == 5.0


def throw(switch_id: str = "sw1", index: int = 3, t_ns: int = 10**12) -> CutThrow:
    start = ThrowEvent(switch_id=switch_id, throw_index=index, direction="left_to_right", phase="start", t_ns=t_ns,
                       reference_t_s=[0.0, 7.0], reference_velocity_rad_s=[0.0, 0.0])
    zeros = np.zeros(3)
    return CutThrow.of(start, start.model_copy(update={"phase": "end", "t_ns": t_ns + 7 * 10**9}), np.arange(3.0),
                       MotorSignals(zeros, zeros, zeros))


def diagnosis_of(cut: CutThrow) -> Diagnosis:
    return Diagnosis(switch_id=cut.switch_id, throw_index=cut.start.throw_index, direction=cut.start.direction,
                     t_start_ns=cut.start.t_ns, t_end_ns=cut.end.t_ns, model="poly", decision="nominal", latency_ms=1.0)


def test_a_held_throw_is_dropped_when_its_diagnosis_is_seen_and_handed_over_when_its_owner_leaves():
    held = HeldThrows(grace_s=60.0)
    seen, orphan = throw(index=1), throw(index=2)
    held.hold(HeldThrow(seen, "vm-1202", 0.0, 1.0))
    held.hold(HeldThrow(orphan, "vm-1202", 0.0, 1.0))
    held.seen(diagnosis_key(diagnosis_of(seen)), 2.0)
    assert len(held) == 1
    assert held.orphaned(frozenset({"vm-1201", "vm-1202"})) == []
    assert [throw_key(h.throw) for h in held.orphaned(frozenset({"vm-1201"}))] == [throw_key(orphan)]
    assert len(held) == 0


def test_a_diagnosis_seen_before_its_throw_completed_here_means_the_throw_is_not_held():
    held = HeldThrows(grace_s=60.0)
    early = throw()
    held.seen(diagnosis_key(diagnosis_of(early)), 1.0)
    held.hold(HeldThrow(early, "vm-1202", 0.0, 1.5))
    assert len(held) == 0


def test_held_throws_older_than_the_grace_period_are_dropped_and_counted():
    held = HeldThrows(grace_s=60.0)
    held.hold(HeldThrow(throw(index=1), "vm-1202", 0.0, 10.0))
    held.hold(HeldThrow(throw(index=2), "vm-1202", 0.0, 50.0))
    assert held.expire(69.0) == 0
    assert held.expire(71.0) == 1 and len(held) == 1


@pytest.mark.parametrize("kept_t_ns, offered_t_ns, model, kept", [
    (100, 200, "poly", 200),  # a later throw's state replaces
    (200, 100, "poly", 200),  # a late one (a slower diagnoser's) does not
    (200, 200, "poly", 200),  # the same throw's (a commissioning restart) does
    (100, 200, "nn", 100),  # another model's is not this diagnoser's business
])
def test_the_state_cache_keeps_the_latest_state_of_its_own_model(kept_t_ns, offered_t_ns, model, kept):
    cache = StateCache("poly")
    cache.put(SwitchState(switch_id="sw1", model="poly", throw_index=1, t_ns=kept_t_ns, state={"k": 1}))
    cache.put(SwitchState(switch_id="sw1", model=model, throw_index=2, t_ns=offered_t_ns, state={"k": 2}))
    assert cache.get("sw1").t_ns == kept


def test_the_state_cache_keeps_each_state_compact_and_gives_it_back_whole():
    """Every diagnoser caches every switch's state of the bus: kept decoded, a commissioned switch's took 38 kB."""
    rng = np.random.default_rng(0)
    healthy = [{"levels": {"rail.chair_friction_coefficient": float(v), "bearing_friction": float(b)},
                "gains": {"left_bolt": float(g)}, "model_weight": float(w)} for v, b, g, w in rng.random((16, 4))]
    states = [SwitchState(switch_id=f"sw{k}", model="poly", throw_index=k, t_ns=k,
                          state={"baseline": {"needed": 4, "healthy": {"left_to_right": healthy}, "recent": {}},
                                 "health": {"histories": {"bearing_friction": rng.random((64, 3)).tolist()}}})
              for k in range(200)]
    payloads = [encode(state) for state in states]
    cache = StateCache("poly")
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for payload in payloads:
        cache.put(decode(SwitchState, payload))  # as they come off the bus: the cache holds what stays
    gc.collect()
    per_state = (tracemalloc.get_traced_memory()[0] - before) / len(states)
    tracemalloc.stop()
    assert per_state < len(payloads[0]), per_state  # less than its JSON: compressed, not decoded
    assert cache.get("sw7") == states[7] and decode(SwitchState, cache.payload("sw7")) == states[7]
    assert sorted(cache.switch_ids()) == sorted(s.switch_id for s in states)
