"""The historian's SQLite file (stdlib sqlite3, the embedded store): diagnoses and health messages by switch and time.

One table `history` holds each message as its JSON beside the switch, kind, throw and time it is looked up
by; a unique index on (switch_id, t_ns, kind, throw_index) serves queries by switch and time, and makes a
message delivered twice one row. `schema_version` says which layout a file has. The journal is WAL, so
queries read while a batch is written, and commits are synchronous=FULL: a committed batch survives a
killed process (and a power cut). auto_vacuum=INCREMENTAL hands the pages of pruned rows back to the disk.

A damaged file is refused at opening, with how many rows can still be read; `salvage` copies those into a
fresh file.
"""
from __future__ import annotations

import logging
import mmap
import os
import sqlite3
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from railswitch.schemas import CHANNEL_MODELS, HISTORY_KINDS, MessageError, decode
from railswitch.services.adapters.history_store import (COLUMNS, KIND_CHECK, PRUNE_SQL, HistoryDbError, HistoryRow,
                                                        HistoryStore)

log = logging.getLogger("railswitch.historian")

__all__ = ["DamagedHistory", "HistoryDb", "HistoryDbError", "HistoryRow", "readable_rows", "salvage"]
# 2: alarm changes are kept too (the kinds' check names them). A file of version 1 is read as it is and migrated by
# the first historian that opens it (MIGRATIONS: SQLite cannot change a check in place, so the table is copied).
SCHEMA_VERSION = 2
TABLE = """
CREATE TABLE {name} (
    switch_id TEXT NOT NULL,
    kind TEXT NOT NULL {check},
    throw_index INTEGER NOT NULL,
    t_ns INTEGER NOT NULL,
    payload TEXT NOT NULL
);"""
INDEX = "CREATE UNIQUE INDEX history_by_switch_time ON history (switch_id, t_ns, kind, throw_index);"
SCHEMA = f"""
CREATE TABLE schema_version (version INTEGER NOT NULL);
INSERT INTO schema_version VALUES ({SCHEMA_VERSION});
{TABLE.format(name="history", check=KIND_CHECK)}
{INDEX}
"""
MIGRATIONS = {1: f"""
{TABLE.format(name="history_next", check=KIND_CHECK)}
INSERT INTO history_next SELECT {COLUMNS} FROM history;
DROP TABLE history;
ALTER TABLE history_next RENAME TO history;
{INDEX}
UPDATE schema_version SET version = 2;
"""}
READABLE_VERSIONS = (1, SCHEMA_VERSION)
SALVAGE_BATCH = 1000  # rows per transaction of a salvage


class DamagedHistory(HistoryDbError):
    """A history file SQLite cannot read whole; `readable` rows of it can still be salvaged."""

    def __init__(self, path: Path, reason: str, readable: int):
        self.readable = readable
        super().__init__(f"history database {path} is damaged ({reason}); {readable} rows are readable: "
                         f"`railswitch history --db {path} --salvage NEW.sqlite` copies them into a fresh file")


class HistoryDb(HistoryStore):
    """One connection to a history file. The first (check=True) creates or checks the file; further ones
    (check=False, one per thread) join a file already checked."""

    table = "history"
    payload_bytes = "CAST(payload AS BLOB)"

    def __init__(self, path: str | os.PathLike[str], *, check: bool = True, create: bool = True):
        self.path = Path(path)
        self.name = str(self.path)
        if check:
            _check_location(self.path, create)
        try:
            # Each connection is used by one thread at a time: the historian opens its query connection
            # before handing it to the thread that answers queries.
            self._db = sqlite3.connect(self.path, isolation_level=None, timeout=30.0, check_same_thread=False)
        except sqlite3.Error as error:
            raise HistoryDbError(f"cannot open history database {self.path}: {error}") from None
        if check:
            self._check(create)
        self._db.execute("PRAGMA synchronous = FULL")

    def _check(self, create: bool) -> None:
        """Refuse a damaged file, another program's database or a newer layout; create the tables in a new file."""
        try:
            problems = [row[0] for row in self._db.execute("PRAGMA quick_check")]
            tables = {row[0] for row in self._db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        except sqlite3.OperationalError as error:  # locked, or an I/O error: the file may be whole
            self.close()
            raise HistoryDbError(f"cannot read history database {self.path}: {error}") from None
        except sqlite3.DatabaseError as error:  # not a database, or corrupt
            self.close()
            raise DamagedHistory(self.path, str(error), count_readable(self.path)) from None
        if problems != ["ok"]:
            self.close()
            raise DamagedHistory(self.path, _first_problem(problems), count_readable(self.path))
        if not tables:
            self._db.execute("PRAGMA auto_vacuum = INCREMENTAL")  # only takes effect before the first table
            self._db.execute("PRAGMA journal_mode = WAL")
            self._db.executescript(f"BEGIN; {SCHEMA} COMMIT;")
            return
        if "schema_version" not in tables or "history" not in tables:
            self.close()
            raise HistoryDbError(f"{self.path} is not a railswitch history database "
                                 f"(it holds {', '.join(sorted(tables))})")
        version = self._db.execute("SELECT max(version) FROM schema_version").fetchone()[0]
        if version not in READABLE_VERSIONS:
            self.close()
            raise HistoryDbError(f"{self.path} has history schema version {version}; this railswitch reads "
                                 f"version {SCHEMA_VERSION}")
        self._db.execute("PRAGMA journal_mode = WAL")
        if version != SCHEMA_VERSION and create:
            log.info("%s: history schema version %d migrated to %d", self.path, version, SCHEMA_VERSION)
            self._db.executescript(f"BEGIN IMMEDIATE; {MIGRATIONS[version]} COMMIT;")

    def write(self, rows: Sequence[HistoryRow]) -> int:
        """Store rows in one transaction (all or none); returns how many were new (the rest were stored before).
        HistoryDbError when the file cannot take them (a full disk)."""
        before = self._db.total_changes
        try:
            with self._transaction():
                self._db.executemany(f"INSERT OR IGNORE INTO history ({COLUMNS}) VALUES (?, ?, ?, ?, ?)", rows)
        except sqlite3.Error as error:
            raise HistoryDbError(f"cannot write history database {self.path}: {error}") from None
        return self._db.total_changes - before

    @contextmanager
    def _transaction(self) -> Iterator[None]:
        """BEGIN IMMEDIATE … COMMIT, rolled back on any failure (the COMMIT's own included)."""
        self._db.execute("BEGIN IMMEDIATE")
        try:
            yield
            self._db.execute("COMMIT")
        except BaseException:
            if self._db.in_transaction:
                self._db.execute("ROLLBACK")
            raise

    def _read(self, sql: str, parameters: tuple = ()) -> list[tuple]:
        try:
            return self._db.execute(sql, parameters).fetchall()
        except sqlite3.Error as error:
            raise HistoryDbError(f"cannot read history database {self.path}: {error}") from None

    def prune(self, before_ns: int) -> int:
        """Delete every row older than before_ns (switch by switch, along the index) and give the freed pages
        back to the disk; returns the rows deleted."""
        deleted = 0
        try:
            for switch_id in self.switches():
                with self._transaction():
                    deleted += self._db.execute(PRUNE_SQL.format(table=self.table), (switch_id, before_ns)).rowcount
            if deleted:
                self._db.execute("PRAGMA incremental_vacuum")
        except sqlite3.Error as error:
            raise HistoryDbError(f"cannot prune history database {self.path}: {error}") from None
        return deleted

    def close(self) -> None:
        self._db.close()


def _first_problem(problems: list[str]) -> str:
    """quick_check's first finding as one line (it reports several, each possibly over several lines)."""
    lines = [line for text in problems for line in text.splitlines() if line and not line.startswith("***")]
    more = f", and {len(lines) - 1} more" if len(lines) > 1 else ""
    return f"{lines[0][:200] if lines else 'quick_check failed'}{more}"


def _check_location(path: Path, create: bool) -> None:
    """Fail in one line before SQLite does in several: a missing directory or file, or a directory given."""
    if path.is_dir():
        raise HistoryDbError(f"cannot use history database {path}: it is a directory")
    if not path.parent.is_dir():
        raise HistoryDbError(f"cannot create history database {path}: directory {path.parent} does not exist")
    if not create and not path.exists():
        raise HistoryDbError(f"history database {path} does not exist")


def readable_rows(path: str | os.PathLike[str]) -> Iterator[HistoryRow]:
    """Every row still in a possibly damaged file (with its write-ahead log) whose message is valid, once each,
    found page by page.

    A truncated file loses interior pages of the table's b-tree (they are allocated late, near the end) and
    with them every path from the root, and a garbage header hides the schema; the rows themselves sit in
    leaf pages, so those are read directly (the SQLite file format, https://sqlite.org/fileformat2.html,
    sections 1.3, 1.6, 2.1 and 4.1). Rows that are not this table's, or not valid any more, are left out."""
    pages, usable = _latest_pages(Path(path))
    seen = set()
    for number, page in pages.items():
        for row in _leaf_rows(page, 100 if number == 1 else 0, pages, usable):
            if row[:4] not in seen and _valid(row):
                seen.add(row[:4])
                yield row


def _latest_pages(path: Path) -> tuple[dict[int, memoryview], int]:
    """Each page's latest image (the log's frames of the current generation over the file's) by page number,
    and the usable bytes of a page. Where the file header is garbage, the log's header or SQLite's default
    page size stands in. The files are mapped, not read: a large file costs address space, not memory."""
    data = _mapped(path)
    log = _mapped(Path(f"{path}-wal"))
    size, usable = _page_geometry(data[:100], int.from_bytes(log[8:12], "big") if len(log) >= 32 else 4096)
    pages = {start // size + 1: data[start:start + size] for start in range(0, len(data) - size + 1, size)}
    salt = log[16:24]
    for at in range(32, len(log) - size - 24 + 1, size + 24):  # frames: a 24-byte header and a page
        if log[at + 8:at + 16] == salt:
            pages[int.from_bytes(log[at:at + 4], "big")] = log[at + 24:at + 24 + size]
    return pages, usable


def _mapped(path: Path) -> memoryview:
    """A file's bytes, mapped read-only (empty when it is missing or empty)."""
    try:
        with open(path, "rb") as f:
            return memoryview(mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ))
    except (OSError, ValueError):  # missing, or empty (which cannot be mapped)
        return memoryview(b"")


def _page_geometry(header: memoryview, fallback: int) -> tuple[int, int]:
    """Page size and usable bytes per page from the file header, or `fallback` where the header is garbage."""
    size = int.from_bytes(header[16:18], "big") if len(header) >= 21 else 0
    size = 65536 if size == 1 else size
    if size < 512 or size > 65536 or size & (size - 1):
        return fallback, fallback
    return size, size - header[20]


def _leaf_rows(page: memoryview, at: int, pages: dict[int, memoryview], usable: int) -> Iterator[HistoryRow]:
    """The rows of a table leaf page (type 13; its header at `at`) that decode as this table's five columns."""
    if len(page) <= at or page[at] != 13:
        return
    cells = int.from_bytes(page[at + 3:at + 5], "big")
    for k in range(cells):
        pointer = int.from_bytes(page[at + 8 + 2 * k:at + 10 + 2 * k], "big")
        try:
            values = _record(_cell_payload(page, pointer, pages, usable))
        except (IndexError, ValueError, UnicodeDecodeError):
            continue
        if len(values) == 5 and [type(v) for v in values] == [str, str, int, int, str]:
            yield HistoryRow(*values)


def _cell_payload(page: memoryview, at: int, pages: dict[int, memoryview], usable: int) -> bytes:
    """A table leaf cell's payload, followed along its overflow pages."""
    size, at = _varint(page, at)
    _, at = _varint(page, at)  # rowid
    most = usable - 35
    if size <= most:
        return bytes(page[at:at + size])
    least = (usable - 12) * 32 // 255 - 23
    local = least + (size - least) % (usable - 4)
    local = local if local <= most else least
    payload = bytearray(page[at:at + local])
    number = int.from_bytes(page[at + local:at + local + 4], "big")
    while len(payload) < size:
        overflow = pages.get(number)
        if overflow is None:
            raise ValueError("overflow chain broken")
        number = int.from_bytes(overflow[:4], "big")
        payload += overflow[4:4 + min(usable - 4, size - len(payload))]
    return bytes(payload)


def _record(payload: bytes) -> list:
    """A record's values: integers and text (the serial types this table stores), NULL as None."""
    header_size, at = _varint(payload, 0)
    types = []
    while at < header_size:
        serial, at = _varint(payload, at)
        types.append(serial)
    values, at = [], header_size
    for serial in types:
        if 1 <= serial <= 6:
            width = (1, 2, 3, 4, 6, 8)[serial - 1]
            values.append(int.from_bytes(payload[at:at + width], "big", signed=True))
            at += width
        elif serial in (8, 9):
            values.append(serial - 8)
        elif serial >= 13 and serial % 2:
            width = (serial - 13) // 2
            values.append(payload[at:at + width].decode())
            at += width
        elif serial == 0:
            values.append(None)
        else:
            raise ValueError(f"serial type {serial} is none of this table's")
    if at > len(payload):
        raise ValueError("record runs past its payload")
    return values


def _varint(data: bytes | memoryview, at: int) -> tuple[int, int]:
    """SQLite's big-endian variable-length integer at `at` and the position after it."""
    value = 0
    for k in range(9):
        byte = data[at + k]
        if k == 8:
            return (value << 8) | byte, at + 9
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, at + k + 1
    raise ValueError("unreachable")


def _valid(row: HistoryRow) -> bool:
    """A row worth keeping: a known kind whose payload is still the valid message of its switch."""
    if row.kind not in HISTORY_KINDS or not isinstance(row.payload, str):
        return False
    try:
        message = decode(CHANNEL_MODELS[row.kind], row.payload.encode())
    except MessageError:
        return False
    return message.switch_id == row.switch_id


def count_readable(path: str | os.PathLike[str]) -> int:
    return sum(1 for _ in readable_rows(path))


def salvage(source: str | os.PathLike[str], target: str | os.PathLike[str]) -> int:
    """Copy the readable rows of a damaged history file into a new one (which must not exist); returns how many."""
    target = Path(target)
    if target.exists():
        raise HistoryDbError(f"will not salvage into {target}: it exists (name a new file)")
    with HistoryDb(target) as fresh:
        return sum(fresh.write(batch) for batch in _batches(readable_rows(source), SALVAGE_BATCH))


def _batches(rows: Iterable[HistoryRow], size: int) -> Iterator[list[HistoryRow]]:
    batch: list[HistoryRow] = []
    for row in rows:
        batch.append(row)
        if len(batch) == size:
            yield batch
            batch = []
    if batch:
        yield batch
