"""HTTP + WebSocket server of the viewer, in its own thread, fed by the node's event loop.

The node's handlers call `LatestStore.put` for every message; the store keeps only the newest
message per stream (topic, sender, actor/character/source name). Each browser connection has its
own send loop that bundles every stream changed since its last bundle, so a browser gets at most
one value per stream per bundle and never a backlog:

- credit: a connection may have at most ``window`` bundles unacknowledged; the page acknowledges a
  bundle after drawing it (in requestAnimationFrame), so a slow or background tab stops the
  sending instead of queueing;
- ``max_rate_hz`` caps bundles per second per connection.

Who may connect. The server hands out nothing to a stranger (a web page in another tab, another
local user): every WebSocket and /stats request must carry the per-launch ``token`` (in the
printed URL, as Jupyter does; the page passes it on); the Host header must name this server
(a DNS-rebinding page's Host is its own name); a browser's Origin must be the page's own
(or in ``allowed_origins``). Commands are checked against a schema of their arguments and limited
to COMMAND_RATE_HZ per connection (burst COMMAND_BURST); a refused command gets an error reply.

Messages are encoded for the browser lazily, once per stream version, whichever connection needs
them first; the bus side only stores references. Commands from the page (JSON text frames) are
checked here and queued for the node, which publishes them from its own thread (ZeroMQ sockets are
not thread-safe).
"""
from __future__ import annotations

import asyncio
import hmac
import json
import logging
import math
import mimetypes
import queue
import secrets
import socket
import threading
import time
from urllib.parse import parse_qs, quote
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from websockets.asyncio.server import ServerConnection
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from ..messages import Envelope, Message
from ..messages.bounded_json import loads_bounded
from ..messages.commands import VIEWER_COMMANDS
from ..net.async_server import AsyncServerThread, ServerStartError
from . import ASSET_DIR
from .avatar import SETUP_HINT, AvatarError, avatar_glb, three_files
from .media import SourceVideo, ranged
from .wire import EncodedRecord, build_bundle, encode_record

log = logging.getLogger(__name__)
logging.getLogger("websockets").setLevel(logging.WARNING)  # not a line per page load

#: commands the page may send, per channel (calibration node / bag player)
COMMANDS = VIEWER_COMMANDS  # what the page may send; the one list lives in messages/commands.py
#: the arguments each command takes: name -> (kind, required); kinds: "seconds" (finite, >= 0)
COMMAND_ARGS: dict[tuple[str, str], dict[str, tuple[str, bool]]] = {
    ("player", "seek"): {"position_s": ("seconds", True)},
}
MAX_SECONDS = 1e7  # no recording or command is longer than this (s); bigger numbers are refused
COMMAND_RATE_HZ = 10.0
MAX_MESSAGE_BYTES, MAX_MESSAGE_DEPTH = 64 * 1024, 8  # a page's command: checked before parsing
COMMAND_BURST = 20
_SERVED_SUFFIXES = (".html", ".js", ".css")


def check_command_args(channel: str, name: str, args: Any) -> dict[str, Any]:
    """``args`` if they match the command's schema; ValueError naming the bad key otherwise."""
    if not isinstance(args, dict):
        raise ValueError("args must be an object")
    schema = COMMAND_ARGS.get((channel, name), {})
    for key in args:
        if key not in schema:
            raise ValueError(f"{channel} {name} takes no argument {str(key)[:40]!r}"
                             + (f" (takes: {', '.join(schema)})" if schema else ""))
    for key, (kind, required) in schema.items():
        if key not in args:
            if required:
                raise ValueError(f"{channel} {name} needs {key!r}")
            continue
        v = args[key]
        if kind == "seconds" and not (isinstance(v, (int, float)) and not isinstance(v, bool)
                                      and math.isfinite(v) and 0 <= v <= MAX_SECONDS):
            raise ValueError(f"{channel} {name}: {key} must be a finite number of seconds in [0, {MAX_SECONDS:g}]")
    return args


class _Bucket:
    """Token bucket: ``take()`` is False once more than ``burst`` came faster than ``rate_hz``."""

    def __init__(self, rate_hz: float, burst: int) -> None:
        self.rate, self.burst, self.level, self.t = rate_hz, burst, float(burst), time.monotonic()

    def take(self) -> bool:
        now = time.monotonic()
        self.level = min(self.burst, self.level + (now - self.t) * self.rate)
        self.t = now
        if self.level >= 1.0:
            self.level -= 1.0
            return True
        return False


class ViewerStartError(ServerStartError):
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

    def entry(self, key: str) -> Entry | None:
        """A snapshot of the newest message of stream ``key`` (None if there is none)."""
        with self._lock:
            e = self._entries.get(key)
            return None if e is None else Entry(e.topic, e.key, e.version, e.env, e.msg)

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
    refused: int = 0
    bucket: _Bucket = field(default_factory=lambda: _Bucket(COMMAND_RATE_HZ, COMMAND_BURST), repr=False)


class ViewerServer(AsyncServerThread):
    """Serves the page and streams the store to every connected browser."""

    start_error = ViewerStartError
    thread_name = "viewer-server"
    what = "viewer"

    def __init__(self, store: LatestStore, hello: dict[str, Any], host: str = "127.0.0.1", port: int = 8765,
                 max_rate_hz: float = 60.0, window: int = 2, asset_dir: Path = ASSET_DIR, token: str = "",
                 allowed_origins: list[str] | None = None, allowed_hosts: list[str] | None = None) -> None:
        super().__init__(host, port)
        self.store = store
        #: every WebSocket and /stats request must carry it (``?token=``); per launch unless given
        self.token = token or secrets.token_urlsafe(18)
        self.allowed_origins = {o.rstrip("/") for o in (allowed_origins or [])}
        self.extra_hosts = [h.lower() for h in (allowed_hosts or [])]
        self.refused = 0
        self.hello = hello
        self.min_interval = 1.0 / max_rate_hz
        self.window = window
        self.assets = {"/" + p.relative_to(asset_dir).as_posix(): p for p in asset_dir.rglob("*")
                       if p.suffix in _SERVED_SUFFIXES and p.is_file()}
        #: the allow-listed three.js modules (node_modules/three); none when three.js is missing
        self.three = three_files()
        if not self.three:
            log.warning("viewer: %s (the page says so too)", SETUP_HINT)
        self._avatars: dict[str, tuple[int, bytes]] = {}   # CharacterInfo key -> (version, GLB)
        self.source_videos: dict[str, SourceVideo] = {}     # the graph's video readers' clips (by node)
        self.commands: queue.Queue[dict[str, Any]] = queue.Queue()
        self.clients: dict[int, ClientStats] = {}
        self.connects = 0
        self.started_ns = time.time_ns()
        self._event: asyncio.Event | None = None

    @property
    def url(self) -> str:
        """The page's address with the token: the one URL that works."""
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        host = f"[{host}]" if ":" in host else host
        return f"http://{host}:{self.port}/?token={quote(self.token)}"

    def stats(self) -> dict[str, Any]:
        clients = [{k: v for k, v in c.__dict__.items() if k != "bucket"} for c in list(self.clients.values())]
        return {"clients": clients, "connects": self.connects, "refused": self.refused,
                "store_puts": self.store.puts, "started_ns": self.started_ns}

    # ----- who may connect --------------------------------------------------------------------
    def _hosts(self) -> set[str]:
        names = {"127.0.0.1", "localhost", "[::1]", self.host.lower(), *self.extra_hosts}
        if self.host in ("0.0.0.0", "::", ""):
            names.add(socket.gethostname().lower())
            try:
                names.update(a[4][0] for a in socket.getaddrinfo(socket.gethostname(), None))
            except OSError:
                pass
        return {f"{h}:{self.port}" for h in names} | set(self.extra_hosts)

    def refusal(self, request: Request, need_token: bool) -> str:
        """Why ``request`` is refused ('' when it may proceed)."""
        hosts = request.headers.get_all("Host")
        host = hosts[0].lower() if len(hosts) == 1 else ""
        if host not in self._hosts():
            return f"Host {host[:80]!r} is not this viewer" if len(hosts) <= 1 else "more than one Host header"
        origins = request.headers.get_all("Origin")
        if len(origins) > 1:
            return "more than one Origin header"
        origin = origins[0] if origins else None
        if origin is not None and origin.rstrip("/") != f"http://{host}" and origin.rstrip("/") not in self.allowed_origins:
            return f"Origin {origin[:80]!r} is not allowed"
        if need_token:
            query = parse_qs(request.path.partition("?")[2])
            given = (query.get("token") or [""])[0]
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return "missing or wrong token (open the URL the viewer printed)"
        return ""

    # ----- server thread ----------------------------------------------------------------------
    def _on_loop(self, loop: asyncio.AbstractEventLoop) -> None:
        self._event = asyncio.Event()
        self.store._wake = lambda: loop.call_soon_threadsafe(self._notify)

    def _serve_options(self) -> dict[str, Any]:
        return {"compression": None, "max_size": 1 << 16, "ping_interval": 10, "ping_timeout": 30}

    def _notify(self) -> None:
        ev, self._event = self._event, asyncio.Event()
        ev.set()

    def _process_request(self, connection: ServerConnection, request: Request) -> Any:
        """The HTTP answer (a Response, a coroutine giving one for the avatar, None for /ws)."""
        path = request.path.split("?", 1)[0]
        why = self.refusal(request, need_token=path in ("/ws", "/stats", "/avatar.glb", "/source_video"))
        if why:
            self.refused += 1
            if self.refused <= 5 or self.refused % 100 == 0:
                log.warning("viewer: refused %s (%s); %d refused so far", path[:60], why, self.refused)
            body = (why + "\n").encode()
            return Response(403, "Forbidden", _headers("text/plain; charset=utf-8", len(body)), body)
        if path == "/ws":
            return None
        if path == "/":
            path = "/index.html"
        if path == "/stats":
            body = json.dumps(self.stats()).encode()
            ctype = "application/json"
        elif path == "/avatar.glb":
            return self._avatar(request)
        elif path == "/source_video":
            return self._source_video(request)
        elif path in self.three:
            body, ctype = self.three[path].read_bytes(), "text/javascript"
        elif path.startswith("/three/"):
            body = (SETUP_HINT if not self.three else "not a served three.js file").encode() + b"\n"
            return Response(404, "Not Found", _headers("text/plain; charset=utf-8", len(body)), body)
        elif path in self.assets:
            body = self.assets[path].read_bytes()
            ctype = mimetypes.guess_type(path)[0] or "application/octet-stream"
            if path.endswith(".js"):
                ctype = "text/javascript"
        else:
            body, ctype = b"not found\n", "text/plain"
            return Response(404, "Not Found", _headers(ctype, len(body)), body)
        return Response(200, "OK", _headers(ctype + "; charset=utf-8", len(body)), body)

    async def _avatar(self, request: Request) -> Response:
        """The mannequin GLB of the CharacterInfo stream ``?key=`` (404 with one line if none), built
        in a worker thread (the connections' sends go on meanwhile) and kept per stream version."""
        key = (parse_qs(request.path.partition("?")[2]).get("key") or [""])[0]
        snap = self.store.entry(key)
        if snap is None or snap.env.type_name != "CharacterInfo":
            body = f"no CharacterInfo stream {key[:80]!r}\n".encode()
            return Response(404, "Not Found", _headers("text/plain; charset=utf-8", len(body)), body)
        cached = self._avatars.get(key)
        if cached is None or cached[0] != snap.version:
            try:
                cached = (snap.version, await asyncio.to_thread(avatar_glb, snap.msg))  # type: ignore[arg-type]
            except AvatarError as exc:
                log.warning("viewer: %s", exc)
                body = f"{exc}\n".encode()
                return Response(422, "Unprocessable Content", _headers("text/plain; charset=utf-8", len(body)), body)
            self._avatars[key] = cached
        return Response(200, "OK", _headers("model/gltf-binary", len(cached[1])), cached[1])

    def set_source_videos(self, videos: dict[str, SourceVideo]) -> None:
        """The clips the page may play in step with their readers' skeletons (told in the hello)."""
        self.source_videos = dict(videos)
        self.hello["source_videos"] = [v.hello() for v in videos.values()]

    def _source_video(self, request: Request) -> Response:
        """Byte ranges of the clip of reader ``?node=`` (only a clip the graph's reader names)."""
        node = (parse_qs(request.path.partition("?")[2]).get("node") or [""])[0]
        video = self.source_videos.get(node)
        if video is None:
            body = f"no video reader {node[:80]!r} in this graph\n".encode()
            return Response(404, "Not Found", _headers("text/plain; charset=utf-8", len(body)), body)
        try:
            status, head, body = ranged(video.path, request.headers.get("Range"))
        except OSError as exc:
            body = f"{video.path.name}: {exc.strerror or exc}\n".encode()
            return Response(404, "Not Found", _headers("text/plain; charset=utf-8", len(body)), body)
        headers = _headers(head.pop("Content-Type"), len(body))
        for k, v in head.items():
            headers[k] = v
        return Response(status, {200: "OK", 206: "Partial Content", 416: "Range Not Satisfiable"}[status], headers, body)

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
            if not client.bucket.take():  # first: a flood of bad commands is limited too
                raise ValueError(f"too many commands (at most {COMMAND_RATE_HZ:g}/s); this one was dropped")
            req = loads_bounded(text, MAX_MESSAGE_BYTES, MAX_MESSAGE_DEPTH)
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
            check_command_args(channel, name, args)
        except (ValueError, TypeError) as exc:
            client.refused += 1
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
        return loads_bounded(text, MAX_MESSAGE_BYTES, MAX_MESSAGE_DEPTH).get("id")
    except (ValueError, TypeError, AttributeError):
        return None
