"""The CSV adapter: throws a trackside logger exported as one row per sample, read as the records a unit that cuts
its own throws would upload (ThrowRecord on railswitch/<id>/record), so `diagnose`, `replay` and `report` take a
CSV file as they take a recording (docs/contracts.md section 4, CSV input).

Columns (any order; others are ignored): switch_id, throw_index, direction (left_to_right or right_to_left), t_s
(seconds from the throw's start), current_a, and optionally angle_rad and velocity_rad_s. Rows of different throws
may come in any order; within a throw the times must go forward, because a time that goes back there is a clock
jump or two files merged, which must not be sorted away. The file names no reference profile and no clock time: each
throw gets the machine type's reference of its direction, and times a minute apart in throw order.

A file that cannot be read as a whole is refused with one line naming its row and column; nothing of it is used.
"""
from __future__ import annotations

import csv
import os
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from railswitch.models.plant.reference import DIRECTIONS, throw_reference
from railswitch.schemas import ThrowRecord, key_expr
from railswitch.services.adapters.recordings import RecordedMessage, Recording, load_recording

REQUIRED = ("switch_id", "throw_index", "direction", "t_s", "current_a")
OPTIONAL = ("angle_rad", "velocity_rad_s")
SPACING_NS = 60 * 10**9  # between the starts of a switch's throws: a minute, more than any throw lasts


class CsvInputError(ValueError):
    """A CSV file that cannot be read as throws; the message is one line naming the file, row and column."""


def is_csv(path: str | os.PathLike[str]) -> bool:
    return Path(path).suffix.lower() == ".csv"


def load_throws(path: str | os.PathLike[str]) -> Recording:
    """A recording, or a CSV file's throws (by the name's .csv): what `diagnose`, `replay` and `report` read."""
    return load_csv(path) if is_csv(path) else load_recording(path)


def load_csv(path: str | os.PathLike[str]) -> Recording:
    """Every throw of a CSV file as a record, in each switch's throw order; CsvInputError when any row is wrong."""
    path = Path(path)
    try:
        return _load_csv(path)
    except UnicodeDecodeError as error:
        raise CsvInputError(f"{path}: not UTF-8 text (byte {error.start}): is it a CSV file?") from None
    except csv.Error as error:
        raise CsvInputError(f"{path}: {error}") from None


def _load_csv(path: Path) -> Recording:
    with open(path, newline="", encoding="utf-8-sig") as f:  # a spreadsheet's byte-order mark is not a column
        rows = csv.reader(f)
        header = [name.strip() for name in next(rows, [])]
        missing = [name for name in REQUIRED if name not in header]
        if missing:
            raise CsvInputError(f"{path}: row 1: no column {', '.join(missing)} (the header needs "
                                f"{', '.join(REQUIRED)}; {', '.join(OPTIONAL)} are optional)")
        column = {name: header.index(name) for name in REQUIRED + OPTIONAL if name in header}
        throws: dict[tuple[str, int], _Throw] = {}
        for number, row in enumerate(rows, start=2):
            if not any(cell.strip() for cell in row):
                continue  # a blank line, as a file's end often has
            cell = _Cells(path, number, row, column)
            switch_id, index, direction = cell.text("switch_id"), cell.integer("throw_index"), cell.text("direction")
            if direction not in DIRECTIONS:
                raise cell.error("direction", f"{direction!r} is not one of {', '.join(DIRECTIONS)}")
            throw = throws.setdefault((switch_id, index), _Throw(direction))
            throw.add(cell, direction)
    if not throws:
        raise CsvInputError(f"{path}: no sample rows after the header")
    records = []
    for switch_id in sorted({switch for switch, _ in throws}):
        t_start_ns = 0
        for (_, index), throw in sorted((key, throw) for key, throw in throws.items() if key[0] == switch_id):
            record = throw.record(path, switch_id, index, max(t_start_ns, index * SPACING_NS))
            records.append(RecordedMessage(key_expr(switch_id, "record"), "record", switch_id, record,
                                           record.t_end_ns))
            t_start_ns = record.t_end_ns + SPACING_NS
    return Recording(records, None, Counter(), Counter())


class _Cells:
    """One row's cells by column name, each read with an error that names the file, row and column."""

    def __init__(self, path: Path, number: int, row: list[str], column: dict[str, int]):
        self.path, self.row_number, self.row, self.column = path, number, row, column

    def error(self, name: str, problem: str) -> CsvInputError:
        return CsvInputError(f"{self.path}: row {self.row_number}, column {name}: {problem}")

    def raw(self, name: str) -> str:
        k = self.column[name]
        return self.row[k].strip() if k < len(self.row) else ""

    def text(self, name: str) -> str:
        value = self.raw(name)
        if not value:
            raise self.error(name, "empty")
        return value

    def integer(self, name: str) -> int:
        value = self.text(name)
        try:
            number = int(value)
        except ValueError:
            raise self.error(name, f"{value!r} is not a whole number") from None
        if number < 0:
            raise self.error(name, f"{number} is below 0")
        return number

    def number(self, name: str) -> float | None:
        """The cell as a finite number; None for an empty cell of an optional column (or a column not there)."""
        if name not in self.column:
            return None
        if name in OPTIONAL and not self.raw(name):
            return None
        value = self.text(name)
        try:
            number = float(value)
        except ValueError:
            raise self.error(name, f"{value!r} is not a number") from None
        if not np.isfinite(number):
            raise self.error(name, f"{value!r} is not a finite number")
        return number


class _Throw:
    """One throw's samples as they come; the signals an optional column holds for all of them or for none."""

    def __init__(self, direction: str):
        self.direction = direction
        self.first_row = 0
        self.t_s: list[float] = []
        self.signals: dict[str, list[float | None]] = {"current_a": [], **{name: [] for name in OPTIONAL}}
        self.first_with: dict[str, int] = {}  # the first row with a value, of each optional signal

    def add(self, cell: _Cells, direction: str) -> None:
        if direction != self.direction:
            raise cell.error("direction", f"{direction} in a throw that began {self.direction} (row "
                                          f"{self.first_row})")
        t_s = cell.number("t_s")
        if t_s < 0:
            raise cell.error("t_s", f"{t_s:g} s is before the throw's start")
        if self.t_s and t_s <= self.t_s[-1]:
            raise cell.error("t_s", f"{t_s:g} s does not come after the throw's previous sample at "
                                    f"{self.t_s[-1]:g} s: times must go forward within a throw")
        self.first_row = self.first_row or cell.row_number
        self.t_s.append(t_s)
        self.signals["current_a"].append(cell.number("current_a"))
        for name in OPTIONAL:
            value = cell.number(name)
            self.signals[name].append(value)
            if value is not None:
                self.first_with.setdefault(name, cell.row_number)

    def record(self, path: Path, switch_id: str, index: int, t_start_ns: int) -> ThrowRecord:
        signals = {}
        for name, values in self.signals.items():
            held = [v for v in values if v is not None]
            if held and len(held) < len(values):
                raise CsvInputError(f"{path}: column {name}: {switch_id} throw {index} has it in {len(held)} of its "
                                    f"{len(values)} rows (first row {self.first_with[name]}): all of a throw's "
                                    "samples or none")
            signals[name] = held or None
        try:
            return logged_record(switch_id, index, self.direction, t_start_ns, self.t_s, signals)
        except ValidationError as error:
            problem = error.errors()[0]
            where = ".".join(str(part) for part in problem["loc"]) or "the throw"
            raise CsvInputError(f"{path}: {switch_id} throw {index} (from row {self.first_row}): {where}: "
                                f"{problem['msg']}") from None


def logged_record(switch_id: str, index: int, direction: str, t_start_ns: int, t_s: Sequence[float] | np.ndarray,
                  signals: Mapping[str, Sequence[float] | np.ndarray | None]) -> ThrowRecord:
    """A throw logged with neither a reference profile nor a clock (a CSV file's, or arrays given to the Python
    API) as a record: its times in seconds from its start, the reference of the machine type modelled in its
    direction. pydantic's ValidationError (a ValueError) names what the record refuses."""
    offsets = np.rint(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)
    reference = throw_reference(direction)
    return ThrowRecord(switch_id=switch_id, throw_index=index, direction=direction, t_start_ns=t_start_ns,
                       t_end_ns=t_start_ns + int(offsets[-1]), reference_t_s=reference.t_s.tolist(),
                       reference_velocity_rad_s=reference.velocity_rad_s.tolist(), t_offset_ns=offsets.tolist(),
                       **{name: None if values is None else np.asarray(values, dtype=float).tolist()
                          for name, values in signals.items()})
