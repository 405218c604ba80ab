"""History over the bus: the historian's query server (a queryable answered in a thread of its own) and the
client's get that gathers every historian's replies."""
from __future__ import annotations

import logging
import queue
import threading

import zenoh

from railswitch.schemas import HISTORY_KEYS, HistoryQuery, HistoryReply, decode, history_key
from railswitch.services.ports import HistoryAnswering

log = logging.getLogger("railswitch.historian")

POLL_S = 0.2  # how long the server's thread waits for a query before it looks whether it was closed


class QueryServer:
    """Answers history queries in a thread of its own with its own connection to the store; the queryable's
    callback only queues the query."""

    def __init__(self, session: zenoh.Session, answers: HistoryAnswering):
        self.answers = answers
        self._closed = threading.Event()
        self._queries: queue.SimpleQueue[zenoh.Query] = queue.SimpleQueue()
        self._queryable = session.declare_queryable(HISTORY_KEYS, self._queries.put)
        self._thread = threading.Thread(target=self._serve, name="history-queries", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._closed.is_set():
            try:
                query = self._queries.get(timeout=POLL_S)
            except queue.Empty:
                continue
            with query:  # leaving it sends the final reply: the client's get ends
                try:
                    self.respond(query)
                except zenoh.ZError as error:  # the client went away, say: the next query is answered all the same
                    log.warning("could not answer a history query on %s: %s", query.key_expr, error)

    def respond(self, query: zenoh.Query) -> None:
        key = str(query.key_expr)
        asked = zenoh.KeyExpr(key)
        try:
            answer = self.answers.answer(key, dict(query.parameters),
                                         lambda switch_id: asked.intersects(zenoh.KeyExpr(history_key(switch_id))))
        except OSError as error:  # the store could not be read: say so to the client, keep serving
            log.error("%s", error)
            query.reply_err(str(error).encode(), encoding=zenoh.Encoding.TEXT_PLAIN)
            return
        if answer.error is not None:
            query.reply_err(answer.error.encode(), encoding=zenoh.Encoding.TEXT_PLAIN)
        for reply_key, payload in answer.replies:
            query.reply(reply_key, payload, encoding=zenoh.Encoding.APPLICATION_JSON)

    def __enter__(self) -> QueryServer:
        return self

    def __exit__(self, *exc) -> None:
        """No new queries; the one being answered is finished first."""
        self._queryable.undeclare()
        self._closed.set()
        self._thread.join()


def ask_historians(session: zenoh.Session, key: str, query: HistoryQuery,
                   timeout_s: float) -> tuple[list[HistoryReply], list[str]]:
    """Every historian's replies to a query on key (consolidation off: every reply comes back), and the error
    replies' texts."""
    found, errors = [], []
    for reply in session.get(f"{key}?{query.parameters()}", target=zenoh.QueryTarget.ALL,
                             consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout_s):
        if reply.ok is not None:
            found.append(decode(HistoryReply, reply.ok.payload.to_bytes()))
        else:
            errors.append(reply.err.payload.to_string())
    return found, errors
