"""The historian's core: diagnoses and health messages into the history store (an SQLite file or a PostgreSQL
database) batch by batch, old rows pruned, and history queries answered from the store.

Writing and answering each hold their own connection to the store (SQLite's WAL lets queries read while a
batch is written), so the service runs them in two threads. Which switches are this historian's is its
ownership (services/core/shards.py): a fixed shard, or the elastic membership of the live historians. Elastic,
every historian reads every switch's messages, writes its own and holds the others' for a grace period, so the
rows of a historian that dies before writing them are written by whoever owns their switches next. A query for a
switch is answered by whichever historian holds rows of it, so switches that changed hands still answer for what
was stored before; merge_replies makes one history of them, a row two historians hold counted once.
"""
from __future__ import annotations

import json
import logging
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from railswitch.schemas import (
    CONTRACT_VERSION,
    HISTORY_KINDS,
    Alarm,
    Diagnosis,
    HistoryQuery,
    HistoryReply,
    Message,
    check_switch_id,
    decode,
    history_key,
)
from railswitch.schemas.history import MAX_TIME_NS
from railswitch.services.ports import History, HistoryDbError, HistoryRow, Received
from railswitch.services.core.intake import Intake
from railswitch.services.core.shards import FixedShard, Ownership

log = logging.getLogger("railswitch.historian")

MAX_PENDING = 100_000  # rows kept in memory while the store cannot be written, oldest dropped first
DAY_NS = 86_400 * 10**9
# Longer than a historian's death takes to be seen (at once for a closed connection, its session lease, 3 s, for
# a silent one) plus its loop's poll: what its owner may not have written yet is still held by the others then.
HOLD_S = 10.0


class HeldRows:
    """Rows of other historians' switches, each with its owner when it arrived, for hold_s: if the owner leaves the
    live set meanwhile, the rows go to whoever owns their switches now."""

    def __init__(self, hold_s: float = HOLD_S):
        self.hold_s = hold_s
        self._rows: deque[tuple[float, str, HistoryRow]] = deque()  # arrival (monotonic s), owner, row; in order

    def __len__(self) -> int:
        return len(self._rows)

    def hold(self, row: HistoryRow, owner: str, arrived_s: float) -> None:
        self._rows.append((arrived_s, owner, row))

    def orphaned(self, members: frozenset[str]) -> list[tuple[float, HistoryRow]]:
        """(arrival, row) of the held rows whose owner is no longer a member, in arrival order; no longer held."""
        orphans = [(at_s, row) for at_s, owner, row in self._rows if owner not in members]
        self._rows = deque(entry for entry in self._rows if entry[1] in members)
        return orphans

    def expire(self, now_s: float) -> None:
        while self._rows and self._rows[0][0] < now_s - self.hold_s:
            self._rows.popleft()


def message_time(message: Message) -> int:
    """The time a message is kept and looked up by: a diagnosis its throw's end, a health message and an alarm change
    their t_ns."""
    return message.t_end_ns if isinstance(message, Diagnosis) else message.t_ns


def message_index(message: Message) -> int:
    """What tells a switch's rows of one kind at one time apart: a throw's index, an alarm change's number (several
    alarms change at one throw's end)."""
    return message.sequence if isinstance(message, Alarm) else message.throw_index


class Historian:
    """Turns received payloads into history rows of this historian's switches and writes each batch in one
    transaction. Junk is counted per reason by the intake and never stored."""

    def __init__(self, db: History, ownership: Ownership | None = None,
                 clock: Callable[[], float] = time.monotonic):
        """Without ownership every switch is this historian's."""
        self.db = db
        self.ownership = ownership or FixedShard((1, 1), "this historian")
        self.intake = Intake(log, HISTORY_KINDS, self.ownership.serves)
        self.held = HeldRows()
        self.clock = clock
        self._taken: list[HistoryRow] = []  # held rows of a historian that left, now this one's: in the next write
        self.taken_over = 0
        self.written = 0
        self.duplicates = 0
        self.batches = 0
        self.pruned = 0
        self.dropped = 0
        self.write_failures = 0
        self._pending: list[HistoryRow] = []

    def write(self, batch: Sequence[Received]) -> int:
        """Store the valid messages of a batch (and any left over from a failed write); returns rows written.

        A store that cannot be written (a full disk, a database server gone) keeps the rows in memory and is tried
        again with the next batch: the service goes on, and nothing is lost unless MAX_PENDING rows pile up."""
        self.held.expire(self.clock())
        rows = self._pending + self._taken + [row for item in batch if (row := self.row(item)) is not None]
        self._taken = []
        if not rows:
            return 0
        try:
            new = self.db.write(rows)
        except HistoryDbError as error:
            return self._keep(rows, str(error))
        if self._pending:
            log.info("the history store takes rows again; %d kept in memory are written", len(self._pending))
        self._pending = []
        self.batches += 1
        self.written += new
        self.duplicates += len(rows) - new
        return new

    def _keep(self, rows: list[HistoryRow], reason: str) -> int:
        if self.write_failures == 0 or not self._pending:
            log.error("cannot write the history store (%s); keeping %d rows in memory and retrying", reason, len(rows))
        self.write_failures += 1
        self.dropped += max(0, len(rows) - MAX_PENDING)
        self._pending = rows[-MAX_PENDING:]
        return 0

    def row(self, item: Received) -> HistoryRow | None:
        """The history row of a received payload, or None (counted when it was junk)."""
        read = self.intake.read(item)
        if read is None:
            return None
        message = read.message
        kind = item.key.rsplit("/", 1)[1]
        t_ns = message_time(message)
        index = message_index(message)
        if t_ns > MAX_TIME_NS or index > MAX_TIME_NS:
            return self.intake.reject(f"{kind}: time or throw index beyond 64 bits", item.key)
        row = HistoryRow(message.switch_id, kind, index, t_ns, read.encoded.decode())
        owner = self.ownership.owner(message.switch_id)
        if owner == self.ownership.me:
            return row
        if owner is not None:
            self.held.hold(row, owner, item.arrived_s)
        return None

    def rebalance(self) -> int:
        """After the live set changed: the held rows of a historian that left and whose switches are this one's
        now are written with the next batch, the rest held for their new owners; returns how many were taken."""
        taken = 0
        for arrived_s, row in self.held.orphaned(self.ownership.members):
            owner = self.ownership.owner(row.switch_id)
            if owner == self.ownership.me:
                self._taken.append(row)
                taken += 1
            elif owner is not None:
                self.held.hold(row, owner, arrived_s)
        if taken:
            log.info("%d rows of a historian that left taken over", taken)
        self.taken_over += taken
        return taken

    def prune(self, now_ns: int, keep_days: float) -> int:
        """Delete the rows older than keep_days before now_ns (by each message's own time)."""
        try:
            deleted = self.db.prune(now_ns - int(keep_days * DAY_NS))
        except HistoryDbError as error:
            log.error("%s; trying again at the next pruning", error)
            return 0
        self.pruned += deleted
        if deleted:
            log.info("pruned %d rows older than %g days", deleted, keep_days)
        return deleted

    def counters(self) -> dict[str, int]:
        return {"written": self.written, "duplicates": self.duplicates, "batches": self.batches,
                "pruned": self.pruned, "pending": len(self._pending), "dropped": self.dropped,
                "write_failures": self.write_failures, "taken_over": self.taken_over, "held": len(self.held),
                "members": len(self.ownership.members)}


@dataclass
class Retention:
    """When to prune: at start-up and every `every_s` seconds after, if rows are kept for `keep_days` only."""

    keep_days: float | None
    every_s: float = 3600.0
    _next_s: float = float("-inf")

    def due(self, now_s: float) -> bool:
        if self.keep_days is None or now_s < self._next_s:
            return False
        self._next_s = now_s + self.every_s
        return True


@dataclass(frozen=True)
class Answer:
    """What a history query gets: one reply (key, JSON) per switch, or an error naming the problem."""

    replies: list[tuple[str, bytes]] = field(default_factory=list)
    error: str | None = None

    def decoded(self) -> list[HistoryReply]:
        """The replies as a client reads them (a store read directly answers as a historian would)."""
        return [decode(HistoryReply, payload) for _, payload in self.replies]


def switch_in_key(key: str) -> str | None:
    """The switch a concrete key railswitch/<id>/history names; None for a key with wildcards (or another
    form), which asks for every switch it matches. ValueError for a concrete chunk that is no switch id."""
    parts = key.split("/")
    if len(parts) != 3 or any(c in key for c in "*$"):
        return None
    return check_switch_id(parts[1])


def reply_payload(switch_id: str, historian: str, diagnoses: list[bytes], health: list[bytes], truncated: bool,
                  alarms: list[bytes] = ()) -> bytes:
    """A HistoryReply's JSON spliced from stored payloads: each was a validated message's JSON when it was
    written, so decoding and encoding it again would only cost time (benchmarks/historian.py)."""
    head = json.dumps({"contract": CONTRACT_VERSION, "switch_id": switch_id, "historian": historian,
                       "truncated": truncated}, separators=(",", ":"))
    return b"".join((head[:-1].encode(), b',"diagnoses":[', b",".join(diagnoses), b'],"health":[', b",".join(health),
                     b'],"alarms":[', b",".join(alarms), b"]}"))


class HistoryAnswers:
    """Answers history queries from its own connection to the store. Bad queries are counted per reason and
    logged once per reason."""

    def __init__(self, db: History, is_mine: Callable[[str], bool], historian: str):
        self.db = db
        self.is_mine = is_mine
        self.historian = historian
        self.answered = 0
        self.refused: Counter[str] = Counter()

    def answer(self, key: str, parameters: Mapping[str, str], matches: Callable[[str], bool]) -> Answer:
        """The answer to a query on `key` (matches(switch_id): whether a switch's history key intersects it).

        A concrete key this historian holds no rows of is refused as unknown only if the switch is its own;
        otherwise another historian answers, and this one stays silent (no replies, no error)."""
        try:
            query = HistoryQuery.from_parameters(parameters)
        except ValueError as error:
            return self._refuse("parameters", str(error), key)
        try:
            switch_id = switch_in_key(key)
        except ValueError as error:
            return self._refuse("switch id", str(error), key)
        return self.answer_query(query, switch_id, matches)

    def answer_query(self, query: HistoryQuery, switch_id: str | None,
                     matches: Callable[[str], bool] = lambda switch_id: True) -> Answer:
        """The answer for one switch, or (switch_id None) for every switch held that `matches`."""
        if switch_id is None:
            switches = {s: self._found(s, query) for s in self.db.switches() if matches(s)}
        else:
            found = self._found(switch_id, query)  # a switch with rows in the window holds rows: no query to ask that
            if any(payloads for payloads, _ in found.values()) or self.db.holds(switch_id):
                switches = {switch_id: found}
            elif self.is_mine(switch_id):
                return self._refuse("unknown switch", f"unknown switch {switch_id}: no history stored",
                                    history_key(switch_id))
            else:
                switches = {}
        self.answered += 1
        return Answer([(history_key(s), self._reply(s, found)) for s, found in switches.items()])

    def _found(self, switch_id: str, query: HistoryQuery) -> dict[str, tuple[list[bytes], bool]]:
        """Per kind, the payloads the query asks for and whether older ones in its window were left out."""
        found = {kind: ([], False) for kind in HISTORY_KINDS}
        for kind in query.kinds():
            found[kind] = self.db.latest(switch_id, kind, query.since_ns, query.until_ns, query.limit)
        return found

    def _reply(self, switch_id: str, found: dict[str, tuple[list[bytes], bool]]) -> bytes:
        return reply_payload(switch_id, self.historian, found["diagnosis"][0], found["health"][0],
                             any(truncated for _, truncated in found.values()), found["alarm"][0])

    def _refuse(self, kind: str, reason: str, key: str) -> Answer:
        """An error answer; one log line per kind of problem, not one per query."""
        self.refused[kind] += 1
        if self.refused[kind] == 1:
            log.warning("refused a history query on %s: %s (further ones are counted)", key, reason)
        return Answer(error=reason)

    def counters(self) -> dict[str, int]:
        return {"queries": self.answered, "queries_refused": sum(self.refused.values())}


def merge_replies(replies: Sequence[HistoryReply], limit: int) -> HistoryReply:
    """One switch's history from the replies of every historian that held some of it (a switch whose shard
    changed hands), oldest first, the latest `limit` of each kind; a message two of them hold counts once."""
    def unique(messages: list) -> list:
        by_key = {(message_time(m), message_index(m)): m for m in messages}
        return [by_key[k] for k in sorted(by_key)]

    diagnoses = unique([d for r in replies for d in r.diagnoses])
    health = unique([h for r in replies for h in r.health])
    alarms = unique([a for r in replies for a in r.alarms])
    truncated = any(r.truncated for r in replies) or max(map(len, (diagnoses, health, alarms))) > limit
    return HistoryReply(switch_id=replies[0].switch_id, historian=", ".join(r.historian for r in replies),
                        truncated=truncated, diagnoses=diagnoses[-limit:], health=health[-limit:],
                        alarms=alarms[-limit:])
