"""`railswitch notify` as a real process on a real router, POSTing to a real HTTP server on loopback: every alarm
change on the bus reaches the webhook once, those published before it started too (caught up from the publisher's
cache), and a webhook that is down at first gets them once it listens."""
from __future__ import annotations

from railswitch.schemas import Alarm, decode, key_expr
from railswitch.services.adapters.zenoh_bus import Publishers
from tests.live import ServiceWatch, instance_of, live_bus, wait_for, wait_ready
from tests.webhook_server import WebhookServer, alarm_change, free_loopback_port

KEPT = 8  # alarm changes an alarm publisher keeps per switch for subscribers that were down, as a diagnoser would


def publish(publishers: Publishers, changes: list[Alarm]) -> None:
    for change in changes:
        publishers.put(key_expr(change.switch_id, "alarm"), change)


def received(server: WebhookServer) -> list[Alarm]:
    return [decode(Alarm, body) for body in server.bodies()]


def test_each_alarm_change_reaches_the_webhook_once_including_those_published_before_notify_started(tmp_path):
    before = [alarm_change(0), alarm_change(0, "sw2")]
    after = [alarm_change(1, change="escalated"), alarm_change(1, "sw2", change="cleared"), alarm_change(2)]
    with WebhookServer() as server, live_bus(tmp_path) as (services, endpoint, session, _):
        watch = ServiceWatch(session, "notify")
        publishers = Publishers(session, cached={"alarm": KEPT})
        publish(publishers, before)
        notify = services.start("notify", "--connect", endpoint, "--webhook", server.url(), "--status-interval", "0.5")
        wait_ready(session, services, notify=1, timeout_s=60)
        publish(publishers, after)
        wait_for(lambda: len(server.bodies()) >= len(before + after), 30, "every change at the webhook")

        def settled() -> bool:  # nothing in flight or waiting: what the webhook got is all it gets
            status = watch.latest(instance_of(notify))
            return status is not None and status.counters["pending"] == 0 and status.received >= len(before + after)
        wait_for(settled, 30, "notify to have nothing pending")
    got = received(server)
    assert sorted(got, key=lambda a: (a.switch_id, a.sequence)) == sorted(before + after,
                                                                          key=lambda a: (a.switch_id, a.sequence))
    assert [a for a in got if a in after] == after  # live changes in the order they were published


def test_a_webhook_down_at_first_gets_each_change_once_it_listens(tmp_path):
    port = free_loopback_port()
    changes = [alarm_change(0), alarm_change(1, change="escalated"), alarm_change(0, "sw2")]
    with live_bus(tmp_path) as (services, endpoint, session, _):
        watch = ServiceWatch(session, "notify")
        notify = services.start("notify", "--connect", endpoint, "--webhook", f"http://127.0.0.1:{port}/alarms",
                                "--status-interval", "0.5")
        wait_ready(session, services, notify=1, timeout_s=60)
        publish(Publishers(session, cached={"alarm": KEPT}), changes)

        def refused() -> bool:
            status = watch.latest(instance_of(notify))
            return status is not None and status.counters.get("failed_attempts: connection refused", 0) >= 2
        wait_for(refused, 30, "notify to have found the webhook down")
        with WebhookServer(port) as server:
            wait_for(lambda: len(server.bodies()) >= len(changes), 60, "every change once the webhook listens")
            wait_for(lambda: watch.latest(instance_of(notify)).counters["pending"] == 0, 30, "nothing pending")
        log = services.log(notify)
    assert received(server) == changes
    assert log.count("connection refused") == 1, log  # logged once, however many attempts failed
