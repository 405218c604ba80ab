"""Historians as real processes, the messages they keep and an outside client's history queries, for the
historian's integration and end-to-end tests."""
from __future__ import annotations

from pathlib import Path

import zenoh

from railswitch.schemas import Alarm, Diagnosis, HistoryReply, SwitchHealth, decode, encode, key_expr
from railswitch.services.adapters.history_store import HistoryRow
from railswitch.services.adapters.processes import services_alive
from tests.live import ServiceProcesses, wait_for, wait_ready

T0_NS = 1_700_000_000 * 10**9  # November 2023
THROW_NS = 600 * 10**9  # a throw every ten minutes


def throw_end(throw: int) -> int:
    return T0_NS + throw * THROW_NS


def diagnosis(switch_id: str, throw: int) -> Diagnosis:
    end = throw_end(throw)
    return Diagnosis(switch_id=switch_id, throw_index=throw, direction="left_to_right" if throw % 2 == 0 else
                     "right_to_left", t_start_ns=end - 7 * 10**9, t_end_ns=end, model="poly", decision="nominal",
                     latency_ms=80.0)


def health(switch_id: str, throw: int) -> SwitchHealth:
    return SwitchHealth(switch_id=switch_id, throw_index=throw, t_ns=throw_end(throw), model="poly", state="ok")


def alarm(switch_id: str, sequence: int, throw: int = 3) -> Alarm:
    """An alarm change at a throw's end, as a diagnoser publishes it."""
    return Alarm(switch_id=switch_id, alarm="left_bolt", change="raised" if sequence == 1 else "acknowledged",
                 severity="medium", cause="fault", text="left_bolt: left_bolt_offset 0.04 m",
                 parameters={"left_bolt_offset": 0.04}, first_throw=throw, last_throw=throw, count=1, active=True,
                 acknowledged=sequence > 1, sequence=sequence, t_ns=throw_end(throw), model="poly")


def stored(switch_id: str, kind: str, throw: int) -> HistoryRow:
    """The row a historian keeps of a diagnosis or health message of a throw."""
    message = diagnosis(switch_id, throw) if kind == "diagnosis" else health(switch_id, throw)
    return HistoryRow(switch_id, kind, throw, throw_end(throw), encode(message).decode())


def stored_alarm(switch_id: str, sequence: int) -> HistoryRow:
    message = alarm(switch_id, sequence)
    return HistoryRow(switch_id, "alarm", sequence, message.t_ns, encode(message).decode())


def publish_throws(session: zenoh.Session, switches: list[str], throws: range) -> None:
    """A diagnosis and a health message per switch and throw, as a diagnoser publishes them."""
    for throw in throws:
        for switch_id in switches:
            session.put(key_expr(switch_id, "diagnosis"), encode(diagnosis(switch_id, throw)))
            session.put(key_expr(switch_id, "health"), encode(health(switch_id, throw)))


def ask(session: zenoh.Session, selector: str, timeout_s: float = 10.0) -> tuple[list[HistoryReply], list[str]]:
    """Every historian's replies to one get (consolidation off), and the error replies' texts."""
    replies, errors = [], []
    for reply in session.get(selector, target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE,
                             timeout=timeout_s):
        if reply.ok is not None:
            replies.append(decode(HistoryReply, reply.ok.payload.to_bytes()))
        else:
            errors.append(reply.err.payload.to_string())
    return replies, errors


def rows(replies: list[HistoryReply]) -> list[tuple[str, str, int]]:
    """(switch, kind, throw) of every message in the replies, repeats kept."""
    return [(r.switch_id, "diagnosis", d.throw_index) for r in replies for d in r.diagnoses] + [
        (r.switch_id, "health", h.throw_index) for r in replies for h in r.health]


def wait_for_rows(session: zenoh.Session, count: int, timeout_s: float = 60.0) -> None:
    """Until the historians answer `count` messages in all (a row answered is a committed row)."""
    wait_for(lambda: len(rows(ask(session, "railswitch/*/history")[0])) >= count, timeout_s, f"{count} rows kept")


def start_historian(services: ServiceProcesses, session: zenoh.Session, endpoint: str, db: Path, *args: str):
    """A historian process on `db`, ready (its token is declared once it answers queries).

    A historian just killed leaves its token on the bus until the router notices; counted as ready, it let a
    test publish before the new one had subscribed (under load, in CI). So first its token must go."""
    running = sum(1 for name, _, p in services.started if name == "historian" and p.poll() is None)
    wait_for(lambda: services_alive(session)["historian"] <= running, 30, "stopped historians' tokens to go")
    process = services.start("historian", "--connect", endpoint, "--db", str(db), "--status-interval", "0.5", *args)
    wait_ready(session, services, 60, historian=running + 1)
    return process
