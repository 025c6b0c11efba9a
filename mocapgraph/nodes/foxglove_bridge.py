"""Foxglove bridge node: the live graph in the Foxglove app, over Foxglove's WebSocket protocol.

One port, ``host:port``, and it needs the per-launch token, an allowed Origin and a Host naming
it, as the viewer does: :mod:`mocapgraph.net.foxglove_ws` serves the protocol behind the gate's
checks (the foxglove-sdk's own server cannot be locked); the SDK gives the schemas. In Foxglove:
Open connection > Foxglove WebSocket > the ``ws://127.0.0.1:<port>/?token=...`` URL the node prints. Channels (created as
their topics first arrive): ``/markers``, ``/actor_pose``, ``/skeleton_pose``, ``/character_pose``,
``/physics_state`` as ``foxglove.SceneUpdate`` for the 3D panel (what is drawn:
:mod:`mocapgraph.bag.foxglove_scene`), ``/diagnostics/<node>`` as JSON for the Plot panel,
``/calibration_status`` and ``/player_status`` as JSON. A
frame is encoded only while some client subscribes to its channel.
"""
from __future__ import annotations

import secrets
from typing import Any, Callable

from ..bag.foxglove_scene import FoxgloveMessage, SceneBuilder, scene_schema
from ..bus import Node, Param
from ..messages import Diagnostics, Message
from ..net.foxglove_ws import FoxgloveServer
from ..net.ws_gate import GateStartError
from .stage_inputs import stage_inputs

QUEUE = 256  # messages per input socket before dropping (counted as gaps)
FOXGLOVE_APP_ORIGIN = "https://app.foxglove.dev"


class FoxgloveBridge(stage_inputs(QUEUE), Node):
    """Serves markers, actors, skeletons, characters, physics bodies and diagnostics to Foxglove."""

    summary = "the live graph in the Foxglove app (Foxglove WebSocket protocol, token on 127.0.0.1)"

    # inputs: every topic of stage_inputs.STAGE_TOPICS (declared by the base), QUEUE messages each

    host = Param("127.0.0.1", "address Foxglove connects to (loopback unless you mean otherwise)")
    port = Param(8766, "WebSocket port; 0 picks a free one (printed at start)", minimum=0, maximum=65535)
    token = Param("", "token clients must give as ?token=; '' makes a new one each start (printed)")
    allowed_origins = Param([FOXGLOVE_APP_ORIGIN], "browser origins allowed to connect (the Foxglove web app); "
                            "the desktop app sends none and is allowed")
    backlog = Param(1024, "messages buffered per client before the oldest are dropped", minimum=16)
    max_clients = Param(16, "clients connected at once at most (more are refused with 503)", minimum=1)

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring: Any = None) -> None:
        super().__init__(name, params, wiring)
        self.builder = SceneBuilder()
        self.channels: dict[str, int] = {}  # Foxglove topic -> channel id
        self.server: FoxgloveServer | None = None
        self.sent = 0

    def input_handler(self, port_name: str) -> Callable[[Message], Any]:
        port = self._ports[port_name]
        feed = self.builder.feed
        latched = bool(port.decl.latched)

        def handle(msg: Message) -> None:
            server = self.server
            # Unwatched frames are not even encoded; definitions (latched) are always kept.
            if not latched:
                fox = f"/{port.topic}/{msg.node}" if isinstance(msg, Diagnostics) else f"/{port.topic}"
                cid = self.channels.get(fox)
                if cid is not None and not server.subscribed(cid):
                    return
            for m in feed(port.envelope, msg, port.topic):
                cid = self.channels.get(m.topic) or self._channel(m)
                if server.subscribed(cid):
                    server.log(cid, m.data, m.log_ns)
                    self.sent += 1

        return handle

    def _channel(self, m: FoxgloveMessage) -> int:
        if m.encoding == "protobuf":
            name, data = scene_schema()  # the SDK's own foxglove.SceneUpdate descriptor
            cid = self.server.add_channel(m.topic, "protobuf", name, data, "protobuf")
        else:
            cid = self.server.add_channel(m.topic, m.encoding, m.schema, m.schema_data, "jsonschema")
        self.channels[m.topic] = cid
        return cid

    def setup(self) -> None:
        token = self.token or secrets.token_urlsafe(18)
        self.server = FoxgloveServer(f"mocapgraph {self.name}", self.host, self.port, token, self.allowed_origins,
                                     self.backlog, self.max_clients)
        try:
            self.server.start()
        except GateStartError as exc:
            self.log.error("%s", exc)
            raise SystemExit(2) from None
        super().setup()
        self.log.info("foxglove bridge at %s (Foxglove: Open connection > Foxglove WebSocket)", self.server.url)

    def on_stop(self) -> None:
        if self.server is not None:
            self.server.stop()
            s = self.server
            self.log.info("foxglove bridge: %d messages sent, %d connections, %d dropped for slow clients, "
                          "refused %s", self.sent, s.accepted, s.dropped, s.refused or "none")
