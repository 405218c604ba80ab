"""What the application (services/core) and the outside systems (services/adapters) share, so that neither imports
the other: the values that cross between them, and the small interfaces the core needs, which the adapters
implement and the commands wire (docs/architecture.md)."""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np

from railswitch.schemas import Message


class Received(NamedTuple):
    """One raw sample as it arrived: key, payload and local arrival time (monotonic seconds)."""

    key: str
    payload: bytes
    arrived_s: float


class RecordedMessage(NamedTuple):
    """One decoded message of a recording, with the channel it came from."""

    key: str
    kind: str
    switch_id: str
    message: Message
    log_time_ns: int


class HistoryRow(NamedTuple):
    """One stored message: its switch, kind (diagnosis or health), throw, time (ns) and JSON."""

    switch_id: str
    kind: str
    throw_index: int
    t_ns: int
    payload: str


class HistoryDbError(OSError):
    """A history database cannot be used; the message is one line."""


class DeliveryFailed(Exception):
    """A POST that did not deliver; `kind` names the failure in a few words (counted and logged per kind),
    `permanent` when trying again cannot help (the server refused the body or the URL)."""

    def __init__(self, kind: str, permanent: bool = False):
        super().__init__(kind)
        self.kind = kind
        self.permanent = permanent


class Publisher(Protocol):
    """Puts messages on the bus (zenoh_bus.Publishers)."""

    def put(self, key: str, message: Message | bytes) -> None: ...


class RecordingSink(Protocol):
    """Appends messages to a recording (recordings.RecordingWriter)."""

    def write(self, key: str, message: Message, log_time_ns: int | None = None,
              payload: bytes | None = None) -> None: ...


class History(Protocol):
    """Rows by switch, kind and time (history_store.HistoryStore: an SQLite file or a PostgreSQL database)."""

    name: str

    def write(self, rows: Sequence[HistoryRow]) -> int: ...

    def prune(self, before_ns: int) -> int: ...

    def latest(self, switch_id: str, kind: str, since_ns: int | None, until_ns: int | None,
               limit: int) -> tuple[list[str], bool]: ...

    def holds(self, switch_id: str) -> bool: ...

    def switches(self) -> list[str]: ...


class IntakeCounts(Protocol):
    """What a service's intake (core/intake.py) counted, as its status reports it."""

    received: int
    rejected: Counter[str]
    ignored: Counter[str]


class Members(Protocol):
    """The live instances of a service, kept from the bus's liveliness (core/membership.py Membership)."""

    me: str

    @property
    def members(self) -> frozenset[str]: ...

    def join(self, member: str, at_s: float = ...) -> bool: ...

    def leave(self, member: str) -> bool: ...


class Answered(Protocol):
    """A history query's answer (core/historian.py Answer): one reply (key, JSON) per switch, or an error."""

    replies: list[tuple[str, bytes]]
    error: str | None


class HistoryAnswering(Protocol):
    """Answers history queries (core/historian.py HistoryAnswers); `matches(switch_id)`: whether that switch's
    history key intersects the query's."""

    def answer(self, key: str, parameters: Mapping[str, str], matches: Callable[[str], bool]) -> Answered: ...


class StoredRail(Protocol):
    """A reduced model's stored document as the diagnosis reads it (model_store.StoredModel)."""

    representation: Any  # models/reduced/rail_models.py Representation
    weights: np.ndarray
    bearing_port: dict
    healthy_gains: dict
    error_model: dict
    model_weight: float
    healthy_check: dict
    path: Path


class ModelSource(Protocol):
    """Where the reduced models' documents come from (the module services/adapters/model_store.py is one)."""

    def load(self, name: str) -> StoredRail: ...
