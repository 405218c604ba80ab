"""The notifier's core against a real HTTP server on loopback (no bus): each alarm change POSTed once as its JSON,
tried again while the server fails or is down, a refusal not tried forever."""
from __future__ import annotations

import logging

from railswitch.schemas import Alarm, decode
from railswitch.services.adapters.processes import wait_for
from railswitch.services.adapters.webhook import Webhook
from railswitch.services.core.notifier import Notifier
from tests.webhook_server import WebhookServer, alarm_change, free_loopback_port

FIRST_RETRY_S = 0.05  # the backoff's first wait, short so that a test's retries take a fraction of a second


def notifier(server_url: str) -> Notifier:
    return Notifier(Webhook(server_url, timeout_s=5.0).post, first_retry_s=FIRST_RETRY_S)


def delivered(n: Notifier, posted: int) -> bool:
    counters = n.counters()
    return counters["posted"] + counters["refused"] == posted and counters["pending"] == 0


def test_each_change_is_posted_once_in_order_as_the_alarms_json():
    changes = [alarm_change(0), alarm_change(0, "sw2"), alarm_change(1, change="escalated"),
               alarm_change(2, change="cleared"), alarm_change(1, "sw2")]
    with WebhookServer() as server, notifier(server.url()) as n:
        for change in changes:
            n.offer(change)
        wait_for(lambda: delivered(n, len(changes)), 10, "every change posted")
    assert [decode(Alarm, body) for body in server.bodies()] == changes  # nothing left pending: no more will come
    first = server.posted[0]
    assert first.path == "/alarms" and first.headers["Content-Type"] == "application/json"
    assert first.headers["Idempotency-Key"] == "sw1-0"


def test_a_change_offered_twice_is_posted_once():
    with WebhookServer() as server, notifier(server.url()) as n:
        assert n.offer(alarm_change(0))
        wait_for(lambda: delivered(n, 1), 10, "the change posted")
        assert not n.offer(alarm_change(0))  # again, from a publisher's cache on catching up
        assert n.offer(alarm_change(1))
        wait_for(lambda: delivered(n, 2), 10, "the next change posted")
    assert [decode(Alarm, body).sequence for body in server.bodies()] == [0, 1]
    assert n.counters()["duplicates"] == 1


def test_a_server_failing_three_times_gets_the_change_on_the_fourth_attempt_and_the_failure_is_logged_once(caplog):
    with WebhookServer(statuses=[503, 503, 500]) as server, notifier(server.url()) as n, caplog.at_level(logging.INFO):
        n.offer(alarm_change(0))
        wait_for(lambda: delivered(n, 1), 10, "the change posted")
    assert server.bodies() == [server.bodies()[0]] * 4
    counters = n.counters()
    assert counters["retries"] == 3 and counters["failed_attempts: HTTP 503"] == 2
    assert counters["failed_attempts: HTTP 500"] == 1
    failures = [r.getMessage() for r in caplog.records if "the webhook failed" in r.getMessage()]
    assert len(failures) == 2 and "HTTP 503" in failures[0], failures  # one line per kind, not per attempt


def test_a_server_down_at_first_gets_the_change_once_it_listens():
    port = free_loopback_port()
    with notifier(f"http://127.0.0.1:{port}/alarms") as n:
        n.offer(alarm_change(0))
        wait_for(lambda: n.counters().get("failed_attempts: connection refused", 0) >= 2, 10, "attempts refused")
        with WebhookServer(port) as server:
            wait_for(lambda: delivered(n, 1), 60, "the change posted once the server listens")
    assert [decode(Alarm, body) for body in server.bodies()] == [alarm_change(0)]


def test_a_change_the_server_refuses_with_400_is_not_tried_again_and_the_next_one_goes_on():
    with WebhookServer(statuses=[400]) as server, notifier(server.url()) as n:
        n.offer(alarm_change(0))
        n.offer(alarm_change(1))
        wait_for(lambda: delivered(n, 2), 10, "both changes done")
    assert [decode(Alarm, body).sequence for body in server.bodies()] == [0, 1]
    counters = n.counters()
    assert counters["refused: HTTP 400"] == 1 and counters["posted"] == 1 and counters["retries"] == 0


def test_beyond_max_pending_waiting_changes_the_oldest_are_dropped_and_counted():
    with WebhookServer() as server:
        n = Notifier(Webhook(server.url()).post, max_pending=2)
        for sequence in range(5):  # offered before the worker starts: all five wait
            n.offer(alarm_change(sequence))
        with n:
            wait_for(lambda: delivered(n, 2), 10, "the changes kept posted")
    assert [decode(Alarm, body).sequence for body in server.bodies()] == [3, 4]
    assert n.counters()["dropped"] == 3
