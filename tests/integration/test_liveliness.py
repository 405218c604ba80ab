"""Who is live, through a real router: the liveliness watch elastic diagnosers build their membership on
(services/adapters/zenoh_bus.py LivelinessWatch)."""
from __future__ import annotations

import time

from railswitch.schemas import SERVICE_PREFIX
from railswitch.services.adapters.zenoh_bus import LivelinessWatch
from tests.live import ServiceProcesses, client, start_router, wait_for


def test_a_watch_sees_the_tokens_present_then_every_join_and_leave(tmp_path):
    with ServiceProcesses(tmp_path) as services:
        endpoint = start_router(services)
        others = client(endpoint)
        try:
            tokens = [others.liveliness().declare_token(f"{SERVICE_PREFIX}/diagnoser/vm-{k}") for k in range(3)]
            time.sleep(0.3)
            # Several sessions: a get asked right after a subscriber with history often came back empty, and a
            # starting diagnoser took the live ones for newcomers.
            for _ in range(5):
                session = client(endpoint)
                try:
                    watch = LivelinessWatch(session, "diagnoser")
                    assert watch.present == {"vm-0", "vm-1", "vm-2"}
                    changes = []

                    def seen(count: int) -> bool:
                        changes.extend(watch.changes())
                        return len(changes) >= count

                    joining = others.liveliness().declare_token(f"{SERVICE_PREFIX}/diagnoser/vm-9")
                    tokens.append(others.liveliness().declare_token(f"{SERVICE_PREFIX}/historian/vm-8"))  # not one
                    wait_for(lambda: seen(1), 10, "the join")
                    joining.undeclare()
                    wait_for(lambda: seen(2), 10, "the leave")
                    assert [(name, alive) for name, alive, _ in changes] == [("vm-9", True), ("vm-9", False)]
                finally:
                    session.close()
        finally:
            others.close()
