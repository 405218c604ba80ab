"""Memory a diagnoser keeps per switch (issue 42: 10 000 switches' state in under 1 GiB).

A fleet diagnoser keeps, for every switch it serves, what the switch's next throws read (ThrowVerdict.kept: warm
starts and the slopes a settled throw borrows), its evidence, baseline, health histories and feature trends
and, while a fault is decided, what each of the fault's throws reported (the latest TRACKED_THROWS); an elastic
diagnoser also caches the latest SwitchState of every switch on the bus, its own and the others'
(services/core/handover.py StateCache). A switch's health histories and recent features are bounded but fill over
its first throws in service, so the switches are measured after `--service` throws each, enough to fill them.

Measured with tracemalloc (what Python allocates and keeps), in one process, after the estimator and a throwaway
switch warmed every cache:
- per_switch_kb: `--switches` population switches, each commissioned and then thrown `--service` more times, the
  memory kept after them over their number (less the states this benchmark keeps to fill the StateCache with);
- per_faulty_throw_kb: one more switch with a bolt left loose for `--faulty` throws: what its fault's track keeps of
  each throw (up to TRACKED_THROWS of them; past that, nothing), measured on a copy of the track made under
  tracemalloc (what else such a switch keeps is per_switch_kb's);
- state_cache_kb: the switches' states, decoded off the bus, as the StateCache keeps them, per switch;
- process_mb: the diagnoser process's resident memory once warm, before any switch (it also holds the plant this
  benchmark simulates with: an upper bound);
- gib_for_10000: a diagnoser serving 10 000 switches, FAULTY_SHARE of them with a fault left in place for all of
  TRACKED_THROWS: process_mb, plus per_switch_kb and state_cache_kb each, plus the faulty ones' tracks, in GiB;
  target: under 1 GiB;
- lean: per_switch_kb and gib_for_10000 of a lean diagnoser (`railswitch diagnoser --lean`: it keeps no slopes for
  settled throws to borrow) over the same switches' throws, in the same process.
"""
from __future__ import annotations

import gc
import pickle
import sys
import tracemalloc
from pathlib import Path

from benchmarks.common import emit, parser, pin_to_one_core
from railswitch.models.diagnosis import switch_diagnoser
from railswitch.models.plant.population import draw_switch
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.schemas import RAIL_MODELS, SwitchState, decode, encode
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.handover import StateCache
from railswitch.services.core.switch_messages import SimulatedThrows

SWITCHES = 10_000
FAULTY_SHARE = 0.05  # chosen: one switch in twenty carries a fault nobody has repaired for TRACKED_THROWS throws
TARGET_GIB = 1.0


def simulated(plant, switch_id: str, seed: int, throws: int, own: dict | None = None,
              faults: dict | None = None, healthy: int = 0) -> list:
    """A switch's throws: `healthy` of them before `faults` are set, the rest after."""
    sim = SwitchSimulation(plant, noise_rel=0.01, seed=seed, own=own)
    source = SimulatedThrows(switch_id, sim)
    out = [source.next() for _ in range(healthy)]
    sim.set_faults(faults or {})
    return out + [source.next() for _ in range(throws - healthy)]


def traced() -> int:
    gc.collect()
    return tracemalloc.get_traced_memory()[0]


def rss_mb(field: str = "VmHWM") -> float:
    """The process's peak (VmHWM) or current (VmRSS) resident memory, in MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return round(int(line.split()[1]) / 1024, 1)
    return float("nan")


def ready(diagnoser: Diagnoser, warming: list) -> tuple[Diagnoser, dict[str, bytes]]:
    """The diagnoser with its estimator built and every cache warmed by a throwaway switch, and where it puts each
    switch's latest state as it goes on the bus (what the StateCache reads)."""
    payloads: dict[str, bytes] = {}

    def on_state(switch_id: str, state: dict) -> None:
        payloads[switch_id] = encode(SwitchState(switch_id=switch_id, model=diagnoser.model,
                                                 throw_index=len(payloads), t_ns=len(payloads), state=state))

    diagnoser.warm_up()
    diagnoser.on_state = on_state
    for throw in warming:
        diagnoser.diagnose(throw)
    del diagnoser.switches["warming"], payloads["warming"]
    return diagnoser, payloads


def fleet_memory(diagnoser: Diagnoser, fleet: list[list], payloads: dict[str, bytes]) -> float:
    """What the diagnoser keeps per switch after diagnosing every switch's throws (tracemalloc running), less the
    states the benchmark keeps."""
    start = traced()
    for throws in fleet:
        for throw in throws:
            diagnoser.diagnose(throw)
    kept_payloads = sum(sys.getsizeof(p) for p in payloads.values())  # the benchmark's, not the diagnoser's
    return (traced() - start - kept_payloads) / len(fleet)


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--model", choices=RAIL_MODELS, default="poly")
    p.add_argument("--switches", type=int, default=8)
    p.add_argument("--service", type=int, default=140,
                   help="healthy throws of each switch after its commissioning (enough to fill its histories)")
    p.add_argument("--faulty", type=int, default=60, help="throws of the switch with a loose bolt after commissioning")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    core = pin_to_one_core()
    plant = compiled_plant()
    commissioning = 2 * COMMISSIONING_THROWS
    fleet = [simulated(plant, f"sw{k}", k, commissioning + args.service, draw_switch(args.seed * 1000 + k).plant)
             for k in range(args.switches)]
    loose = simulated(plant, "loose", args.seed, commissioning + args.faulty, faults={"left_bolt_offset": 0.04},
                      healthy=commissioning)
    warming = simulated(plant, "warming", args.seed + 1, commissioning + 2)

    diagnoser, payloads = ready(Diagnoser(args.model), warming)
    gc.collect()
    process = rss_mb("VmRSS")

    tracemalloc.start()
    per_switch = fleet_memory(diagnoser, fleet, payloads)
    for throw in loose:
        outcome = diagnoser.diagnose(throw)
    tracks = [fault.track for fault in diagnoser.switches["loose"].faults.values()]
    pickled = pickle.dumps(tracks)
    before = traced()
    copies = pickle.loads(pickled)  # as many new objects as the tracks hold, measured as they are made
    per_faulty_throw = (traced() - before) / max(sum(len(track) for track in copies), 1)

    cache = StateCache(args.model)
    before = traced()
    for payload in payloads.values():
        cache.put(decode(SwitchState, payload))  # as it comes off the bus
    per_state = (traced() - before) / len(payloads)
    tracemalloc.stop()

    # the same switches' throws through a lean diagnoser (no borrowed slopes), in the same process
    lean, lean_payloads = ready(Diagnoser(args.model, lean=True), warming)
    tracemalloc.start()
    lean_per_switch = fleet_memory(lean, fleet, lean_payloads)
    tracemalloc.stop()

    kb = 1024.0
    tracked = switch_diagnoser.TRACKED_THROWS
    faulty = FAULTY_SHARE * SWITCHES * tracked * per_faulty_throw
    gib = (process * 2**20 + SWITCHES * (per_switch + per_state) + faulty) / 2**30
    lean_gib = (process * 2**20 + SWITCHES * (lean_per_switch + per_state) + faulty) / 2**30
    result = {"per_switch_kb": round(per_switch / kb, 1), "per_faulty_throw_kb": round(per_faulty_throw / kb, 2),
              "tracked_throws": tracked, "state_cache_kb": round(per_state / kb, 1),
              "process_mb": process, "faulty_track_mb": round(tracked * per_faulty_throw / 2**20, 2),
              "gib_for_10000": round(gib, 2), "target_gib": TARGET_GIB, "met": gib <= TARGET_GIB,
              "faulty_decision": outcome.diagnosis.decision, "switches": args.switches,
              "throws_per_switch": commissioning + args.service, "faulty_throws": args.faulty,
              "lean": {"per_switch_kb": round(lean_per_switch / kb, 1), "gib_for_10000": round(lean_gib, 2),
                       "met": lean_gib <= TARGET_GIB},
              "peak_rss_mb": rss_mb(), "model": args.model, "core": core}
    emit(result, args.json)


if __name__ == "__main__":
    main()
