"""`railswitch simulate`: run the high-fidelity plant offline and write an MCAP recording."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from models.plant import Plant
from models.switch import SwitchSimulation
from services.mcap_io import RecordingWriter, check_writable
from services.switch_messages import motor_messages, throw_messages, truth_message


@dataclass(frozen=True)
class SimulationSummary:
    path: Path
    throws: int
    messages: int
    bytes: int


def simulate_to_mcap(out: str | Path, *, switch_id: str = "sw1", throws: int = 2, faults: dict[str, float] | None = None,
                     noise_rel: float = 0.0, seed: int = 0, rate_hz: float = 50.0, plant: Plant | None = None,
                     progress=None) -> SimulationSummary:
    """Simulate `throws` alternating throws and record motor, throw and truth channels.

    The file appears only when complete (written beside it, then renamed).
    """
    check_writable(out)
    sim = SwitchSimulation(plant or Plant(), rate_hz=rate_hz, faults=faults, noise_rel=noise_rel, seed=seed)
    with RecordingWriter(out) as writer:
        writer.write(*truth_message(switch_id, sim, 0))
        for key, message in motor_messages(switch_id, sim, sim.initial_sample()):
            writer.write(key, message)
        for _ in range(throws):
            for key, message in throw_messages(switch_id, sim, sim.throw()):
                writer.write(key, message)
            if progress is not None:
                progress()
        count = writer.message_count
    path = Path(out)
    return SimulationSummary(path, throws, count, path.stat().st_size)
