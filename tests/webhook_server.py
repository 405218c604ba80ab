"""A real HTTP server on loopback that records what is POSTed to it, and the alarm changes the notifier's tests
send it."""
from __future__ import annotations

import socket
import threading
from collections.abc import Iterable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import NamedTuple

from railswitch.schemas import Alarm


class Posted(NamedTuple):
    path: str
    headers: dict[str, str]
    body: bytes


def alarm_change(sequence: int, switch_id: str = "sw1", change: str = "raised") -> Alarm:
    """Change `sequence` of a switch's obstacle alarm."""
    return Alarm(switch_id=switch_id, alarm="obstacle", change=change, severity="high", cause="fault",
                 text="obstacle at 0.42 m", parameters={"obstacle_position": 0.42}, first_throw=3,
                 last_throw=3 + sequence, count=1 + sequence, active=change != "cleared", acknowledged=False,
                 sequence=sequence, t_ns=1_700_000_000 * 10**9 + sequence, model="poly")


def free_loopback_port() -> int:
    """A TCP port on 127.0.0.1 nobody listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class WebhookServer:
    """Answers each POST with the next of `statuses`, then 200; every request is kept in `posted` (use it as a
    context manager: it serves in a thread of its own until the block ends)."""

    def __init__(self, port: int = 0, statuses: Iterable[int] = ()):
        self.posted: list[Posted] = []
        self._statuses = list(statuses)
        self._lock = threading.Lock()
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 - http.server API
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                with server._lock:
                    server.posted.append(Posted(self.path, dict(self.headers), body))
                    status = server._statuses.pop(0) if server._statuses else 200
                self.send_response(status)
                self.send_header("Content-Length", "0")
                self.end_headers()

            def log_message(self, *args) -> None:
                pass

        self._http = ThreadingHTTPServer(("127.0.0.1", port), Handler)
        self.port = self._http.server_address[1]
        self._thread = threading.Thread(target=self._http.serve_forever, name="webhook-server", daemon=True)

    def url(self, path: str = "/alarms") -> str:
        return f"http://127.0.0.1:{self.port}{path}"

    def bodies(self) -> list[bytes]:
        with self._lock:
            return [p.body for p in self.posted]

    def __enter__(self) -> WebhookServer:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._http.shutdown()
        self._http.server_close()
        self._thread.join()
