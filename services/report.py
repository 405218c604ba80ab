"""`railswitch report`: pictures of every throw, overlaying several recordings."""
from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from services.mcap_io import RecordingReader  # noqa: E402
from services.throw_cutter import CutThrow, cut_throws  # noqa: E402

PANELS = (("current_a", "current [A]"), ("angle_rad", "angle [rad]"), ("velocity_rad_s", "angular velocity [rad/s]"))


def _label(path: Path, throw: CutThrow) -> str:
    """File name plus the injected faults, when the recording says which."""
    if throw.truth is None:
        return path.stem
    params = throw.truth.params()
    active = throw.truth.active_modes()
    if not active:
        return f"{path.stem} (nominal)"
    shown = [f"{name}={value:g}" for name, value in params.items()
             if name != "obstacle_position" and value != 0.0]
    if "obstacle" in active:
        shown.append(f"obstacle_position={params['obstacle_position']:g}")
    return f"{path.stem} ({', '.join(shown)})"


def load_throws(path: Path) -> list[CutThrow]:
    """Throws of one recording; damage is reported on stderr with what could be read."""
    reader = RecordingReader(path)
    throws = list(cut_throws(message.message for message in reader))
    damage = f"; {reader.damage}" if reader.damage else ""
    if not throws:
        raise ValueError(f"{path}: no throws found in {reader.messages_read} messages{damage}")
    if damage:
        print(f"railswitch report: {path}: {reader.damage}; using the {reader.messages_read} messages before it",
              file=sys.stderr)
    return throws


def write_report(recordings: list[str], out_dir: str) -> list[Path]:
    """One PNG per throw index (current, angle, velocity over time since the throw's start)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    by_index: dict[tuple[str, int, str], list[tuple[str, CutThrow]]] = defaultdict(list)
    for name in recordings:
        path = Path(name)
        for throw in load_throws(path):
            by_index[(throw.switch_id, throw.start.throw_index, throw.start.direction)].append((_label(path, throw), throw))

    written = []
    for (switch_id, index, direction), curves in sorted(by_index.items()):
        fig, axes = plt.subplots(len(PANELS), 1, figsize=(9, 8), sharex=True)
        for label, throw in curves:
            for ax, (signal, _) in zip(axes, PANELS):
                ax.plot(throw.t_s, getattr(throw, signal), lw=1.2, label=label)
        for ax, (_, ylabel) in zip(axes, PANELS):
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3)
        axes[-1].set_xlabel("time since throw start [s]")
        axes[0].legend(fontsize=8, loc="best")
        fig.suptitle(f"{switch_id} throw {index}: {direction.replace('_', ' ')}")
        fig.tight_layout()
        target = out / f"{switch_id}_throw{index:03d}_{direction}.png"
        fig.savefig(target, dpi=110)
        plt.close(fig)
        written.append(target)
    return written
