"""What the historian's two stores share, and the one place that picks a store for a `--db` value.

A path means the embedded SQLite file (history_db.py); a `postgresql://` (or `postgres://`) URL means a shared
PostgreSQL database (history_pg.py), which several historians write at once. Both keep the same rows, read them
with the same queries and raise HistoryDbError, in one line, for anything that stops them.
"""
from __future__ import annotations

import os
import re
from collections.abc import Sequence

from railswitch.schemas import HISTORY_KINDS
from railswitch.schemas.history import MAX_TIME_NS
from railswitch.services.ports import HistoryDbError, HistoryRow

COLUMNS = "switch_id, kind, throw_index, t_ns, payload"
KIND_CHECK = "CHECK (kind IN ({}))".format(", ".join(f"'{k}'" for k in HISTORY_KINDS))
URL_SCHEMES = ("postgresql://", "postgres://")
# The reads of both stores, `?` for a parameter; {table} is the store's table, {payload} its payload as bytes.
LATEST_SQL = ("SELECT {payload} FROM {table} WHERE switch_id = ? AND kind = ? AND t_ns >= ? AND t_ns < ? "
              "ORDER BY t_ns DESC LIMIT ?")
THROW_INDICES_SQL = "SELECT throw_index FROM {table} WHERE switch_id = ? AND kind = ?"
HOLDS_SQL = "SELECT 1 FROM {table} WHERE switch_id = ? LIMIT 1"
SWITCHES_SQL = "SELECT DISTINCT switch_id FROM {table}"
COUNT_SQL = "SELECT count(*) FROM {table}"
PRUNE_SQL = "DELETE FROM {table} WHERE switch_id = ? AND t_ns < ?"


class HistoryStore:
    """Rows by switch, kind and time: written in batches, read by the historian's queries, pruned by age.
    Subclasses say how a batch is written and run the shared reads through `_read`."""

    table: str
    # The payload column read as UTF-8 bytes: a reply splices them as they are, where text would be decoded into
    # strings and encoded again (a reply may hold a thousand diagnoses).
    payload_bytes: str
    name: str  # the file, or the URL with its password masked: for messages and a reply's `historian`

    def write(self, rows: Sequence[HistoryRow]) -> int:
        """Store rows in one transaction (all or none); returns how many were new. HistoryDbError if refused."""
        raise NotImplementedError

    def prune(self, before_ns: int) -> int:
        """Delete every row older than before_ns; returns how many."""
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def _read(self, sql: str, parameters: tuple = ()) -> list[tuple]:
        raise NotImplementedError

    def latest(self, switch_id: str, kind: str, since_ns: int | None, until_ns: int | None,
               limit: int) -> tuple[list[bytes], bool]:
        """The payloads of the latest `limit` rows of one switch and kind with since_ns <= t_ns < until_ns,
        oldest first, and whether older rows in the window were left out."""
        rows = self._read(LATEST_SQL.format(table=self.table, payload=self.payload_bytes),
                          (switch_id, kind, since_ns or 0, MAX_TIME_NS if until_ns is None else until_ns, limit + 1))
        return [payload for (payload,) in reversed(rows[:limit])], len(rows) > limit

    def throw_indices(self, switch_id: str, kind: str) -> list[int]:
        """The throw index of every row of one switch and kind (a throw stored twice, twice)."""
        return [index for (index,) in self._read(THROW_INDICES_SQL.format(table=self.table), (switch_id, kind))]

    def holds(self, switch_id: str) -> bool:
        return bool(self._read(HOLDS_SQL.format(table=self.table), (switch_id,)))

    def switches(self) -> list[str]:
        """Every switch with a row, from the index alone."""
        return [switch_id for (switch_id,) in self._read(SWITCHES_SQL.format(table=self.table))]

    def count(self) -> int:
        return self._read(COUNT_SQL.format(table=self.table))[0][0]

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def is_url(target: str | os.PathLike[str]) -> bool:
    """Whether a --db value names a server (anything with a scheme) rather than a file."""
    return "://" in str(target)


def masked(url: str) -> str:
    """The URL with its password, if any, shown as ***: safe for logs and error messages."""
    url = re.sub(r"(://[^:@/?]*):[^@/?]*@", r"\1:***@", url)
    return re.sub(r"(password=)[^&]*", r"\1***", url)


def open_history(target: str | os.PathLike[str], *, check: bool = True, create: bool = True) -> HistoryStore:
    """The store a --db value names: a PostgreSQL database for a postgresql:// URL, else an SQLite file.
    check=True creates the tables if missing (create) or checks them; check=False joins a store already checked,
    for a second connection. HistoryDbError, in one line, if it cannot be used."""
    if not is_url(target):
        from railswitch.services.adapters.history_db import HistoryDb

        return HistoryDb(target, check=check, create=create)
    url = str(target)
    if not url.startswith(URL_SCHEMES):
        raise HistoryDbError(f"cannot use history database {masked(url)}: a URL must start with postgresql:// "
                             "(a path means an SQLite file)")
    try:
        from railswitch.services.adapters.history_pg import PostgresHistory
    except ImportError as error:
        if not (error.name or "").startswith("psycopg"):
            raise
        raise HistoryDbError(f"history database {masked(url)} needs psycopg, which is not installed: "
                             "pip install 'railswitch[postgres]'") from None
    return PostgresHistory(url, check=check, create=create)
