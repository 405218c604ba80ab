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

from railswitch.schemas import MAX_LIMIT, HistoryQuery, Message, SwitchHealth
from railswitch.services.adapters.csv_throws import load_throws as load_file
from railswitch.services.adapters.history_store import open_history
from railswitch.services.commands.options import add_model_argument, fail
from railswitch.services.core.fleet_diagnoser import DiagnosedThrow, diagnose_messages
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.historian import HistoryAnswers
from railswitch.services.core.pictures import life_pictures, throw_label, throw_picture
from railswitch.services.core.records import every_throw
from railswitch.services.core.throw_cutter import CutThrow


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


def health_from_db(path: str) -> list[SwitchHealth]:
    """Every health message a history store keeps (the latest MAX_LIMIT of each switch), as a historian answers."""
    with open_history(path, create=False) as db:
        answer = HistoryAnswers(db, lambda _: True, historian=db.name).answer_query(
            HistoryQuery(kind="health", limit=MAX_LIMIT), None)
    return [h for reply in answer.decoded() for h in reply.health]


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
            by_index[key].append((throw_label(path, throw), throw))
    single = len(recordings) == 1
    fits = diagnosed(messages, model) if model and single else {}
    written = [throw_picture(out, key, curves, fits.get(key[:2]), model) for key, curves in sorted(by_index.items())]
    if healths is None:
        recorded = [m for m in messages if isinstance(m, SwitchHealth)] if single else []
        healths = recorded or [item.health for item in fits.values() if item.health is not None]
    return written + life_pictures(out, healths, fits)


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
        return fail("give a recording (F.mcap or F.csv) or a history store (--db F.sqlite or --db postgresql://…)")
    try:
        written = write_report(args.recordings, args.out, None if args.model == "none" else args.model, args.db)
    except (OSError, ValueError) as error:
        return fail(str(error))
    for path in written:
        print(path)
    return 0
