"""`railswitch report`: pictures of every throw, overlaying several recordings, and of each switch's life.

Per switch, `<switch>_health.png` draws each fault parameter over the throws with its ±2σ band, its limit and
the throw at which the latest trend reaches it, from the switch's SwitchHealth messages: those a recording
holds, else those its offline diagnosis gives (`--model`), or those a history store keeps (`--db F.sqlite|URL`).
`<switch>_estimates.png` draws each throw's estimates, and `<switch>_features.png` each throw feature (throw time,
peak, mean and lock current, energy) per direction against the band its commissioning taught, from the same health
messages. Throws are whole numbers on every axis.
"""
from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from railswitch.schemas.faults import FAULT_PARAMETERS  # noqa: E402
from railswitch.services.core.fleet_diagnoser import DiagnosedThrow, Diagnoser, diagnose_messages  # noqa: E402
from railswitch.schemas import MAX_LIMIT, HistoryQuery, Message, SwitchHealth  # noqa: E402
from railswitch.services.adapters.history_store import open_history  # noqa: E402
from railswitch.services.adapters.csv_throws import load_throws as load_file  # noqa: E402
from railswitch.services.commands.options import add_model_argument, fail  # noqa: E402
from railswitch.services.core.health_series import ParameterSeries, SwitchSeries, health_series  # noqa: E402
from railswitch.services.core.historian import HistoryAnswers  # noqa: E402
from railswitch.services.core.records import every_throw  # noqa: E402
from railswitch.services.core.throw_cutter import CutThrow  # noqa: E402

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
    """Messages and throws of one recording or CSV file; damage is reported on stderr with what could be read."""
    recording = load_file(path)
    throws = list(every_throw(recording.messages))
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


def throw_axis(ax: Axes) -> None:
    """Throws are counted: ticks on whole numbers only."""
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def estimates_figure(switch_id: str, items: list[DiagnosedThrow]) -> Figure:
    """Each fault parameter's estimate (each mode's own hypothesis, with its standard deviation) over one
    switch's throws."""
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
        throw_axis(ax)
    drawn = [ax for ax in axes if ax.get_legend_handles_labels()[0]]
    if drawn:
        drawn[0].legend(fontsize=8)
    axes[0].set_title(f"{switch_id}: estimates of each mode's own hypothesis; black bars: injected truth", fontsize=9)
    axes[-1].set_xlabel("throw")
    fig.tight_layout()
    return fig


def health_figure(series: SwitchSeries) -> Figure:
    """Each fault parameter of one switch over its throws: level with its ±2σ band, the limit, and the throw at
    which the latest trend reaches it (with its 5 %-95 % interval). The picture looks ahead half the throws
    it shows; a crossing farther out is named in the legend instead of squeezing the history into a corner."""
    names = list(series.parameters)
    first = min(int(p.throws[0]) for p in series.parameters.values())
    horizon = series.last_throw + max(10, (series.last_throw - first) // 2)
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 2.0 * len(names)), sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        p = series.parameters[name]
        ax.plot(p.throws, p.level, "o-", ms=3, lw=1.0, label="level")
        ax.fill_between(p.throws, p.level - 2 * p.level_std, p.level + 2 * p.level_std, alpha=0.25, label="±2σ")
        ax.axhline(p.limit, color="tab:red", lw=1.0, ls="--", label="limit")
        if p.crossing is not None:
            _draw_crossing(ax, p, horizon)
        ax.set_ylabel(f"{name}\n[{FAULT_PARAMETERS[name].unit}]", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
        throw_axis(ax)
    axes[-1, 0].set_xlim(first - 0.5, horizon + 0.5)
    axes[0, 0].set_title(f"{series.switch_id}: health after throw {series.last_throw}: {series.state}", fontsize=9)
    axes[-1, 0].set_xlabel("throw")
    fig.tight_layout()
    return fig


def _draw_crossing(ax: Axes, p: ParameterSeries, horizon: int) -> None:
    """The predicted throw at the limit: a marker on the limit line and its interval shaded, or (beyond the
    picture's horizon) a legend entry."""
    c = p.crossing
    label = f"limit at throw {c.throw:.0f}"
    if c.low is not None and c.high is not None:
        label += f" ({c.low:.0f}–{c.high:.0f})"
        if c.low <= horizon:
            ax.axvspan(c.low, min(c.high, horizon + 0.5), color="tab:red", alpha=0.08)
    if c.throw <= horizon:
        ax.plot([p.throws[-1], c.throw], [p.level[-1], p.limit], ":", color="tab:red", lw=1.0)
        ax.plot([c.throw], [p.limit], "v", color="tab:red", ms=8, label=label)
    else:
        ax.plot([], [], "v", color="tab:red", ms=8, label=label + ", beyond the picture")


FEATURE_LABELS = {"throw_time_s": "throw time [s]", "peak_current_a": "peak current [A]",
                  "mean_current_a": "mean current [A]", "energy_j": "energy [J]", "lock_current_a": "lock current [A]"}
DIRECTION_COLOURS = {"left_to_right": "tab:blue", "right_to_left": "tab:orange"}


def features_figure(switch_id: str, healths: list[SwitchHealth]) -> Figure:
    """Each feature over the throws, per direction, with its commissioned band."""
    fig, axes = plt.subplots(len(FEATURE_LABELS), 1, figsize=(9, 11), sharex=True)
    for ax, (name, label) in zip(axes, FEATURE_LABELS.items()):
        for direction, colour in DIRECTION_COLOURS.items():
            points = sorted((h.throw_index, f) for h in healths for f in h.features
                            if f.name == name and f.direction == direction)
            if not points:
                continue
            throws = [t for t, _ in points]
            ax.plot(throws, [f.value for _, f in points], "o-", ms=3, lw=1, color=colour,
                    label=direction.replace("_", " "))
            ax.fill_between(throws, [f.low for _, f in points], [f.high for _, f in points], color=colour, alpha=0.12,
                            step="mid")
            outside = [(t, f.value) for t, f in points if f.state == "outside"]
            if outside:
                ax.plot(*zip(*outside), "x", color="red", ms=7)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3)
        throw_axis(ax)
    handles, labels = next((found for ax in axes if (found := ax.get_legend_handles_labels())[0]), ([], []))
    if handles:
        fig.legend(handles, labels, fontsize=8, loc="upper right")
    axes[-1].set_xlabel("throw")
    fig.suptitle(f"{switch_id}: throw features against their commissioned band (x: outside it)")
    fig.tight_layout()
    return fig


def save(fig: Figure, target: Path) -> Path:
    fig.savefig(target, dpi=110)
    plt.close(fig)
    return target


def health_from_db(path: str) -> list[SwitchHealth]:
    """Every health message a history store keeps (the latest MAX_LIMIT of each switch), as a historian answers."""
    with open_history(path, create=False) as db:
        answer = HistoryAnswers(db, lambda _: True, historian=db.name).answer_query(
            HistoryQuery(kind="health", limit=MAX_LIMIT), None)
    return [h for reply in answer.decoded() for h in reply.health]


def life_pictures(out: Path, healths: list[SwitchHealth], fits: dict[tuple[str, int], DiagnosedThrow]) -> list[Path]:
    """Per switch: its health over the throws and, when the throws were diagnosed here, their estimates."""
    written = [save(health_figure(series), out / f"{switch_id}_health.png")
               for switch_id, series in health_series(healths).items() if series.parameters]
    by_switch: dict[str, list[DiagnosedThrow]] = defaultdict(list)
    for (switch_id, _), item in sorted(fits.items()):
        by_switch[switch_id].append(item)
    written += [save(estimates_figure(switch_id, items), out / f"{switch_id}_estimates.png")
                for switch_id, items in by_switch.items()]
    by_switch_health: dict[str, list[SwitchHealth]] = defaultdict(list)
    for health in healths:
        if health.features:
            by_switch_health[health.switch_id].append(health)
    written += [save(features_figure(switch_id, items), out / f"{switch_id}_features.png")
                for switch_id, items in sorted(by_switch_health.items())]
    return written


def write_report(recordings: list[str], out_dir: str, model: str | None = None, db: str | None = None) -> list[Path]:
    """One PNG per throw index (current, angle, velocity over time since the throw's start), and per switch
    its life (health over the throws; estimates, when diagnosed here).

    With `model` and a single recording, each throw also shows the decided hypothesis's fitted current and
    velocity. Health comes from `db` when given, else from the single recording's health messages, else from
    its offline diagnosis (with `model`).
    """
    healths = health_from_db(db) if db else None  # a store that cannot be read stops it before DIR is made
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    by_index: dict[tuple[str, int, str], list[tuple[str, CutThrow]]] = defaultdict(list)
    messages: list[Message] = []
    for name in recordings:
        path = Path(name)
        messages, throws = load_throws(path)
        for throw in throws:
            key = (throw.switch_id, throw.start.throw_index, throw.start.direction)
            by_index[key].append((_label(path, throw), throw))
    single = len(recordings) == 1
    fits = diagnosed(messages, model) if model and single else {}
    written = [throw_picture(out, key, curves, fits.get(key[:2]), model) for key, curves in sorted(by_index.items())]
    if healths is None:
        recorded = [m for m in messages if isinstance(m, SwitchHealth)] if single else []
        healths = recorded or [item.health for item in fits.values() if item.health is not None]
    return written + life_pictures(out, healths, fits)


def throw_picture(out: Path, key: tuple[str, int, str], curves: list[tuple[str, CutThrow]],
                  item: DiagnosedThrow | None, model: str | None) -> Path:
    """One throw's signals from every recording, with the decided hypothesis's fit when there is one."""
    switch_id, index, direction = key
    fig, axes = plt.subplots(len(PANELS), 1, figsize=(9, 8), sharex=True)
    for label, throw in curves:
        for ax, (signal, _) in zip(axes, PANELS):
            ax.plot(throw.t_s, getattr(throw.signals, signal), lw=1.2, label=label)
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
    return save(fig, out / f"{switch_id}_throw{index:03d}_{direction}.png")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recordings", nargs="*", metavar="F.mcap")
    parser.add_argument("--out", required=True, metavar="DIR")
    parser.add_argument("--db", metavar="F.sqlite|URL", default=None,
                        help="draw each switch's health from a history file or postgresql:// database "
                             "(railswitch historian)")
    add_model_argument(parser, "none", help_text="reduced model whose fits and estimates are drawn (one recording); "
                                                 "none: data only")


def run(args: argparse.Namespace) -> int:
    if not args.recordings and not args.db:
        return fail("give a recording (F.mcap) or a history file (--db F.sqlite)")
    try:
        written = write_report(args.recordings, args.out, None if args.model == "none" else args.model, args.db)
    except (OSError, ValueError) as error:
        return fail(str(error))
    for path in written:
        print(path)
    return 0
