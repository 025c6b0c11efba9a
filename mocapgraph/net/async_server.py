"""A `websockets` server on its own asyncio loop in a daemon thread: start (wait until bound), stop, join.

The viewer's server and the Foxglove bridge's server share this lifecycle. A subclass gives the
connection handler (``_handle``), optionally the HTTP check before the upgrade
(``_process_request``), the ``serve`` options (``_serve_options``) and what to set up on the loop
before binding (``_on_loop``). ``start`` returns once the socket is bound (``self.port`` is then the
real port when 0 was asked) or raises ``start_error`` with the reason in one line.
"""
from __future__ import annotations

import asyncio
import threading
from typing import Any

from websockets.asyncio.server import ServerConnection, serve
from websockets.http11 import Request, Response


class ServerStartError(RuntimeError):
    """The server could not bind its address (port in use, bad host) or did not start in time."""


class AsyncServerThread:
    """Lifecycle of one WebSocket server thread; ``host``/``port`` are what it binds."""

    start_error: type[RuntimeError] = ServerStartError
    thread_name = "ws-server"
    what = "server"  # named in start errors

    def __init__(self, host: str, port: int) -> None:
        self.host = host
        self.port = port
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Future | None = None

    # ----- caller's thread ---------------------------------------------------------------------
    def start(self, timeout_s: float = 5.0) -> None:
        """Bind and serve in a daemon thread; ``start_error`` when it cannot."""
        self._thread = threading.Thread(target=self._thread_main, name=self.thread_name, daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise self.start_error(f"{self.what} on {self.host}:{self.port} did not start within {timeout_s} s")
        if self._error is not None:
            raise self.start_error(f"cannot serve the {self.what} on {self.host}:{self.port}: {self._error}")

    def stop(self, timeout_s: float = 2.0) -> None:
        """Close the listening socket and every connection; wait up to ``timeout_s`` for the thread."""
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(lambda: stop.done() or stop.set_result(None))
            except RuntimeError:  # the loop closed between the check and the call
                pass
        if self._thread is not None:
            self._thread.join(timeout_s)

    def call_soon(self, fn: Any, *args: Any) -> bool:
        """Run ``fn(*args)`` on the server's loop (thread-safe); False when the loop is not running."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return False
        try:
            loop.call_soon_threadsafe(fn, *args)
        except RuntimeError:
            return False
        return True

    # ----- for subclasses ----------------------------------------------------------------------
    async def _handle(self, ws: ServerConnection) -> None:
        raise NotImplementedError

    def _process_request(self, connection: ServerConnection, request: Request) -> Response | None:
        return None

    def _serve_options(self) -> dict[str, Any]:
        return {"compression": None, "ping_interval": 10, "ping_timeout": 30}

    def _on_loop(self, loop: asyncio.AbstractEventLoop) -> None:
        """Called on the server thread before binding."""

    # ----- server thread -----------------------------------------------------------------------
    def _thread_main(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # noqa: BLE001 - reported to the starting thread
            self._error = exc
            self._ready.set()

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = self._loop.create_future()
        self._on_loop(self._loop)
        try:
            server = await serve(self._handle, self.host, self.port, process_request=self._process_request,
                                 **self._serve_options())
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
