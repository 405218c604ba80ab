"""An HTTP webhook: one JSON body POSTed to one URL, and what went wrong told apart as retry or refusal.

The standard library's urllib is enough for a POST; redirects are not followed, because urllib would follow a
301/302 of a POST with a GET without the body and report the GET's 200 as if the change had been delivered.
"""
from __future__ import annotations

import http.client
import socket
import ssl
import urllib.error
import urllib.request
from urllib.parse import urlsplit
from railswitch.services.ports import DeliveryFailed

RETRIED_4XX = (408, 429)  # request timeout, too many requests: the server asks to be tried again
MAX_REPLY_BYTES = 64 << 10  # what is read of a reply before the connection is closed


def check_url(url: str) -> str:
    """The URL if it is http:// or https:// with a host, else ValueError naming it and the accepted form."""
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 - raises ValueError on a port that is not a number in 0 … 65535
    except ValueError:
        parts = None
    if parts is None or parts.scheme not in ("http", "https") or not parts.hostname or any(c.isspace() for c in url):
        raise ValueError(f"{url!r} must be an http:// or https:// URL with a host")
    return url


def check_header(text: str) -> tuple[str, str]:
    """'Name: value' as (name, value), else ValueError naming it; for an authorization token, say. Printable ASCII
    only: anything else would fail every POST (http.client encodes headers as Latin-1 and refuses line breaks)."""
    name, sep, value = text.partition(":")
    name, value = name.strip(), value.strip()
    if (not sep or not name or not all(c.isascii() and (c.isalnum() or c in "-_") for c in name)
            or not (value.isascii() and value.isprintable())):
        raise ValueError(f"{text!r} is not a header 'Name: value' in printable ASCII")
    return name, value


class _NoRedirects(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args, **kwargs):  # noqa: ARG002 - urllib API
        return None  # the 3xx is raised as an HTTPError


class Webhook:
    """POSTs JSON bodies to url with the given extra headers, each attempt bounded by timeout_s."""

    def __init__(self, url: str, headers: dict[str, str] | None = None, timeout_s: float = 10.0):
        self.url = check_url(url)
        # what logs name: a webhook's path or query often holds its secret token, and user:password@ would
        parts = urlsplit(url)
        self.where = f"{parts.scheme}://{parts.netloc.rpartition('@')[2]}"
        self.headers = {"Content-Type": "application/json", "User-Agent": "railswitch-notify", **(headers or {})}
        self.timeout_s = timeout_s
        self._opener = urllib.request.build_opener(_NoRedirects)

    def post(self, body: bytes, headers: dict[str, str] | None = None) -> None:
        """Deliver body (any 2xx), or raise DeliveryFailed."""
        request = urllib.request.Request(self.url, data=body, method="POST", headers={**self.headers, **(headers or {})})
        try:
            with self._opener.open(request, timeout=self.timeout_s) as reply:
                reply.read(MAX_REPLY_BYTES)
        except urllib.error.HTTPError as error:
            error.close()
            code = error.code
            raise DeliveryFailed(f"HTTP {code}", permanent=code < 500 and code not in RETRIED_4XX) from None
        except urllib.error.URLError as error:
            raise DeliveryFailed(failure_kind(error.reason)) from None
        except (OSError, http.client.HTTPException) as error:
            raise DeliveryFailed(failure_kind(error)) from None


def failure_kind(error: BaseException | str) -> str:
    """A few words for a failed connection, the same for every attempt that failed the same way."""
    if isinstance(error, TimeoutError):
        return "timeout"
    if isinstance(error, ConnectionRefusedError):
        return "connection refused"
    if isinstance(error, (ConnectionResetError, ConnectionAbortedError, http.client.RemoteDisconnected)):
        return "connection reset"
    if isinstance(error, socket.gaierror):
        return "host not found"
    if isinstance(error, ssl.SSLError):
        return "TLS error"
    if isinstance(error, http.client.HTTPException):
        return "bad HTTP reply"
    return error if isinstance(error, str) else type(error).__name__
