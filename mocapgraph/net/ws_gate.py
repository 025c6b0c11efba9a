"""A WebSocket server that lets a connection in only with the per-launch token, an allowed Origin
and a Host header naming this server.

The checks follow Jupyter's: a token in the URL (``?token=``, compared in constant time), browsers
only from the allowed origins (a page from elsewhere cannot open the socket), a Host header naming
this loopback server (no DNS rebinding). A refused request gets a 403 (400 for a malformed Host)
with the reason in one line, before any WebSocket frame; the counts per reason are in
``refused``. Subclasses handle the accepted connections (:mod:`mocapgraph.net.foxglove_ws`).
"""
from __future__ import annotations

import hmac
import ipaddress
from typing import Sequence
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.server import ServerConnection
from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from .async_server import AsyncServerThread, ServerStartError


class GateStartError(ServerStartError):
    """The gated server could not bind its address."""


def _refuse(status: int, reason: str, why: str) -> Response:
    body = (why + "\n").encode()
    return Response(status, reason, Headers([("Content-Type", "text/plain; charset=utf-8"),
                                             ("Content-Length", str(len(body)))]), body)


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


class GatedServer(AsyncServerThread):
    """Serves ``host:port``; only requests passing the token, Origin and Host checks are upgraded.

    token: what ``?token=`` must say ('' accepts any, only for tests and trusted networks).
    origins: Origin header values allowed; a request without Origin (a desktop app, a script)
    passes.
    """

    start_error = GateStartError
    thread_name = "ws-gate"
    what = "gate"

    def __init__(self, host: str, port: int, token: str, origins: Sequence[str]) -> None:
        super().__init__(host, port)
        self.token = token
        self.origins = set(origins)
        self.accepted = 0  # connections past the checks (counted by the subclass's handler)
        self.refused: dict[str, int] = {}

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}/" + (f"?token={self.token}" if self.token else "")

    def _refuse(self, kind: str, status: int, reason: str, why: str) -> Response:
        self.refused[kind] = self.refused.get(kind, 0) + 1
        return _refuse(status, reason, why)

    def _process_request(self, connection: ServerConnection, request: Request) -> Response | None:
        hosts = request.headers.get_all("Host")
        if len(hosts) != 1:
            return self._refuse("host", 400, "Bad Request", "exactly one Host header, please")
        host = hosts[0]
        try:
            name = urlsplit(f"//{host}").hostname or ""
        except ValueError:  # "[" , "[::1" ...: not a host name at all
            return self._refuse("host", 400, "Bad Request", f"malformed Host {host[:80]!r}")
        if _is_loopback(self.host) and not _is_loopback(name):
            return self._refuse("host", 403, "Forbidden", f"Host {host[:80]!r} is not this loopback server")
        origins = request.headers.get_all("Origin")
        if len(origins) > 1:
            return self._refuse("origin", 403, "Forbidden", "more than one Origin header")
        if origins and origins[0] not in self.origins:
            return self._refuse("origin", 403, "Forbidden", f"Origin {origins[0][:80]!r} is not allowed")
        if self.token:
            given = parse_qs(request.path.partition("?")[2]).get("token", [""])[0]  # (urlsplit: "//[" raises)
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return self._refuse("token", 403, "Forbidden", "missing or wrong token (use the URL the node printed)")
        return None
