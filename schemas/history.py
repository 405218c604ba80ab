"""A switch's history as the historian answers for it (docs/contracts.md section 3, History).

A Zenoh `get` on railswitch/<id>/history (or a wildcard such as railswitch/*/history) with the
parameters of HistoryQuery is answered by the historian that holds the switch with one HistoryReply per
switch; a malformed query gets an error reply naming the problem.
"""
from __future__ import annotations

import re
from collections.abc import Mapping
from datetime import datetime, timedelta, timezone
from typing import Annotated, Literal, Self, get_args

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from railswitch.schemas.messages import KEY_PREFIX, Alarm, Diagnosis, Message, SwitchHealth, SwitchId, check_switch_id

HistoryKind = Literal["diagnosis", "health", "alarm"]
HISTORY_KINDS: tuple[str, ...] = get_args(HistoryKind)
HISTORY_KEYS = f"{KEY_PREFIX}/*/history"  # what a historian's queryable answers
DEFAULT_LIMIT = 1000  # rows of each kind when a query names no limit
MAX_LIMIT = 10_000  # rows of each kind one reply may carry (about 50 MB of JSON)
MAX_TIME_NS = 2**63 - 1  # SQLite integers are 64-bit signed: times up to the year 2262
QUERY_PARAMETERS = ("since", "until", "limit", "kind")
_EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)

TimeNs = Annotated[int, Field(ge=0, le=MAX_TIME_NS, description="nanoseconds since the Unix epoch")]


def history_key(switch_id: str) -> str:
    """The key expression a switch's history is asked for on: railswitch/<id>/history."""
    return f"{KEY_PREFIX}/{check_switch_id(switch_id)}/history"


def parse_time(text: str, name: str = "time") -> int:
    """Integer nanoseconds since the Unix epoch, or ISO-8601 (a date, or date and time; UTC unless it gives an
    offset); ValueError names the value and what is accepted."""
    text = text.strip()
    if re.fullmatch(r"[+-]?\d+", text):
        value = int(text)
    else:
        try:
            moment = datetime.fromisoformat(text)
        except ValueError:
            raise ValueError(f"{name} {text!r} is neither ISO-8601 (e.g. 2024-05-01T12:00:00Z) "
                             "nor integer nanoseconds since 1970") from None
        moment = moment if moment.tzinfo else moment.replace(tzinfo=timezone.utc)
        value = (moment - _EPOCH) // timedelta(microseconds=1) * 1000
    if not 0 <= value <= MAX_TIME_NS:
        raise ValueError(f"{name} {text} is outside the accepted range 1970-01-01 … 2262-04-11 "
                         f"(0 … {MAX_TIME_NS} ns)")
    return value


def format_time(t_ns: int) -> str:
    """ISO-8601 in UTC to the millisecond, as tables show times."""
    moment = _EPOCH + timedelta(microseconds=t_ns // 1000)
    return moment.isoformat(timespec="milliseconds").replace("+00:00", "Z")


class HistoryQuery(BaseModel):
    """What a history query asks for: rows with since_ns <= t_ns < until_ns (a diagnosis's t_ns is its throw's
    end), the latest `limit` of each kind, of one kind or both."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    since_ns: TimeNs | None = None
    until_ns: TimeNs | None = None
    limit: Annotated[int, Field(ge=1, le=MAX_LIMIT)] = DEFAULT_LIMIT
    kind: HistoryKind | None = None

    @model_validator(mode="after")
    def _check_window(self) -> Self:
        if self.since_ns is not None and self.until_ns is not None and self.since_ns >= self.until_ns:
            raise ValueError(f"since ({self.since_ns} ns) is not before until ({self.until_ns} ns)")
        return self

    @classmethod
    def from_parameters(cls, parameters: Mapping[str, str]) -> HistoryQuery:
        """The query a selector's parameters ask for; ValueError with one line naming the first problem."""
        unknown = [name for name in parameters if name not in QUERY_PARAMETERS]
        if unknown:
            raise ValueError(f"unknown query parameter {unknown[0]!r}; accepted: {', '.join(QUERY_PARAMETERS)}")
        values: dict[str, object] = {}
        for name in ("since", "until"):
            if name in parameters:
                values[f"{name}_ns"] = parse_time(parameters[name], name)
        if "limit" in parameters:
            values["limit"] = parse_limit(parameters["limit"])
        if "kind" in parameters:
            if parameters["kind"] not in HISTORY_KINDS:
                raise ValueError(f"kind {parameters['kind']!r} is not one of {', '.join(HISTORY_KINDS)}")
            values["kind"] = parameters["kind"]
        return cls.checked(**values)

    @classmethod
    def checked(cls, **values: object) -> HistoryQuery:
        """The query of these values; ValueError with one line naming the first problem."""
        try:
            return cls.model_validate(values)
        except ValidationError as error:
            first = error.errors(include_url=False)[0]
            where = ".".join(map(str, first["loc"]))
            message = first["msg"].removeprefix("Value error, ")
            raise ValueError(f"{where}: {message}" if where else message) from None

    def parameters(self) -> str:
        """The selector parameters that ask for this query (times in nanoseconds)."""
        values = {"since": self.since_ns, "until": self.until_ns, "limit": self.limit, "kind": self.kind}
        return ";".join(f"{name}={value}" for name, value in values.items() if value is not None)

    def kinds(self) -> tuple[str, ...]:
        return HISTORY_KINDS if self.kind is None else (self.kind,)


def parse_limit(text: str) -> int:
    """A row limit in 1 … MAX_LIMIT; ValueError names the value and the range."""
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"limit {text!r} is not an integer") from None
    if not 1 <= value <= MAX_LIMIT:
        raise ValueError(f"limit {text} is outside the accepted range 1 … {MAX_LIMIT}")
    return value


class HistoryReply(Message):
    """One switch's history, oldest first: its diagnoses, health messages and alarm changes in the query's window (the
    latest `limit` of each kind; `truncated` when older ones in the window were left out), and the historian that
    answered (<host>-<pid>). A reply without `alarms` came from a historian that did not keep them."""

    switch_id: SwitchId
    historian: str
    truncated: bool = False
    diagnoses: list[Diagnosis] = []
    health: list[SwitchHealth] = []
    alarms: list[Alarm] = []
