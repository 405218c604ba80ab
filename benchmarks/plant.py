"""Wall time of the high-fidelity plant over two throws (14 s simulated) on one core.

The plant's equations and their Jacobian run as machine code (services/adapters/compiled.py); the same
plant through CasADi's virtual machine is timed beside it, with the largest difference between the two.

Its fidelity: the RMS difference over each throw of the example recordings (made by the plant as it was when
they were recorded) from the faults each recording names run now, against the bound the recordings' check
allows for the solver (services/core/recording_check.py: 200 times the relative tolerance times the signal's
nominal peak).

Also times scipy's BDF on the same equations, given the same exact sparse
Jacobian, to justify CVODES as the plant's integrator.

`fleet_realtime_factor`: the same over switches of the population (each its own build and weather), four in
five with a fault drawn as benchmarks.diagnosis draws them, two throws each. CVODES's steps over one pair of
throws move by up to a fifth either way with a rounding anywhere (the error test near the contacts decides
them), so the nominal pair is one draw; this is the figure over many, with the slowest tenth's.
"""
from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.integrate import solve_ivp

from benchmarks.common import emit, parser, pin_to_one_core
from benchmarks.diagnosis import draw_cases
from railswitch.models.plant.faults import fault_vector
from railswitch.models.plant.high_fidelity import Plant
from railswitch.models.plant.population import draw_switch
from railswitch.models.plant.reference import THROW_DURATION_S, throw_reference
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.adapters.recordings import RecordingReader
from railswitch.services.core.recording_check import SIGNALS, rms_bound, rms_differences
from railswitch.services.core.throw_cutter import cut_throws

SIM_SECONDS = 2 * THROW_DURATION_S
RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"


def two_throws(plant: Plant) -> tuple[float, np.ndarray, np.ndarray]:
    """Wall time of two throws, their rail positions and their motor currents."""
    sim = SwitchSimulation(plant)
    start = time.perf_counter()
    throws = [sim.throw() for _ in range(2)]
    wall = time.perf_counter() - start
    return (wall, np.concatenate([t.samples.rail_position_m for t in throws]),
            np.concatenate([t.samples.signals.current_a for t in throws]))


def median_wall(plant: Plant, runs: int = 5) -> float:
    """Median wall time of two throws over `runs` runs (the integrators already built)."""
    return statistics.median([two_throws(plant)[0] for _ in range(runs)])


def fleet_realtime(plant: Plant, seed: int = 1, per_mode: int = 4, nominal: int = 4) -> dict:
    """Real-time factor over two throws of each of 5 * per_mode + nominal population switches (switch seed 1000 + k),
    faulty ones as benchmarks.diagnosis draws them (matrix seed `seed`): over all of them, and their tenth
    percentile (the slow switches)."""
    walls = []
    for k, (_, faults) in enumerate(draw_cases(seed, per_mode, nominal)):
        sim = SwitchSimulation(plant, faults=faults, own=draw_switch(1000 + k).plant)  # settling is not timed
        start = time.perf_counter()
        for _ in range(2):
            sim.throw()
        walls.append(time.perf_counter() - start)
    factors = SIM_SECONDS / np.array(walls)
    return {"switches": len(walls), "realtime_factor": round(SIM_SECONDS * len(walls) / sum(walls), 1),
            "p10_realtime_factor": round(float(np.percentile(factors, 10)), 1)}


def scipy_bdf_two_throws(plant: Plant) -> tuple[float, np.ndarray]:
    """The same two throws with scipy's BDF, CasADi-evaluated right-hand side and Jacobian."""
    f = plant.ode_function()
    sim = SwitchSimulation(plant)
    state, fault = sim.state, np.concatenate([fault_vector(), plant.variables()])
    rails = []
    start = time.perf_counter()
    for direction in ("left_to_right", "right_to_left"):
        reference = throw_reference(direction)
        state = plant.start_throw(state)

        def control(t):
            return np.array([reference(t), 0.0, 1.0])

        def rhs(t, x):
            return np.asarray(f(t, x, fault, control(t))[0]).ravel()

        def jac(t, x):
            return sp.csc_matrix(f(t, x, fault, control(t))[1])

        grid = np.arange(1, 351) / 50.0
        solution = solve_ivp(rhs, (0.0, THROW_DURATION_S), state, method="BDF", jac=jac, t_eval=grid,
                             rtol=1e-6, atol=1e-7)
        state = solution.y[:, -1]
        rails.append(plant.params.rail.neutral_m + solution.y[plant.nodes - 1])
    return time.perf_counter() - start, np.concatenate(rails)


def against_recordings(plant: Plant) -> dict:
    """The largest RMS difference over a throw between each example recording and the faults it names run now,
    per signal, as a share of the bound the recordings' check allows for the solver."""
    bound = rms_bound(plant)
    worst = dict.fromkeys(SIGNALS, 0.0)
    for path in sorted(RECORDINGS.glob("*.mcap")):
        recorded = list(cut_throws(m.message for m in RecordingReader(path)))
        for differences in rms_differences(recorded, plant, recorded[0].truth.params()):
            worst = {s: max(worst[s], differences[s]) for s in SIGNALS}
    return {"rms": worst, "bound": bound, "share_of_bound": {s: round(worst[s] / bound[s], 4) for s in SIGNALS}}


def main() -> None:
    args = parser(__doc__).parse_args()
    core = pin_to_one_core()
    start = time.perf_counter()
    plant = compiled_plant()  # machine code from this machine's cache (compiled on its first run)
    first, reference_rails, currents = two_throws(plant)  # includes building the CVODES integrator
    build = time.perf_counter() - start - first
    wall = median_wall(plant)
    fleet = fleet_realtime(plant)
    plain = Plant()  # the same equations through CasADi's virtual machine
    _, plain_rails, plain_currents = two_throws(plain)  # its first run builds its integrator, as above
    plain_wall = median_wall(plain)
    scipy_wall, scipy_rails = scipy_bdf_two_throws(plant)
    stats = plant.describe()
    fidelity = against_recordings(plant)
    emit({
        "states": stats["states"],
        "rail_nodes": stats["rail_nodes"],
        "sim_seconds": SIM_SECONDS,
        "wall_seconds": round(wall, 4),
        "realtime_factor": round(SIM_SECONDS / wall, 1),
        "fleet_realtime_factor": fleet,
        "first_run_wall_seconds": round(first, 4),
        "build_seconds": round(build, 3),
        "solver": "cvodes",
        "machine_code": stats["machine_code"],
        "plain_realtime_factor": round(SIM_SECONDS / plain_wall, 1),
        "machine_code_vs_plain_max_diff": {"rail_m": float(np.max(np.abs(reference_rails - plain_rails))),
                                           "current_a": float(np.max(np.abs(currents - plain_currents)))},
        "vs_recordings_max_rms": fidelity["rms"],
        "vs_recordings_share_of_bound": fidelity["share_of_bound"],
        "scipy_bdf_wall_seconds": round(scipy_wall, 3),
        "scipy_bdf_realtime_factor": round(SIM_SECONDS / scipy_wall, 2),
        "scipy_vs_cvodes_max_rail_diff_m": float(np.max(np.abs(scipy_rails - reference_rails))),
        "core": core,
    }, args.json)


if __name__ == "__main__":
    main()
