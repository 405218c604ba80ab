"""`railswitch report`: pictures of every throw, overlaying several recordings."""
from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from railswitch.schemas.faults import FAULT_PARAMETERS  # noqa: E402
from railswitch.services.core.fleet_diagnoser import DiagnosedThrow, Diagnoser, diagnose_messages  # noqa: E402
from railswitch.schemas import Message  # noqa: E402
from railswitch.services.adapters.recordings import load_recording  # noqa: E402
from railswitch.services.commands.options import add_model_argument, fail  # noqa: E402
from railswitch.services.core.throw_cutter import CutThrow, cut_throws  # noqa: E402

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


def load_throws(path: Path) -> tuple[list[Message], list[CutThrow]]:
    """Messages and throws of one recording; damage is reported on stderr with what could be read."""
    recording = load_recording(path)
    throws = list(cut_throws(recording.messages))
    damage = f"; {recording.damage}" if recording.damage else ""
    if not throws:
        raise ValueError(f"{path}: no throws found in {len(recording.messages)} messages{damage}")
    note = recording.note()
    if note:
        print(f"railswitch report: {path}: {note}", file=sys.stderr)
    return recording.messages, throws


def diagnosed(messages: list[Message], model: str) -> dict[tuple[str, int], DiagnosedThrow]:
    """Every throw of one recording diagnosed, by (switch, throw index)."""
    return {(item.throw.switch_id, item.throw.start.throw_index): item
            for item in diagnose_messages(messages, Diagnoser(model))}


def estimates_figure(items: list[DiagnosedThrow], target: Path) -> Path:
    """Each fault parameter's estimate (decided mode, with its standard deviation) over the throws."""
    names = list(FAULT_PARAMETERS)
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 2.0 * len(names)), sharex=True)
    for ax, name in zip(axes, names):
        for direction, marker in (("left_to_right", "o"), ("right_to_left", "s")):
            points = [(i.diagnosis.throw_index, h.params[name], h.std.get(name, 0.0))
                      for i in items if i.diagnosis.direction == direction
                      for h in i.diagnosis.hypotheses if h.mode == FAULT_PARAMETERS[name].mode and name in h.params]
            if points:
                x, y, e = zip(*points)
                ax.errorbar(x, y, yerr=e, fmt=marker, ms=4, capsize=3, label=direction.replace("_", " "))
            truth = [(i.diagnosis.throw_index, i.throw.truth.params()[name]) for i in items
                     if i.throw.truth is not None and i.diagnosis.direction == direction]
            if truth:
                ax.plot(*zip(*truth), "k_", ms=12)
        p = FAULT_PARAMETERS[name]
        ax.set_ylabel(f"{name}\n[{p.unit}]", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("throw (estimates of each mode's own hypothesis; black bars: injected truth)")
    fig.tight_layout()
    fig.savefig(target, dpi=110)
    plt.close(fig)
    return target


def write_report(recordings: list[str], out_dir: str, model: str | None = None) -> list[Path]:
    """One PNG per throw index (current, angle, velocity over time since the throw's start).

    With `model` and a single recording, each throw also shows the decided
    hypothesis's fitted current and velocity, and one more PNG the parameter
    estimates over the throws.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    by_index: dict[tuple[str, int, str], list[tuple[str, CutThrow]]] = defaultdict(list)
    for name in recordings:
        path = Path(name)
        messages, throws = load_throws(path)
        for throw in throws:
            by_index[(throw.switch_id, throw.start.throw_index, throw.start.direction)].append((_label(path, throw), throw))

    fits = diagnosed(messages, model) if model and len(recordings) == 1 else {}
    written = []
    for (switch_id, index, direction), curves in sorted(by_index.items()):
        fig, axes = plt.subplots(len(PANELS), 1, figsize=(9, 8), sharex=True)
        for label, throw in curves:
            for ax, (signal, _) in zip(axes, PANELS):
                ax.plot(throw.t_s, getattr(throw.signals, signal), lw=1.2, label=label)
        item = fits.get((switch_id, index))
        if item is not None and item.verdict is not None:
            decided = item.verdict.mode
            for ax, (signal, _) in zip(axes, PANELS):
                if signal != "angle_rad":
                    ax.plot(item.throw.t_s[1:], item.verdict.fitted[signal], "--", lw=1.2,
                            label=f"fitted: {decided} ({model})")
            axes[0].set_title(f"decision: {item.diagnosis.decision}", fontsize=9)
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
    if fits:
        written.append(estimates_figure(list(fits.values()), out / "estimates.png"))
    return written


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recordings", nargs="+", metavar="F.mcap")
    parser.add_argument("--out", required=True, metavar="DIR")
    add_model_argument(parser, "none", help_text="reduced model whose fits and estimates are drawn (one recording); "
                                                 "none: data only")


def run(args: argparse.Namespace) -> int:
    try:
        written = write_report(args.recordings, args.out, None if args.model == "none" else args.model)
    except (OSError, ValueError) as error:
        return fail(str(error))
    for path in written:
        print(path)
    return 0
