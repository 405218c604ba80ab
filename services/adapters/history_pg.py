"""The historian's shared store in PostgreSQL (psycopg 3): the rows of the SQLite file, in a server that several
historians write at once and Grafana, psql or pandas read.

Table `railswitch_history` holds what SQLite's `history` does, keyed by (switch_id, kind, t_ns, throw_index):
the key makes a message that two historians (or one, twice) write one row, and serves a switch's latest rows of
a kind. A row stays whole in its page up to WHOLE_ROW bytes (toast_tuple_target; a diagnosis is some 4 kB) rather
than having its payload compressed, or moved to the TOAST table, beyond 2 kB, PostgreSQL's default: reading a
switch's latest 1000 diagnoses then fetches no TOAST chunks and decompresses nothing, which took most of such a
query's time. `railswitch_schema_version` says which layout the database has. Our own names leave the server's
other tables alone. A batch is copied into a temporary table and inserted from there in key order with ON CONFLICT
DO NOTHING: one round trip for the rows, and two historians writing the same rows take their locks in the same
order, so neither waits for the other in a deadlock. The batch is copied in COPY's binary format: the server takes
each payload as it comes, where the text format has it scan every character for escapes. The temporary table keeps
rows whole too: a value it compressed would go into the history compressed, and compressing every diagnosis took
most of a write's time.

A lost connection raises HistoryDbError and is opened again by the next call, so the historian keeps a batch it
could not write and writes it once the server is back.
"""
from __future__ import annotations

import logging
from collections.abc import Sequence

import psycopg
from psycopg.conninfo import conninfo_to_dict, make_conninfo

from railswitch.services.adapters.history_store import (COLUMNS, KIND_CHECK, PRUNE_SQL, HistoryDbError, HistoryRow,
                                                        HistoryStore, masked)

# 2: alarm changes are kept too (the kinds' check names them). A database of version 1 is read as it is and migrated
# by the first historian that opens it, under the schema lock.
log = logging.getLogger("railswitch.historian")

SCHEMA_VERSION = 2
READABLE_VERSIONS = (1, SCHEMA_VERSION)
TABLE = "railswitch_history"
VERSION_TABLE = "railswitch_schema_version"
WHOLE_ROW = 8160  # bytes: a row up to this size stays whole and uncompressed in its page (toast_tuple_target)
INCOMING = "railswitch_incoming"  # a connection's own temporary table, a batch on its way in
INCOMING_TYPES = ("text", "text", "int8", "int8", "text")  # its columns, in COLUMNS' order, for a binary COPY
SCHEMA = f"""
CREATE TABLE {VERSION_TABLE} (version integer NOT NULL);
INSERT INTO {VERSION_TABLE} VALUES ({SCHEMA_VERSION});
CREATE TABLE {TABLE} (
    switch_id text NOT NULL,
    kind text NOT NULL {KIND_CHECK},
    throw_index bigint NOT NULL,
    t_ns bigint NOT NULL,
    payload text NOT NULL,
    PRIMARY KEY (switch_id, kind, t_ns, throw_index)
) WITH (toast_tuple_target = {WHOLE_ROW})
"""
MIGRATIONS = {1: f"""
ALTER TABLE {TABLE} DROP CONSTRAINT IF EXISTS {TABLE}_kind_check;
ALTER TABLE {TABLE} ADD CONSTRAINT {TABLE}_kind_check {KIND_CHECK};
UPDATE {VERSION_TABLE} SET version = {SCHEMA_VERSION};
"""}
INSERT = (f"INSERT INTO {TABLE} ({COLUMNS}) SELECT {COLUMNS} FROM {INCOMING} "
          "ORDER BY switch_id, kind, t_ns, throw_index ON CONFLICT DO NOTHING")
# Historians starting at once create the tables one after the other: the first creates, the others check.
SCHEMA_LOCK = 0x7261696C  # "rail", the advisory lock key
CONNECT_TIMEOUT_S = 10  # unless the URL says otherwise: a server that does not answer is an error, not a hang


class PostgresHistory(HistoryStore):
    """One connection to a PostgreSQL history. The first (check=True) creates or checks the tables; further ones
    (check=False, one per thread) join a database already checked."""

    table = TABLE
    payload_bytes = "convert_to(payload, 'UTF8')"  # bytea, whose binary format is the bytes themselves

    def __init__(self, url: str, *, check: bool = True, create: bool = True):
        self.name = masked(url)
        self._db: psycopg.Connection | None = None
        try:
            settings = conninfo_to_dict(url)
        except psycopg.Error as error:
            raise self._error("use", error) from None
        settings.setdefault("connect_timeout", CONNECT_TIMEOUT_S)
        self._conninfo = make_conninfo(**settings)
        self._incoming_ready = False
        self._connection()
        if check:
            self._check(create)

    def _connection(self) -> psycopg.Connection:
        """The open connection, or a new one where there is none (never opened, or lost)."""
        if self._db is None or self._db.closed or self._db.broken:
            try:
                self._db = psycopg.connect(self._conninfo, autocommit=True)
            except psycopg.Error as error:
                self._db = None
                raise self._error("connect to", error) from None
            self._incoming_ready = False
        return self._db

    def _check(self, create: bool) -> None:
        """Create the tables in a database without them (create), or refuse a layout that is not ours."""
        try:
            db = self._connection()
            with db.transaction():
                db.execute("SELECT pg_advisory_xact_lock(%s)", (SCHEMA_LOCK,))
                found = [name for name in (TABLE, VERSION_TABLE)
                         if db.execute("SELECT to_regclass(%s)", (name,)).fetchone()[0] is not None]
                if not found and create:
                    db.execute(SCHEMA)
                    return
                version = db.execute(f"SELECT max(version) FROM {VERSION_TABLE}").fetchone()[0] \
                    if len(found) == 2 else None
                if create and version in MIGRATIONS:
                    db.execute(MIGRATIONS[version])
                    log.info("%s: history schema version %d migrated to %d", self.name, version, SCHEMA_VERSION)
                    version = SCHEMA_VERSION
        except psycopg.Error as error:
            self.close()
            raise self._error("check", error) from None
        if not found:
            self.close()
            raise HistoryDbError(f"history database {self.name} holds no railswitch history (a historian given "
                                 "this URL creates it)")
        if len(found) == 1:
            self.close()
            raise HistoryDbError(f"{self.name} is not a railswitch history database (it has {found[0]} but not "
                                 f"{({TABLE, VERSION_TABLE} - set(found)).pop()})")
        if version not in READABLE_VERSIONS:
            self.close()
            raise HistoryDbError(f"{self.name} has history schema version {version}; this railswitch reads "
                                 f"version {SCHEMA_VERSION}")

    def write(self, rows: Sequence[HistoryRow]) -> int:
        """Store rows in one transaction (all or none); returns how many were new (the rest were stored before,
        by this historian or another). HistoryDbError when the server cannot take them (gone, full)."""
        try:
            db = self._connection()
            if not self._incoming_ready:
                db.execute(f"CREATE TEMPORARY TABLE IF NOT EXISTS {INCOMING} (switch_id text, kind text, "
                           f"throw_index bigint, t_ns bigint, payload text) WITH (toast_tuple_target = {WHOLE_ROW}) "
                           "ON COMMIT DELETE ROWS")
                self._incoming_ready = True
            with db.transaction(), db.cursor() as cursor:
                with cursor.copy(f"COPY {INCOMING} ({COLUMNS}) FROM STDIN (FORMAT BINARY)") as copy:
                    copy.set_types(INCOMING_TYPES)
                    for row in rows:
                        copy.write_row(row)
                cursor.execute(INSERT)
                return cursor.rowcount
        except psycopg.Error as error:
            raise self._error("write", error) from None

    def _read(self, sql: str, parameters: tuple = ()) -> list[tuple]:
        try:
            with self._connection().cursor(binary=True) as cursor:  # values as the server holds them, unescaped
                return cursor.execute(sql.replace("?", "%s"), parameters).fetchall()
        except psycopg.Error as error:
            raise self._error("read", error) from None

    def prune(self, before_ns: int) -> int:
        """Delete every row older than before_ns, switch by switch along the key, each switch in a transaction of
        its own (autovacuum hands the space back); returns the rows deleted."""
        deleted = 0
        try:
            for switch_id in self.switches():
                deleted += self._connection().execute(PRUNE_SQL.format(table=TABLE).replace("?", "%s"),
                                                      (switch_id, before_ns)).rowcount
        except psycopg.Error as error:
            raise self._error("prune", error) from None
        return deleted

    def _error(self, doing: str, error: psycopg.Error) -> HistoryDbError:
        """One line naming the database (password masked) and what went wrong; a lost connection is dropped,
        to be opened again by the next call."""
        if isinstance(error, psycopg.OperationalError) and self._db is not None:
            self.close()
        lines = [line.strip() for line in str(error).splitlines() if line.strip()]
        reason = masked(lines[0]) if lines else type(error).__name__
        return HistoryDbError(f"cannot {doing} history database {self.name}: {reason}")

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None
