"""What a diagnoser keeps of a switch between throws (issue 16, a fleet of tens of thousands of switches per core): only
what later throws read, and a bounded amount however long a fault stays in place."""
import gc
import tracemalloc

import numpy as np

from railswitch.models.diagnosis import switch_diagnoser
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS, MODE_PARAMETERS, Tracked
from railswitch.services.core.switch_messages import SimulatedThrows


def _arrays(verdict) -> dict[str, int]:
    """Bytes of the arrays a kept verdict holds: residuals, fitted outputs, slopes."""
    sizes = {"residual": 0, "fitted": 0, "slopes": 0}
    for estimate in verdict.estimates.values():
        sizes["residual"] += estimate.residual.nbytes
        if estimate.slopes is not None:
            sizes["slopes"] += estimate.slopes.derivative.nbytes
    sizes["fitted"] = sum(np.asarray(values).nbytes for values in verdict.fitted.values())
    return sizes


def test_a_switch_keeps_only_what_its_next_throws_read_and_a_persisting_fault_adds_little(diagnoser, plant,
                                                                                         monkeypatch):
    monkeypatch.setattr(switch_diagnoser, "TRACKED_THROWS", 4)  # read when the switch is first met
    sim = SwitchSimulation(plant, noise_rel=0.01, seed=11)
    source = SimulatedThrows("kept", sim)
    for _ in range(2 * COMMISSIONING_THROWS):
        outcome = diagnoser.diagnose(source.next())
    switch = diagnoser.switches["kept"]
    assert outcome.diagnosis.decision == "nominal"
    for verdict in switch.latest.values():  # healthy: its slopes stay for the next throw to borrow, nothing else
        assert _arrays(verdict)["residual"] == _arrays(verdict)["fitted"] == 0
        assert not verdict.reported and not verdict.evidence  # the switch keeps its own evidence
        assert _arrays(verdict)["slopes"] > 0
        assert verdict.estimates["nominal"].residual.shape[1] == 3  # the signals measured, for the next throw
    assert outcome.verdict.fitted and outcome.verdict.estimates["nominal"].residual.size > 0  # the caller's is whole

    sim.set_faults({"left_bolt_offset": 0.04})
    used = []
    for k in range(8):
        diagnosed = diagnoser.diagnose(source.next())
        if k == 2:
            gc.collect()
            tracemalloc.start()
        elif k > 2:
            gc.collect()
            used.append(tracemalloc.get_traced_memory()[0])
    tracemalloc.stop()
    assert diagnosed.diagnosis.decision == "left_bolt"
    assert diagnosed.diagnosis.faults == ["left_bolt"]
    assert switch.latest["left_to_right"].base == {"left_bolt"}  # fitted with it present; the other direction cannot
    for verdict in switch.latest.values():  # a faulty throw's slopes: no later throw borrows them
        assert _arrays(verdict)["residual"] == _arrays(verdict)["fitted"] == 0
        assert (_arrays(verdict)["slopes"] > 0) == (verdict.mode == "nominal"), verdict.mode
    # the fault's throws are combined over the latest TRACKED_THROWS, each kept as its mode's parameters
    track = switch.faults["left_bolt"].track
    assert len(track) == 4 and all(isinstance(v, Tracked) and len(v.params) == len(MODE_PARAMETERS["left_bolt"])
                                   for v in track)
    assert diagnosed.diagnosis.estimate.since_throw == track[0].index
    # a throw kept whole held over 100 kB: what each adds is a small part of that (benchmarks.memory)
    assert (used[-1] - used[0]) / (len(used) - 1) < 20_000, np.diff(used)


def test_a_lean_diagnoser_keeps_no_slopes_and_diagnoses_alike(diagnoser, plant, monkeypatch):
    """`railswitch diagnoser --lean`: a switch keeps no slopes for its settled throws to borrow (they compute theirs
    afresh), and a fault is found as it is without."""
    monkeypatch.setattr(diagnoser, "lean", True)  # read when the switch is first met
    sim = SwitchSimulation(plant, noise_rel=0.01, seed=12)
    source = SimulatedThrows("lean", sim)
    for _ in range(2 * COMMISSIONING_THROWS + 2):
        outcome = diagnoser.diagnose(source.next())
    assert outcome.diagnosis.decision == "nominal"
    switch = diagnoser.switches["lean"]
    assert switch.lean and all(_arrays(verdict)["slopes"] == 0 for verdict in switch.latest.values())
    sim.set_faults({"left_bolt_offset": 0.05})
    for _ in range(4):
        outcome = diagnoser.diagnose(source.next())
    assert outcome.diagnosis.faults == ["left_bolt"]
    del diagnoser.switches["lean"]


def test_a_diagnosers_own_state_back_from_the_bus_is_not_cached_again_and_a_later_ones_is(diagnoser, plant,
                                                                                           monkeypatch):
    from railswitch.schemas import SwitchState, encode, key_expr
    from railswitch.services.adapters.zenoh_bus import Received
    from railswitch.services.core import handover
    from railswitch.services.core.live_diagnoser import LiveDiagnoser
    from railswitch.services.core.records import record_of_throw

    compressed, compress = [], handover.zlib.compress
    monkeypatch.setattr(handover.zlib, "compress", lambda data, level: compressed.append(data) or compress(data, level))
    live = LiveDiagnoser(diagnoser, publishers=None)
    source = SimulatedThrows("echo", SwitchSimulation(plant, noise_rel=0.01, seed=12))
    live.handle(Received(key_expr("echo", "record"), encode(record_of_throw(source.next())), 0.0))
    assert live.diagnosed == 1 and len(compressed) == 1  # cached as published
    own = live.states.get("echo")
    live.handle(Received(key_expr("echo", "state"), encode(own), 0.0))  # the bus hands it back
    assert len(compressed) == 1 and live.states.get("echo") == own
    later = SwitchState(switch_id="echo", model=own.model, throw_index=own.throw_index + 1, t_ns=own.t_ns + 1,
                        state=own.state)  # another diagnoser's, after a later throw
    live.handle(Received(key_expr("echo", "state"), encode(later), 0.0))
    assert len(compressed) == 2 and live.states.get("echo") == later
    assert "echo" not in diagnoser.switches  # resumed from the later state at its next throw, as before
