"""The Foxglove WebSocket protocol (``foxglove.websocket.v1``) served behind our token gate, one port.

Why not the foxglove-sdk's own server: it has no authentication and no way to hand it a socket or
refuse a connection (0.30: ``start_server`` takes host, port, TLS and listeners told of
subscriptions, never of connections), so any local process that found its port could read the
graph. This server speaks the protocol as documented (github.com/foxglove/ws-protocol,
docs/spec.md) for what a data source needs: ``serverInfo`` and ``advertise`` on connect,
``advertise`` for each new channel, ``subscribe``/``unsubscribe`` from the client, binary Message
Data (opcode 1, uint32 subscription id, uint64 log time ns, payload, little-endian) and ``status``
replies to anything it does not support (no capabilities are offered). Payloads and schemas come
encoded from the caller (the SDK's schemas, :mod:`mocapgraph.bag.foxglove_scene`).

Threads: the node thread calls `add_channel`, `subscribed` and `log`; everything else runs on the
server's loop. Each client has a bounded queue of data messages (the oldest dropped when it holds
``backlog`` messages or CLIENT_BYTES bytes, counted in ``dropped``) and a control queue of
``backlog`` messages (a client that lets it fill is disconnected), as the SDK's
``message_backlog_size`` does. At most ``max_clients`` are connected at once (more get a 503 in
one line), so stalled clients hold a bounded amount of memory, given back when they leave.
Connection lines (the websockets library's, two per connection or refusal) are rate-limited.
"""
from __future__ import annotations

import asyncio
import base64
import json
import struct
import time
from collections import deque
from dataclasses import dataclass, field
from itertools import count
from typing import Any, Sequence

from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed

from websockets.http11 import Request, Response

from ..bus.peer_guard import give_back_heap
from ..messages.bounded_json import loads_bounded
from .log_limit import limited_logger
from .ws_gate import GatedServer

SUBPROTOCOL = "foxglove.websocket.v1"
MESSAGE_DATA = 0x01
MAX_CLIENT_BYTES, MAX_CLIENT_DEPTH = 256 * 1024, 8  # a client op (subscribe lists: 30 B each): checked before parsing
_HEADER = struct.Struct("<BIQ")
STATUS_INFO, STATUS_WARNING, STATUS_ERROR = 0, 1, 2
#: bytes of data messages queued for one client at most (the oldest dropped beyond)
CLIENT_BYTES = 4 << 20


@dataclass(frozen=True)
class Channel:
    """One advertised channel; ``schema`` as sent (base64 for binary schemas, text for JSON Schema)."""

    id: int
    topic: str
    encoding: str
    schema_name: str
    schema: str
    schema_encoding: str

    def advert(self) -> dict[str, Any]:
        return {"id": self.id, "topic": self.topic, "encoding": self.encoding, "schemaName": self.schema_name,
                "schema": self.schema, "schemaEncoding": self.schema_encoding}


@dataclass(eq=False)  # hashed by identity: kept in a set
class _Client:
    ws: ServerConnection
    data: deque
    control: deque = field(default_factory=deque)
    subs: dict[int, int] = field(default_factory=dict)      # subscription id -> channel id
    by_chan: dict[int, int] = field(default_factory=dict)   # channel id -> subscription id
    dropped: int = 0
    queued: int = 0   # bytes in ``data``
    wake: Any = None


class FoxgloveServer(GatedServer):
    """Foxglove WebSocket server on ``host:port`` with the gate's checks; ``backlog`` messages per client."""

    thread_name = "foxglove-ws"
    what = "foxglove bridge"

    def __init__(self, name: str, host: str, port: int, token: str, origins: Sequence[str],
                 backlog: int = 1024, max_clients: int = 16) -> None:
        super().__init__(host, port, token, origins)
        self.name = name
        self.backlog = backlog
        self.max_clients = max_clients
        self.session_id = str(time.time_ns())
        self.channels: dict[int, Channel] = {}      # loop thread's view (advertised)
        self.clients: set[_Client] = set()
        self.dropped = 0                             # data messages dropped for slow clients, all clients
        self.disconnected_slow = 0
        self._ids = count(1)
        self._subscribers: dict[int, int] = {}      # channel id -> clients subscribed (read by the node thread)
        self._inbox: deque = deque()
        self._scheduled = False

    def _serve_options(self) -> dict[str, Any]:
        return {"subprotocols": [SUBPROTOCOL], "compression": None, "max_size": 1 << 20,
                "ping_interval": 10, "ping_timeout": 30, "logger": limited_logger("mocapgraph.foxglove.ws")}

    def _process_request(self, connection: ServerConnection, request: Request) -> Response | None:
        refused = super()._process_request(connection, request)
        if refused is None and len(self.clients) >= self.max_clients:
            return self._refuse("full", 503, "Service Unavailable",
                                f"{self.max_clients} clients are connected, the most this bridge serves "
                                "(its max_clients); try again when one has left")
        return refused

    # ----- node thread -------------------------------------------------------------------------
    def add_channel(self, topic: str, encoding: str, schema_name: str, schema: bytes, schema_encoding: str) -> int:
        """Advertise a channel to every client (now and on connect); its id for `log`."""
        text = base64.b64encode(schema).decode() if schema_encoding in ("protobuf", "flatbuffer") else schema.decode()
        ch = Channel(next(self._ids), topic, encoding, schema_name, text, schema_encoding)
        self._post(("advertise", ch))
        return ch.id

    def subscribed(self, channel_id: int) -> bool:
        """Whether some client subscribes to the channel (so the caller may skip encoding)."""
        return self._subscribers.get(channel_id, 0) > 0

    def log(self, channel_id: int, data: bytes, log_ns: int) -> None:
        """Send one message to every client subscribed to the channel."""
        self._post(("data", channel_id, data, log_ns))

    def _post(self, item: tuple) -> None:
        self._inbox.append(item)
        # One wake-up per batch: the loop clears the flag before draining, so an item appended
        # after its last look schedules the next drain.
        if not self._scheduled:
            self._scheduled = True
            if not self.call_soon(self._drain):
                self._scheduled = False

    # ----- loop thread -------------------------------------------------------------------------
    def _drain(self) -> None:
        self._scheduled = False
        inbox = self._inbox
        while inbox:
            item = inbox.popleft()
            if item[0] == "data":
                _, cid, data, ns = item
                for c in self.clients:
                    sub = c.by_chan.get(cid)
                    if sub is not None:
                        frame = _HEADER.pack(MESSAGE_DATA, sub, ns) + data
                        while c.data and (len(c.data) == c.data.maxlen or c.queued + len(frame) > CLIENT_BYTES):
                            c.queued -= len(c.data.popleft())
                            c.dropped += 1
                            self.dropped += 1
                        c.data.append(frame)
                        c.queued += len(frame)
                        c.wake.set()
            else:
                ch = item[1]
                self.channels[ch.id] = ch
                msg = json.dumps({"op": "advertise", "channels": [ch.advert()]})
                for c in list(self.clients):
                    self._control(c, msg)

    def _control(self, c: _Client, text: str) -> None:
        if len(c.control) >= self.backlog:
            # A client that stops reading control messages is gone in all but name.
            self.disconnected_slow += 1
            self._forget(c)
            c.ws.transport.abort()
            return
        c.control.append(text)
        c.wake.set()

    def _status(self, c: _Client, level: int, message: str) -> None:
        self._control(c, json.dumps({"op": "status", "level": level, "message": message}))

    def _forget(self, c: _Client) -> None:
        if c in self.clients:
            self.clients.discard(c)
            for cid in c.by_chan:
                self._subscribers[cid] = self._subscribers.get(cid, 1) - 1
            c.by_chan.clear()
            c.subs.clear()

    async def _handle(self, ws: ServerConnection) -> None:
        self.accepted += 1
        c = _Client(ws, deque(maxlen=self.backlog), wake=asyncio.Event())
        self.clients.add(c)
        c.control.append(json.dumps({"op": "serverInfo", "name": self.name, "capabilities": [],
                                     "metadata": {}, "sessionId": self.session_id}))
        if self.channels:
            c.control.append(json.dumps({"op": "advertise",
                                         "channels": [ch.advert() for ch in self.channels.values()]}))
        sender = asyncio.create_task(self._send_loop(c))
        try:
            async for msg in ws:
                self._on_message(c, msg)
                if c not in self.clients:
                    break
        except ConnectionClosed:
            pass
        finally:
            sender.cancel()
            await asyncio.gather(sender, return_exceptions=True)
            self._forget(c)
            c.data.clear()
            c.control.clear()
            if not self.clients:   # what stalled clients held goes back to the system
                self._loop.call_later(0.5, give_back_heap)

    async def _send_loop(self, c: _Client) -> None:
        try:
            while True:
                if c.control:
                    await c.ws.send(c.control.popleft())
                elif c.data:
                    frame = c.data.popleft()
                    c.queued -= len(frame)
                    await c.ws.send(frame)
                else:
                    c.wake.clear()
                    await c.wake.wait()
        except ConnectionClosed:
            pass

    def _on_message(self, c: _Client, msg: str | bytes) -> None:
        if isinstance(msg, bytes):
            self._status(c, STATUS_ERROR, "binary client messages are not supported (no clientPublish capability)")
            return
        try:
            req = loads_bounded(msg, MAX_CLIENT_BYTES, MAX_CLIENT_DEPTH)
        except ValueError as exc:  # also too long or too deep (checked before parsing: no RecursionError)
            self._status(c, STATUS_ERROR, f"not JSON ({str(exc)[:80]}): " + msg[:60])
            return
        op = req.get("op") if isinstance(req, dict) else None
        if op == "subscribe":
            self._subscribe(c, req.get("subscriptions"))
        elif op == "unsubscribe":
            self._unsubscribe(c, req.get("subscriptionIds"))
        else:
            self._status(c, STATUS_ERROR, f"unsupported op {str(op)[:40]!r} (this server offers no capabilities)")

    def _subscribe(self, c: _Client, subs: Any) -> None:
        if not isinstance(subs, list):
            self._status(c, STATUS_ERROR, "subscribe: 'subscriptions' must be a list")
            return
        for s in subs:
            sid = s.get("id") if isinstance(s, dict) else None
            cid = s.get("channelId") if isinstance(s, dict) else None
            if not (isinstance(sid, int) and isinstance(cid, int)) or isinstance(sid, bool) or not 0 <= sid < 2**32:
                self._status(c, STATUS_ERROR, f"subscribe: each subscription needs integer id and channelId: {str(s)[:60]}")
            elif sid in c.subs:
                self._status(c, STATUS_ERROR, f"subscribe: subscription id {sid} is already in use")
            elif cid not in self.channels:
                self._status(c, STATUS_ERROR, f"subscribe: no channel {cid}")
            elif cid in c.by_chan:
                self._status(c, STATUS_WARNING, f"subscribe: already subscribed to channel {cid}")
            else:
                c.subs[sid] = cid
                c.by_chan[cid] = sid
                self._subscribers[cid] = self._subscribers.get(cid, 0) + 1

    def _unsubscribe(self, c: _Client, ids: Any) -> None:
        if not isinstance(ids, list):
            self._status(c, STATUS_ERROR, "unsubscribe: 'subscriptionIds' must be a list")
            return
        for sid in ids:
            cid = c.subs.pop(sid, None) if isinstance(sid, int) else None
            if cid is None:
                self._status(c, STATUS_WARNING, f"unsubscribe: no subscription {str(sid)[:20]}")
                continue
            del c.by_chan[cid]
            self._subscribers[cid] -= 1
