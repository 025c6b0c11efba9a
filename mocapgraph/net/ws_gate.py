"""A WebSocket front door: checks a per-launch token, the Origin and the Host header, then relays
the connection both ways to a WebSocket server that has no checks of its own.

Used in front of the Foxglove SDK's server (which offers no authentication): clients connect to
``ws://host:port/?token=T``; the inner server listens on a free loopback port only. The checks
follow Jupyter's: a token in the URL (compared in constant time), browsers only from the allowed
origins (a page from elsewhere cannot open the socket), a Host header naming this server (no DNS
rebinding). Messages are relayed as they come; a slow client holds the relay, and the inner
server then drops its oldest messages (bounded), never this process's memory.
"""
from __future__ import annotations

import asyncio
import hmac
import ipaddress
import threading
from typing import Sequence
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.client import connect
from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response


class GateStartError(RuntimeError):
    """The gate could not bind its address."""


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


class WebSocketGate:
    """Serves ``host:port`` and relays each accepted connection to ``inner_url``.

    token: what ``?token=`` must say ('' accepts any, only for tests and trusted networks).
    origins: Origin header values allowed; a request without Origin (a desktop app, a script)
    passes. subprotocols: offered to clients; the inner connection uses ``inner_subprotocol``.
    """

    def __init__(self, inner_url: str, host: str, port: int, token: str, origins: Sequence[str],
                 subprotocols: Sequence[str], inner_subprotocol: str) -> None:
        self.inner_url = inner_url
        self.host = host
        self.port = port
        self.token = token
        self.origins = set(origins)
        self.subprotocols = list(subprotocols)
        self.inner_subprotocol = inner_subprotocol
        self.accepted = 0
        self.refused: dict[str, int] = {}
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Future | None = None

    # ----- node thread -------------------------------------------------------------------------
    def start(self, timeout_s: float = 5.0) -> None:
        self._thread = threading.Thread(target=self._thread_main, name="ws-gate", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise GateStartError(f"gate on {self.host}:{self.port} did not start within {timeout_s} s")
        if self._error is not None:
            raise GateStartError(f"cannot serve on {self.host}:{self.port}: {self._error}")

    def stop(self, timeout_s: float = 2.0) -> None:
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(lambda: self._stop.done() or self._stop.set_result(None))
        if self._thread is not None:
            self._thread.join(timeout_s)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}/" + (f"?token={self.token}" if self.token else "")

    # ----- gate thread -------------------------------------------------------------------------
    def _thread_main(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # noqa: BLE001 - reported to the starting thread
            self._error = exc
            self._ready.set()

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = self._loop.create_future()
        try:
            server = await serve(self._relay, self.host, self.port, process_request=self._check,
                                 subprotocols=self.subprotocols or None, compression=None, max_size=1 << 22,
                                 ping_interval=10, ping_timeout=30)
        except OSError as exc:
            self._error = exc
            self._ready.set()
            return
        self.port = server.sockets[0].getsockname()[1]
        self._ready.set()
        try:
            await self._stop
        finally:
            server.close()
            await server.wait_closed()

    def _refuse(self, kind: str, status: int, reason: str, why: str) -> Response:
        self.refused[kind] = self.refused.get(kind, 0) + 1
        return _refuse(status, reason, why)

    def _check(self, connection: ServerConnection, request: Request) -> Response | None:
        hosts = request.headers.get_all("Host")
        if len(hosts) != 1:
            return self._refuse("host", 400, "Bad Request", "exactly one Host header, please")
        host = hosts[0]
        name = urlsplit(f"//{host}").hostname or ""
        if _is_loopback(self.host) and not _is_loopback(name):
            return self._refuse("host", 403, "Forbidden", f"Host {host!r} is not this loopback server")
        origin = request.headers.get("Origin")
        if origin is not None and origin not in self.origins:
            return self._refuse("origin", 403, "Forbidden", f"Origin {origin!r} is not allowed")
        if self.token:
            given = parse_qs(urlsplit(request.path).query).get("token", [""])[0]
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return self._refuse("token", 403, "Forbidden", "missing or wrong token (use the URL the node printed)")
        return None

    async def _relay(self, client: ServerConnection) -> None:
        self.accepted += 1
        try:
            async with connect(self.inner_url, subprotocols=[self.inner_subprotocol], compression=None,
                               max_size=None, ping_interval=None) as inner:
                async def pump(src, dst) -> None:
                    async for msg in src:
                        await dst.send(msg)

                tasks = [asyncio.create_task(pump(client, inner)), asyncio.create_task(pump(inner, client))]
                done, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
                for t in pending:
                    t.cancel()
                for t in done:
                    if t.exception() is not None and not isinstance(t.exception(), ConnectionClosed):
                        raise t.exception()
        except (ConnectionClosed, OSError):
            pass
