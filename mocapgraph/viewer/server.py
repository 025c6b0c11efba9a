"""HTTP + WebSocket server of the viewer, in its own thread, fed by the node's event loop.

The node's handlers call `LatestStore.put` for every message; the store keeps only the newest
message per stream (topic, sender, actor/character/source name). Each browser connection has its
own send loop that bundles every stream changed since its last bundle, so a browser gets at most
one value per stream per bundle and never a backlog:

- credit: a connection may have at most ``window`` bundles unacknowledged; the page acknowledges a
  bundle after drawing it (in requestAnimationFrame), so a slow or background tab stops the
  sending instead of queueing;
- ``max_rate_hz`` caps bundles per second per connection.

Messages are encoded for the browser lazily, once per stream version, whichever connection needs
them first; the bus side only stores references. Commands from the page (JSON text frames) are
checked here and queued for the node, which publishes them from its own thread (ZeroMQ sockets are
not thread-safe).
"""
from __future__ import annotations

import asyncio
import json
import logging
import mimetypes
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from ..messages import Envelope, Message
from ..messages.commands import VIEWER_COMMANDS
from . import ASSET_DIR
from .wire import EncodedRecord, build_bundle, encode_record

log = logging.getLogger(__name__)
logging.getLogger("websockets").setLevel(logging.WARNING)  # not a line per page load

#: commands the page may send, per channel (calibration node / bag player)
COMMANDS = VIEWER_COMMANDS  # what the page may send; the one list lives in messages/commands.py
_SERVED_SUFFIXES = (".html", ".js", ".css")


class ViewerStartError(RuntimeError):
    """The server could not start (port in use, bad host)."""


@dataclass
class Entry:
    """The newest message of one stream and its cached wire form."""

    topic: str
    key: str
    version: int
    env: Envelope
    msg: Message
    encoded: EncodedRecord | None = None
    encoded_version: int = -1


class LatestStore:
    """Newest message per stream, shared between the node thread (writer) and the server thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._entries: dict[str, Entry] = {}
        self.version = 0
        self.puts = 0
        self._armed = False
        self._wake: Any = None  # set by the server: callable that wakes waiting connections

    def put(self, topic: str, ident: str, env: Envelope, msg: Message) -> None:
        """Keep ``msg`` as the newest of its stream (called on the node thread, per message)."""
        key = f"{topic}|{env.sender}|{ident}"
        with self._lock:
            self.version += 1
            self.puts += 1
            e = self._entries.get(key)
            if e is None:
                self._entries[key] = Entry(topic, key, self.version, env, msg)
            else:
                e.version, e.env, e.msg = self.version, env, msg
            wake = self._armed
            self._armed = False
        if wake and self._wake is not None:
            self._wake()

    def arm(self) -> None:
        """Ask for one wake-up at the next put."""
        self._armed = True

    def changed(self, seen: dict[str, int]) -> list[Entry]:
        """Entries newer than ``seen`` (key -> version); updates ``seen``."""
        with self._lock:
            out = [e for e in self._entries.values() if e.version > seen.get(e.key, 0)]
            for e in out:
                seen[e.key] = e.version
            return [Entry(e.topic, e.key, e.version, e.env, e.msg) for e in out] if out else []

    def encoded(self, snap: Entry) -> EncodedRecord:
        """Wire form of a snapshot, encoded once per version and shared by all connections."""
        with self._lock:
            live = self._entries.get(snap.key)
            if live is not None and live.encoded_version == snap.version and live.encoded is not None:
                return live.encoded
        rec = encode_record(snap.topic, snap.key, snap.env, snap.msg)
        with self._lock:
            live = self._entries.get(snap.key)
            if live is not None and live.version == snap.version:
                live.encoded, live.encoded_version = rec, snap.version
        return rec


@dataclass
class ClientStats:
    """One browser connection's counters (served at /stats for tests and benchmarks)."""

    id: int
    remote: str
    connected_at: float = field(default_factory=time.time)
    bundles: int = 0
    records: int = 0
    bytes: int = 0
    acks: int = 0
    credit: int = 0
    commands: int = 0


class ViewerServer:
    """Serves the page and streams the store to every connected browser."""

    def __init__(self, store: LatestStore, hello: dict[str, Any], host: str = "127.0.0.1", port: int = 8765,
                 max_rate_hz: float = 60.0, window: int = 2, asset_dir: Path = ASSET_DIR) -> None:
        self.store = store
        self.hello = hello
        self.host = host
        self.port = port
        self.min_interval = 1.0 / max_rate_hz
        self.window = window
        self.assets = {"/" + p.relative_to(asset_dir).as_posix(): p for p in asset_dir.rglob("*")
                       if p.suffix in _SERVED_SUFFIXES and p.is_file()}
        self.commands: queue.Queue[dict[str, Any]] = queue.Queue()
        self.clients: dict[int, ClientStats] = {}
        self.connects = 0
        self.started_ns = time.time_ns()
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Future | None = None
        self._event: asyncio.Event | None = None

    # ----- lifecycle (node thread) ------------------------------------------------------------
    def start(self, timeout_s: float = 5.0) -> None:
        """Bind and serve in a daemon thread; ViewerStartError when the port cannot be bound."""
        self._thread = threading.Thread(target=self._thread_main, name="viewer-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise ViewerStartError(f"viewer server did not start within {timeout_s} s")
        if self._error is not None:
            raise ViewerStartError(f"cannot serve the viewer on {self.host}:{self.port}: {self._error}")

    def stop(self, timeout_s: float = 2.0) -> None:
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(lambda: self._stop.done() or self._stop.set_result(None))
        if self._thread is not None:
            self._thread.join(timeout_s)

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def stats(self) -> dict[str, Any]:
        return {"clients": [c.__dict__ for c in list(self.clients.values())], "connects": self.connects,
                "store_puts": self.store.puts, "started_ns": self.started_ns}

    # ----- server thread ----------------------------------------------------------------------
    def _thread_main(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # noqa: BLE001 - reported to the starting thread
            self._error = exc
            self._ready.set()

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = self._loop.create_future()
        self._event = asyncio.Event()
        self.store._wake = lambda: self._loop.call_soon_threadsafe(self._notify)
        try:
            server = await serve(self._handle, self.host, self.port, process_request=self._http,
                                 compression=None, max_size=1 << 16, ping_interval=10, ping_timeout=30)
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

    def _notify(self) -> None:
        ev, self._event = self._event, asyncio.Event()
        ev.set()

    def _http(self, connection: ServerConnection, request: Request) -> Response | None:
        path = request.path.split("?", 1)[0]
        if path == "/ws":
            return None
        if path == "/":
            path = "/index.html"
        if path == "/stats":
            body = json.dumps(self.stats()).encode()
            ctype = "application/json"
        elif path in self.assets:
            body = self.assets[path].read_bytes()
            ctype = mimetypes.guess_type(path)[0] or "application/octet-stream"
            if path.endswith(".js"):
                ctype = "text/javascript"
        else:
            body, ctype = b"not found\n", "text/plain"
            return Response(404, "Not Found", _headers(ctype, len(body)), body)
        return Response(200, "OK", _headers(ctype + "; charset=utf-8", len(body)), body)

    async def _handle(self, ws: ServerConnection) -> None:
        self.connects += 1
        cid = self.connects
        peer = ws.remote_address
        client = ClientStats(cid, f"{peer[0]}:{peer[1]}" if peer else "?", credit=self.window)
        self.clients[cid] = client
        credit = asyncio.Event()
        credit.set()
        await ws.send(json.dumps({"type": "hello", "client": cid, "session": self.started_ns, **self.hello}))
        # A closed socket ends the reader; a sender waiting for credit would never notice on its own.
        tasks = [asyncio.create_task(self._read(ws, client, credit)),
                 asyncio.create_task(self._send_loop(ws, client, credit))]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            self.clients.pop(cid, None)

    async def _read(self, ws: ServerConnection, client: ClientStats, credit: asyncio.Event) -> None:
        try:
            await self._read_messages(ws, client, credit)
        except ConnectionClosed:
            pass

    async def _read_messages(self, ws: ServerConnection, client: ClientStats, credit: asyncio.Event) -> None:
        async for text in ws:
            if text == "a":  # the page drew a bundle
                client.acks += 1
                client.credit = min(self.window, client.credit + 1)
                credit.set()
                continue
            reply = self._command(text, client)
            await ws.send(json.dumps(reply))

    def _command(self, text: Any, client: ClientStats) -> dict[str, Any]:
        try:
            req = json.loads(text)
            if not isinstance(req, dict) or req.get("type") != "command":
                raise ValueError("not a command")
            channel, name = req.get("channel"), req.get("command")
            if channel not in COMMANDS:
                raise ValueError(f"unknown channel {channel!r}")
            if name not in COMMANDS[channel]:
                raise ValueError(f"{channel} has no command {name!r} (known: {', '.join(COMMANDS[channel])})")
            args = req.get("args") or {}
            target = req.get("target") or ""
            if not isinstance(args, dict) or not isinstance(target, str):
                raise ValueError("args must be an object and target a string")
        except (ValueError, TypeError) as exc:
            return {"type": "command_result", "id": _req_id(text), "ok": False, "error": str(exc)}
        client.commands += 1
        self.commands.put({"channel": channel, "command": name, "args": args, "target": target})
        return {"type": "command_result", "id": req.get("id"), "ok": True}

    async def _send_loop(self, ws: ServerConnection, client: ClientStats, credit: asyncio.Event) -> None:
        try:
            await self._send_bundles(ws, client, credit)
        except ConnectionClosed:
            pass

    async def _send_bundles(self, ws: ServerConnection, client: ClientStats, credit: asyncio.Event) -> None:
        seen: dict[str, int] = {}
        while True:
            while client.credit <= 0:
                credit.clear()
                await credit.wait()
            ev = self._event
            self.store.arm()
            snaps = self.store.changed(seen)
            if not snaps:
                await ev.wait()
                continue
            t_send = time.monotonic()
            data = build_bundle([self.store.encoded(s) for s in snaps], time.time_ns() / 1e6)
            client.credit -= 1
            await ws.send(data)
            client.bundles += 1
            client.records += len(snaps)
            client.bytes += len(data)
            wait = t_send + self.min_interval - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)


def _headers(ctype: str, length: int) -> Headers:
    return Headers([("Content-Type", ctype), ("Content-Length", str(length)), ("Cache-Control", "no-store"),
                    ("Connection", "close")])


def _req_id(text: Any) -> Any:
    try:
        return json.loads(text).get("id")
    except (ValueError, TypeError, AttributeError):
        return None
