"""The pictures `railswitch report` draws, as PNG files: every throw's signals (several recordings overlaid, with
the decided hypothesis's fit), and per switch its life: each fault parameter's health over the throws with its
±2σ band, its limit and the throw at which the latest trend reaches it; each throw's estimates; each throw feature
per direction against the band its commissioning taught. Throws are whole numbers on every axis."""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from railswitch.schemas import SwitchHealth  # noqa: E402
from railswitch.schemas.faults import FAULT_PARAMETERS  # noqa: E402
from railswitch.services.core.fleet_diagnoser import DiagnosedThrow  # noqa: E402
from railswitch.services.core.health_series import ParameterSeries, SwitchSeries, health_series  # noqa: E402
from railswitch.services.core.throw_cutter import CutThrow  # noqa: E402


PANELS = (("current_a", "current [A]"), ("angle_rad", "angle [rad]"), ("velocity_rad_s", "angular velocity [rad/s]"))


def throw_label(path: Path, throw: CutThrow) -> str:
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
