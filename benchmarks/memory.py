"""Memory a diagnoser keeps per switch (issue 16: tens of thousands of switches per core).

A fleet diagnoser keeps, for every switch it serves, what the switch's next throws read (ThrowVerdict.kept: warm
starts, the slopes a settled throw borrows, evidence, reports), its baseline and health tracker and, while a fault is
decided, the reports of the fault's throws (the latest TRACKED_THROWS); an elastic diagnoser also caches the latest
SwitchState of every switch on the bus, its own and the others' (services/core/handover.py StateCache).

Measured with tracemalloc (what Python allocates and keeps), in one process, after the estimator and a throwaway
switch warmed every cache:
- per_switch_kb: `--switches` population switches, each commissioned and then thrown `--service` more times, the
  memory kept after them over their number;
- per_faulty_throw_kb: one more switch with a bolt left loose for `--faulty` throws, what each of the second half of
  those throws added (up to TRACKED_THROWS of them; past that, nothing);
- state_cache_kb: the switches' states, decoded off the bus, as the StateCache keeps them, per switch;
- gib_for_30000: a diagnoser serving 30 000 switches (the issue's switches per core), per_switch_kb plus
  state_cache_kb each, in GiB; target (chosen): within 8 GiB, a third of this 24 GiB machine.
"""
from __future__ import annotations

import gc
import tracemalloc
from pathlib import Path

from benchmarks.common import emit, parser, pin_to_one_core
from railswitch.models import switch_diagnosis
from railswitch.models.population import draw_switch
from railswitch.models.switch import SwitchSimulation
from railswitch.models.switch_diagnosis import COMMISSIONING_THROWS
from railswitch.schemas import RAIL_MODELS, SwitchState, decode, encode
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.core.fleet_diagnoser import Diagnoser
from railswitch.services.core.handover import StateCache
from railswitch.services.core.switch_messages import SimulatedThrows

SWITCHES_PER_CORE = 30_000
TARGET_GIB = 8.0


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


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return round(int(line.split()[1]) / 1024, 1)
    return float("nan")


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--model", choices=RAIL_MODELS, default="poly")
    p.add_argument("--switches", type=int, default=16)
    p.add_argument("--service", type=int, default=8, help="healthy throws of each switch after its commissioning")
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

    diagnoser = Diagnoser(args.model)
    diagnoser.warm_up()
    states: dict[str, dict] = {}
    diagnoser.on_state = lambda switch_id, state: states.__setitem__(switch_id, state)
    for throw in warming:
        diagnoser.diagnose(throw)
    del diagnoser.switches["warming"], states["warming"]

    tracemalloc.start()
    start = traced()
    for throws in fleet:
        for throw in throws:
            diagnoser.diagnose(throw)
    per_switch = (traced() - start) / args.switches
    half = commissioning + args.faulty // 2
    for throw in loose[:half]:
        diagnoser.diagnose(throw)
    middle = traced()
    for throw in loose[half:]:
        outcome = diagnoser.diagnose(throw)
    per_faulty_throw = (traced() - middle) / (len(loose) - half)

    payloads = [encode(SwitchState(switch_id=switch_id, model=args.model, throw_index=k, t_ns=k, state=state))
                for k, (switch_id, state) in enumerate(states.items())]
    cache = StateCache(args.model)
    before = traced()
    for payload in payloads:
        cache.put(decode(SwitchState, payload))  # as it comes off the bus
    per_state = (traced() - before) / len(payloads)
    tracemalloc.stop()

    kb = 1024.0
    gib = SWITCHES_PER_CORE * (per_switch + per_state) / 2**30
    tracked = getattr(switch_diagnosis, "TRACKED_THROWS", None)
    result = {"per_switch_kb": round(per_switch / kb, 1), "per_faulty_throw_kb": round(per_faulty_throw / kb, 2),
              "tracked_throws": tracked, "state_cache_kb": round(per_state / kb, 1),
              "gib_for_30000": round(gib, 2), "target_gib": TARGET_GIB, "met": gib <= TARGET_GIB,
              "faulty_decision": outcome.diagnosis.decision, "switches": args.switches,
              "throws_per_switch": commissioning + args.service, "faulty_throws": args.faulty,
              "peak_rss_mb": rss_mb(), "model": args.model, "core": core}
    emit(result, args.json)


if __name__ == "__main__":
    main()
