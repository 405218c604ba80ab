"""The notifier's core: alarm changes handed on to a webhook, each once and in the order they came, tried again
with exponential backoff until delivered.

A change is never given up while the process lives unless the receiver refuses it for good (a 4xx) or more than
MAX_PENDING changes wait behind a receiver that is down (the oldest go first, counted). The same change arriving
twice (live, then again from a publisher's cache on catching up) is handed on once: a change is its switch and
sequence number.
"""
from __future__ import annotations

import logging
import random
import threading
from collections import Counter, OrderedDict, deque
from collections.abc import Callable

from railswitch.schemas import Alarm, encode
from railswitch.services.ports import DeliveryFailed

log = logging.getLogger("railswitch.notify")

MAX_PENDING = 10_000  # changes waiting for the receiver; beyond it the oldest are dropped
MAX_SEEN = 100_000  # changes remembered for de-duplication, oldest forgotten first
FIRST_RETRY_S = 0.5
MAX_RETRY_S = 30.0

Post = Callable[[bytes, dict[str, str]], None]  # delivers a body with extra headers, or raises DeliveryFailed


def change_of(alarm: Alarm) -> tuple[str, int]:
    """What identifies one alarm change (schemas/messages.py Alarm)."""
    return alarm.switch_id, alarm.sequence


def backoff_s(failures: int, first_s: float, max_s: float) -> float:
    """The wait after `failures` failed attempts in a row: doubling from first_s up to max_s, drawn between half
    and all of it so that notifiers failing together do not all try again at once."""
    full = min(max_s, first_s * 2.0 ** min(failures - 1, 64))  # a day-long outage must not overflow a float
    return random.uniform(full / 2, full)


class Notifier:
    """A queue of alarm changes and a worker thread that posts them one by one (use it as a context manager)."""

    def __init__(self, post: Post, *, first_retry_s: float = FIRST_RETRY_S, max_retry_s: float = MAX_RETRY_S,
                 max_pending: int = MAX_PENDING):
        self.post = post
        self.first_retry_s = first_retry_s
        self.max_retry_s = max_retry_s
        self.max_pending = max_pending
        self.failed: Counter[str] = Counter()  # failed attempts per kind of failure
        self.refused: Counter[str] = Counter()  # changes refused for good, per reply
        self.posted = self.retries = self.duplicates = self.dropped = 0
        self._pending: deque[Alarm] = deque()  # waiting behind the one in flight
        self._in_flight: Alarm | None = None
        self._seen: OrderedDict[tuple[str, int], None] = OrderedDict()
        self._changed = threading.Condition()
        self._closed = False
        self._worker = threading.Thread(target=self._deliver_all, name="webhook", daemon=True)

    def offer(self, alarm: Alarm) -> bool:
        """Queue a change for posting; False (counted) if it came before."""
        change = change_of(alarm)
        with self._changed:
            if change in self._seen:
                self.duplicates += 1
                return False
            self._seen[change] = None
            if len(self._seen) > MAX_SEEN:
                self._seen.popitem(last=False)
            self._pending.append(alarm)
            if len(self._pending) > self.max_pending:
                self._pending.popleft()
                self.dropped += 1
                if self.dropped == 1:
                    log.error("more than %d alarm changes wait for the webhook: dropping the oldest (counted)",
                              self.max_pending)
            self._changed.notify()
        return True

    def counters(self) -> dict[str, int]:
        with self._changed:  # the worker adds kinds of failure meanwhile
            return ({"posted": self.posted, "pending": len(self._pending) + (self._in_flight is not None),
                     "retries": self.retries, "duplicates": self.duplicates, "dropped": self.dropped,
                     "refused": sum(self.refused.values()), "failed_attempts": sum(self.failed.values())}
                    | {f"failed_attempts: {kind}": n for kind, n in self.failed.items()}
                    | {f"refused: {kind}": n for kind, n in self.refused.items()})

    def _next(self) -> Alarm | None:
        """The oldest pending change, now in flight, or None once closed."""
        with self._changed:
            self._changed.wait_for(lambda: self._pending or self._closed)
            if self._closed:
                return None
            self._in_flight = self._pending.popleft()
            return self._in_flight

    def _deliver_all(self) -> None:
        while (alarm := self._next()) is not None:
            if not self._deliver(alarm):
                return  # closed with it in flight
            with self._changed:
                self._in_flight = None

    def _deliver(self, alarm: Alarm) -> bool:
        """Post one change until it is delivered or refused (True), or the notifier closes (False)."""
        body = encode(alarm)
        key = {"Idempotency-Key": "%s-%d" % change_of(alarm)}  # a receiver can drop what a lost reply had us resend
        failures = 0
        while True:
            try:
                self.post(body, key)
            except DeliveryFailed as failure:
                failures += 1
                if self._failed(failure, alarm):
                    return True
                with self._changed:
                    if self._changed.wait_for(lambda: self._closed, backoff_s(failures, self.first_retry_s,
                                                                              self.max_retry_s)):
                        return False
                self.retries += 1
                continue
            self.posted += 1
            if failures:
                log.info("the webhook took %s alarm change %d after %d failed attempt(s)", alarm.switch_id,
                         alarm.sequence, failures)
            return True

    def _failed(self, failure: DeliveryFailed, alarm: Alarm) -> bool:
        """Count and (once per kind) log a failed attempt; whether the change is given up (refused for good)."""
        counter = self.refused if failure.permanent else self.failed
        with self._changed:
            counter[failure.kind] += 1
        if counter[failure.kind] == 1:
            if failure.permanent:
                log.error("the webhook refused %s alarm change %d (%s): not retried (further refusals are counted)",
                          alarm.switch_id, alarm.sequence, failure.kind)
            else:
                log.warning("the webhook failed: %s; retrying with backoff up to %.0f s (further failures of this "
                            "kind are counted)", failure.kind, self.max_retry_s)
        return failure.permanent

    def __enter__(self) -> Notifier:
        self._worker.start()
        return self

    def __exit__(self, *exc) -> None:
        """Stop after the attempt under way; what is still pending is logged, not delivered."""
        with self._changed:
            self._closed = True
            self._changed.notify_all()
        self._worker.join()
        left = len(self._pending) + (self._in_flight is not None)
        if left:
            log.warning("%d alarm change(s) not delivered to the webhook", left)
