"""`railswitch simulate`: run the high-fidelity plant offline and write an MCAP recording."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from models.plant import Plant
from models.switch import SwitchSimulation
from services.mcap_io import RecordingWriter, check_writable
from services.switch_messages import switch_messages


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
        for key, message in switch_messages(switch_id, sim, throws, progress):
            writer.write(key, message)
        count = writer.message_count
    path = Path(out)
    return SimulationSummary(path, throws, count, path.stat().st_size)
