"""The one Zenoh helper: sessions from options or a config file, publishers, inboxes, liveliness, status.

Every live service opens its session here, so mode, endpoints, scouting and a Zenoh
config file (TLS, authentication, access control) behave the same everywhere.
Subscriber callbacks only queue raw payloads; services decode in their own loop.
"""
from __future__ import annotations

import json
import logging
import os
import queue
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import zenoh
import zenoh.ext

from railswitch.schemas import DEFAULT_ENDPOINT, KEY_PREFIX, SERVICE_PREFIX, Message, ServiceStatus, encode, recent_key
from railswitch.services.ports import IntakeCounts, Members, Received


log = logging.getLogger("railswitch.bus")

RETRY_S = 1.0
# An elastic service's session lease: one gone silent (hung, host down) leaves its live set after this, one killed
# at once (its connection closes).
ELASTIC_LEASE_MS = 3000
# Catch-up (docs/contracts.md section 3, Catching up): a publisher of throws keeps each switch's latest ones in a cache
# that subscribers which were down, or start late, ask for; a heartbeat after new samples lets a live subscriber
# notice a sample it missed and fetch it from the cache.
HEARTBEAT_S = 1.0
RECENT_QUERY_S = 5.0  # how long a diagnoser waits for the recorders' recent throws of a sample stream


class BusError(RuntimeError):
    """A session cannot be configured or opened; the message is one line."""


@dataclass(frozen=True)
class BusOptions:
    """How a service joins the bus.

    mode None keeps a config file's mode, else client. Without --connect a client or peer
    connects to DEFAULT_ENDPOINT unless the config file names endpoints; multicast scouting
    is off unless asked for, whatever the file says.
    """

    mode: str | None = None
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    config_file: str | None = None
    multicast_scouting: bool = False
    lease_ms: int | None = None  # how long the router waits on a silent session before dropping it (and its tokens)


def zenoh_config(options: BusOptions) -> zenoh.Config:
    """The session config: the file (if any), then the options on top."""
    if options.config_file:
        try:
            config = zenoh.Config.from_file(options.config_file)
        except (zenoh.ZError, OSError, ValueError) as error:
            raise BusError(f"cannot read Zenoh config {options.config_file}: {_one_line(error)}") from None
    else:
        config = zenoh.Config()
    mode = options.mode or (None if options.config_file else "client")
    if mode is not None:
        config.insert_json5("mode", json.dumps(mode))
    mode = json.loads(config.get_json("mode"))
    connect = list(options.connect)
    if not connect and mode != "router" and not json.loads(config.get_json("connect/endpoints") or "[]"):
        connect = [DEFAULT_ENDPOINT]
    try:
        if connect:
            config.insert_json5("connect/endpoints", json.dumps(connect))
        if options.listen:
            config.insert_json5("listen/endpoints", json.dumps(list(options.listen)))
    except zenoh.ZError as error:
        raise BusError(f"bad endpoint in {connect + list(options.listen)}: {_one_line(error)}") from None
    config.insert_json5("scouting/multicast/enabled", json.dumps(options.multicast_scouting))
    # Zenoh's shared memory (on by default for payloads over 3 KiB between processes of one host: records, diagnoses)
    # takes SIGINT and SIGTERM from Python when it starts, for its own cleanup at exit: a service that had received
    # one such payload never saw its stop signal and was killed with its file unfinished. The payloads are small.
    config.insert_json5("transport/shared_memory/enabled", "false")
    if options.lease_ms is not None:
        config.insert_json5("transport/link/tx/lease", str(options.lease_ms))
    if mode != "router":
        # Fail fast inside open() so that the retry loop below stays interruptible; once
        # connected, Zenoh itself reconnects when the router comes back.
        config.insert_json5("connect/timeout_ms", "2000")
        config.insert_json5("connect/exit_on_failure", "true")
    return config


def _one_line(error: BaseException) -> str:
    text = " ".join(str(error).split())
    return text.split(" at /")[0][:300]  # Zenoh appends the Rust source location


def open_session(options: BusOptions, *, retry: bool = True, wait_s: float | None = None,
                 stop: threading.Event | None = None) -> zenoh.Session:
    """Open a session, retrying every second while no router answers (until wait_s or stop)."""
    config = zenoh_config(options)
    deadline = None if wait_s is None else time.monotonic() + wait_s
    announced = False
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError as error:
            reason = _one_line(error)
            if not retry or "connect" not in reason.lower() or (deadline and time.monotonic() > deadline):
                raise BusError(f"cannot open a Zenoh session: {reason}") from None
            if not announced:
                log.warning("waiting for the bus (%s); retrying every %.0f s", reason, RETRY_S)
                announced = True
            if stop is None:
                time.sleep(RETRY_S)
            elif stop.wait(RETRY_S):
                raise BusError("stopped while waiting for the bus") from None
            config = zenoh_config(options)  # a config is consumed by open()


def instance_name(pid: int | None = None) -> str:
    """This process (or process pid of this host), as a key chunk: host-pid."""
    host = "".join(c if c.isalnum() or c in "-_" else "-" for c in socket.gethostname()) or "host"
    return f"{host}-{os.getpid() if pid is None else pid}"


def declare_service(session: zenoh.Session, name: str) -> zenoh.LivelinessToken:
    """Liveliness token railswitch/@service/<name>/<instance> (docs/contracts.md section 3)."""
    return session.liveliness().declare_token(f"{SERVICE_PREFIX}/{name}/{instance_name()}")


class LivelinessWatch:
    """The live instances of a service (tokens railswitch/@service/<name>/<instance>): those present now, then
    every join and leave, queued by the callback with its arrival time for the service's own loop. A session that
    dies takes its token with it: at once when its connection closes, after its lease when it goes silent."""

    def __init__(self, session: zenoh.Session, name: str):
        self._queue: queue.SimpleQueue[tuple[str, bool, float]] = queue.SimpleQueue()
        pattern = f"{SERVICE_PREFIX}/{name}/*"
        # Without history: a liveliness get right after a subscriber with history often comes back empty (zenoh
        # 1.10), and the tokens present would then arrive as joins of now rather than of before this one started.
        self._subscriber = session.liveliness().declare_subscriber(pattern, self._on_sample, history=False)
        self.present = {_last_chunk(reply.ok.key_expr) for reply in session.liveliness().get(pattern)
                        if reply.ok is not None}  # asked after subscribing, so no change falls in between

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self._queue.put((_last_chunk(sample.key_expr), sample.kind == zenoh.SampleKind.PUT, time.monotonic()))

    def changes(self) -> list[tuple[str, bool, float]]:
        """(instance, alive, arrival in monotonic s) of every change since the last call."""
        out = []
        while True:
            try:
                out.append(self._queue.get_nowait())
            except queue.Empty:
                return out


class LiveSet:
    """An elastic service's live set as seen on the bus: a Membership (services/core/membership.py) fed with the
    instances present at start-up and then every join and leave. The instance itself joins with joined(), once its
    token is declared; its own token seen gone is logged (cut off from the router) and does not remove it."""

    def __init__(self, session: zenoh.Session, service: str, membership: Members):
        self.service = service
        self.membership = membership
        self.watch = LivelinessWatch(session, service)
        self.cut_off = False
        for member in self.watch.present:
            membership.join(member)

    def joined(self) -> None:
        """This instance's token is on the bus: it serves what starts from now on."""
        self.membership.join(self.membership.me, time.monotonic())

    def poll(self) -> bool:
        """Apply the joins and leaves seen since the last call; whether the live set changed."""
        changed = False
        for member, alive, at_s in self.watch.changes():
            if member == self.membership.me and alive == self.cut_off:
                self.cut_off = not alive
                log.warning("this %s is %s", self.service, "cut off from the bus (its own token went); serving on"
                            if self.cut_off else "back on the bus")
            changed |= self.membership.join(member, at_s) if alive else self.membership.leave(member)
        if changed:
            log.info("live %ss: %d", self.service, len(self.membership.members))
        return changed


def _last_chunk(key: zenoh.KeyExpr) -> str:
    return str(key).rsplit("/", 1)[-1]


class QueryInbox:
    """A queryable whose callback only queues the queries; the service answers them in its own loop."""

    def __init__(self, session: zenoh.Session, key: str):
        self._queue: queue.SimpleQueue[zenoh.Query] = queue.SimpleQueue()
        self._queryable = session.declare_queryable(key, self._queue.put)

    def answer(self, replies: Callable[[str, dict[str, str]], list[tuple[str, bytes]]]) -> None:
        """Reply to every waiting query with `replies(key expression, parameters)` (key, payload) that match it."""
        while True:
            try:
                query = self._queue.get_nowait()
            except queue.Empty:
                return
            with query:  # dropping a query tells the querier that this queryable is done
                for key, payload in replies(str(query.key_expr), dict(query.parameters)):
                    if query.key_expr.intersects(key):
                        query.reply(key, payload, encoding=zenoh.Encoding.APPLICATION_JSON)


def recent_throws(session: zenoh.Session, switch_id: str = "*", after_ns: int | None = None,
                  timeout_s: float = RECENT_QUERY_S) -> list[Received]:
    """The recorders' kept throws of a switch's sample stream (or of every switch) that ended after `after_ns`, as
    records received now on railswitch/<id>/record (services/core/recent_throws.py): each throw once (several
    recorders may keep it), in each switch's order."""
    selector = recent_key(switch_id) + ("" if after_ns is None else f"?after_ns={after_ns}")
    unique = {}
    for item in query_all(session, selector, timeout_s):
        switch = item.key.split("/")[1]
        try:
            order = (int(json.loads(item.payload)["t_end_ns"]), 0)
        except (ValueError, KeyError, TypeError):
            order = (-1, len(unique))  # junk from a foreign queryable: kept for the intake to count
        unique.setdefault((switch, order), Received(f"{KEY_PREFIX}/{switch}/record", item.payload, item.arrived_s))
    return [unique[key] for key in sorted(unique)]


def query_all(session: zenoh.Session, key: str, timeout_s: float) -> list[Received]:
    """Every reply of every queryable on key (none consolidated away), as received payloads."""
    replies = session.get(key, target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE,
                          timeout=timeout_s)
    return [Received(str(reply.ok.key_expr), reply.ok.payload.to_bytes(), time.monotonic())
            for reply in replies if reply.ok is not None]


class Publishers:
    """One declared publisher per key, JSON-encoded, blocking rather than dropping under congestion. The keys of the
    kinds in `cached` (kind -> samples per key) get Zenoh advanced publishers that keep that many latest samples for
    subscribers that were down or start late (Inbox `catch_up`)."""

    def __init__(self, session: zenoh.Session, *, congestion: zenoh.CongestionControl = zenoh.CongestionControl.BLOCK,
                 cached: dict[str, int] | None = None):
        self._session = session
        self._congestion = congestion
        self._cached = cached or {}
        self._publishers: dict[str, zenoh.Publisher | zenoh.ext.AdvancedPublisher] = {}
        self.published = 0

    def put(self, key: str, message: Message | bytes) -> None:
        publisher = self._publishers.get(key)
        if publisher is None:
            publisher = self._publishers[key] = self._declare(key)
        publisher.put(message if isinstance(message, bytes) else encode(message))
        self.published += 1

    def _declare(self, key: str) -> zenoh.Publisher | zenoh.ext.AdvancedPublisher:
        kept = self._cached.get(key.rsplit("/", 1)[-1])
        if not kept:
            return self._session.declare_publisher(key, encoding=zenoh.Encoding.APPLICATION_JSON,
                                                   congestion_control=self._congestion)
        return zenoh.ext.declare_advanced_publisher(
            self._session, key, encoding=zenoh.Encoding.APPLICATION_JSON, congestion_control=self._congestion,
            cache=zenoh.ext.CacheConfig(kept), publisher_detection=True,
            sample_miss_detection=zenoh.ext.MissDetectionConfig(sporadic_heartbeat=HEARTBEAT_S))


class Inbox:
    """Subscriptions whose callbacks only enqueue; the service drains the queue in its own thread.

    The kinds in `catch_up` (railswitch/*/<kind>) come through Zenoh advanced subscribers instead (and not through
    a plain subscription that would also match them): on start they ask every publisher's cache for what it kept
    (the throws published while this service was down), and once running they fetch from the cache a sample they
    notice they missed. Samples older than a cache holds are gone; Zenoh's count of them is `missed`, logged once
    per publisher, and the services tell which throws they were by the gap in each switch's throw indices."""

    def __init__(self, session: zenoh.Session, keys: list[str], catch_up: tuple[str, ...] = ()):
        self.queue: queue.SimpleQueue[Received] = queue.SimpleQueue()
        self.missed = 0
        self._missed_from: set[str] = set()
        self._catch_up = tuple(f"/{kind}" for kind in catch_up)
        self._subscribers = [session.declare_subscriber(key, self._on_live if catch_up else self._on_sample)
                             for key in keys]
        self._advanced = [zenoh.ext.declare_advanced_subscriber(
            session, f"{KEY_PREFIX}/*/{kind}", self._on_sample,
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
            recovery=zenoh.ext.RecoveryConfig(heartbeat=True), subscriber_detection=True) for kind in catch_up]
        self._miss_listeners = [subscriber.sample_miss_listener(self._on_miss) for subscriber in self._advanced]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self.queue.put(Received(str(sample.key_expr), sample.payload.to_bytes(), time.monotonic()))

    def _on_live(self, sample: zenoh.Sample) -> None:
        if not str(sample.key_expr).endswith(self._catch_up):  # those come through the advanced subscribers
            self._on_sample(sample)

    def _on_miss(self, miss: zenoh.ext.Miss) -> None:
        self.missed += miss.nb
        source = str(miss.source)
        if source not in self._missed_from:
            self._missed_from.add(source)
            log.warning("%d sample(s) of publisher %s were missed and are no longer in its cache (further misses "
                        "of it are counted)", miss.nb, source)

    def get(self, timeout_s: float) -> Received | None:
        try:
            return self.queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def drain(self, stop: threading.Event, poll_s: float = 0.2) -> Iterator[Received | None]:
        """Received samples (None after poll_s without any) until stop is set; then the
        subscriptions end and what is still queued comes out before the iterator does."""
        while not stop.is_set():
            yield self.get(poll_s)
        self.close()
        while (item := self.get(0.0)) is not None:
            yield item

    def close(self) -> None:
        for listener in self._miss_listeners:
            listener.undeclare()
        for subscriber in self._subscribers + self._advanced:
            subscriber.undeclare()
        self._subscribers, self._advanced, self._miss_listeners = [], [], []


class StatusReporter:
    """Publishes a ServiceStatus on railswitch/@service/<name>/<instance>/status every interval_s,
    with what the service's intake (services/core/intake.py) received, rejected and ignored (a newer publisher's)."""

    def __init__(self, publishers: Publishers, service: str, intake: IntakeCounts, interval_s: float = 5.0):
        self.publishers = publishers
        self.service = service
        self.intake = intake
        self.instance = instance_name()
        self.key = f"{SERVICE_PREFIX}/{service}/{self.instance}/status"
        self.interval_s = interval_s
        self._started = time.monotonic()
        self._next = self._started

    def maybe_publish(self, counters: dict[str, int] | Callable[[], dict[str, int]], force: bool = False) -> None:
        """Publish when due (or forced); `counters` may be a function, called only then (a service's loop asks on
        every message)."""
        now = time.monotonic()
        if not force and now < self._next:
            return
        self._next = now + self.interval_s
        if callable(counters):
            counters = counters()
        status = ServiceStatus(service=self.service, instance=self.instance, t_ns=time.time_ns(),
                               uptime_s=now - self._started, received=self.intake.received,
                               rejected=dict(self.intake.rejected), ignored_fields=dict(self.intake.ignored),
                               counters=counters)
        self.publishers.put(self.key, status)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """An Event set by SIGINT or SIGTERM, so a process that starts services finishes its work (and files) cleanly.

    Python's handlers: the signals reach whatever runs while the block is open. A service process uses
    wait_for_stop_signals instead, which no library can take the signals from."""
    stop = threading.Event()
    previous = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}

    def handler(signum, frame):  # noqa: ARG001 - signal API
        stop.set()

    for sig in previous:
        signal.signal(sig, handler)
    try:
        yield stop
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


@contextmanager
def wait_for_stop_signals() -> Iterator[threading.Event]:
    """An Event set by SIGINT or SIGTERM, for a service process: the signals are blocked in this thread before any
    Zenoh thread exists (so in every thread the process starts later), and one thread takes them with sigwait.

    A native library can replace a signal's handler (Zenoh's shared memory did so), and Python runs its handlers only
    when the main thread gets round to it; a blocked signal stays pending until sigwait takes it, whichever handler is
    installed. Threads started earlier (a BLAS pool started by an import) keep their mask: the command line blocks
    the signals while it imports a command (services/commands/cli.py), and a Python handler sets the Event for any
    thread that still takes them. Call it from the main thread before opening a session; a child process started
    inside the block inherits the blocked signals, so a process that starts children uses stop_on_signals."""
    with stop_on_signals() as stop:
        waiter_ready = threading.Event()
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)

        def wait() -> None:
            waiter_ready.set()
            signal.sigwait(STOP_SIGNALS)
            stop.set()

        waiter = threading.Thread(target=wait, name="railswitch-stop-signals", daemon=True)
        waiter.start()
        waiter_ready.wait()
        try:
            yield stop
        finally:
            if waiter.is_alive():  # the service ended by itself: wake the waiter with a signal only it takes
                signal.pthread_kill(waiter.ident, signal.SIGTERM)
                waiter.join()
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def configure_logging(verbose: bool = False) -> None:
    """One line per event on stderr, with the service's name."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s", datefmt="%H:%M:%S")
    zenoh.try_init_log_from_env()  # RUST_LOG=debug shows why a link is refused (TLS, credentials)

