"""railswitch's Python API, for a notebook or a script: read throws from a recording or a CSV file, build them from
numpy arrays, simulate them, and diagnose them, with no router and no service. `import railswitch` gives these names
(railswitch/__init__.py loads this module on first use, so importing the package stays light).

    import railswitch
    diagnoser = railswitch.Diagnoser(model="poly")
    for throw in railswitch.read_throws("log.csv"):          # or F.mcap
        result = diagnoser.diagnose(throw)
        print(result.diagnosis.switch_id, result.diagnosis.throw_index, result.diagnosis.faults)

A Diagnoser keeps each switch's state (its commissioning, confirmed faults and health) across the throws it is
given, in order, as the live diagnoser does: give it a switch's throws oldest first. `result` is a DiagnosedThrow:
`.diagnosis` (the Diagnosis message of docs/contracts.md section 3), `.health` (SwitchHealth) and `.alarms`.
"""
from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from railswitch.models.plant.high_fidelity import Plant
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.schemas import CHANNEL_MODELS, HISTORY_KINDS, Message, decode
from railswitch.services.adapters.history_store import open_history
from railswitch.services.adapters.csv_throws import load_throws, logged_record
from railswitch.services.core.fleet_diagnoser import DiagnosedThrow
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.records import every_throw, throw_of_record
from railswitch.services.core.switch_messages import SimulatedThrows
from railswitch.services.core.throw_cutter import CutThrow as Throw

__all__ = ["DiagnosedThrow", "Diagnoser", "Throw", "make_throw", "read_history", "read_throws", "simulate"]


def read_throws(path: str | os.PathLike[str]) -> list[Throw]:
    """Every throw of a recording (MCAP) or a CSV file (docs/contracts.md section 4), in the order they ended.

    A damaged recording gives what could be read before the damage; a CSV file that cannot be read raises
    railswitch.services.adapters.csv_throws.CsvInputError (a ValueError) naming its row and column."""
    return list(every_throw(load_throws(path).messages))


def make_throw(switch_id: str, throw_index: int, direction: str, t_s: Sequence[float] | np.ndarray,
               current_a: Sequence[float] | np.ndarray, angle_rad: Sequence[float] | np.ndarray | None = None,
               velocity_rad_s: Sequence[float] | np.ndarray | None = None, *, t_start_ns: int = 0) -> Throw:
    """A throw from arrays of its samples: times in seconds from its start (the sample at 0 the last at rest), the
    motor current and, where logged, its angle and angular velocity. `direction`: left_to_right or right_to_left.
    The values are checked as a ThrowRecord's are (ValueError naming the field); the throw gets the reference
    profile of the machine type modelled in its direction, as a CSV file's throws do."""
    if np.ndim(t_s) != 1 or len(t_s) < 2:
        raise ValueError("t_s: a throw needs at least two sample times")
    record = logged_record(switch_id, throw_index, direction, t_start_ns, t_s,
                           {"current_a": current_a, "angle_rad": angle_rad, "velocity_rad_s": velocity_rad_s})
    return throw_of_record(record)


def simulate(throws: int = 4, *, faults: dict[str, float] | None = None, own: dict[str, float] | None = None,
             switch_id: str = "sw1", noise: float = 0.0, seed: int = 0, plant: Plant | None = None) -> list[Throw]:
    """`throws` throws of a simulated switch (the high-fidelity plant), alternating directions from left to right.

    `faults`: fault parameters by name (docs/contracts.md section 2, e.g. {"left_bolt_offset": 0.05});
    `own`: the switch's own build and weather where not nominal (section 2a); `noise`: white noise of that share
    of each signal's peak. Each throw carries the truth it was simulated with (`throw.truth`). Pass one `plant` to
    several calls to build its solver once."""
    sim = SwitchSimulation(plant or Plant(), faults=faults, own=own, noise_rel=noise, seed=seed)
    source = SimulatedThrows(switch_id, sim)
    return [source.next() for _ in range(throws)]


def read_history(db: str | os.PathLike[str], switch_id: str, kind: str = "diagnosis", *, limit: int = 1000,
                 since_ns: int | None = None, until_ns: int | None = None) -> list[Message]:
    """A switch's latest `limit` stored messages of one kind (diagnosis, health or alarm), oldest first, from a
    historian's SQLite file or a postgresql:// URL; the store is only read (a missing file is an error, not made).

    HistoryDbError (an OSError, one line) when the store cannot be used; ValueError for an unknown kind."""
    if kind not in HISTORY_KINDS:
        raise ValueError(f"kind {kind!r} is not one of {', '.join(HISTORY_KINDS)}")
    with open_history(db, create=False) as store:
        payloads, _ = store.latest(switch_id, kind, since_ns, until_ns, limit)
    return [decode(CHANNEL_MODELS[kind], payload) for payload in payloads]
