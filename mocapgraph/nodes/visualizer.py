"""The visualizer node: a live 3D stage in the browser at http://127.0.0.1:<port>/.

It subscribes to the pipeline's topics (every one optional: a topic that nothing publishes is
simply not shown), keeps the newest message per stream and streams them to each browser at the
browser's own pace over a WebSocket (see `viewer.server`). Buttons on the page come back as
`NodeCommand` on ``calibration_command`` / ``player_command``.

Inputs take every message (``latest_only`` False) on purpose: the runtime's latest-only keeps one
message per socket read across all senders, which would hide all but one actor on a shared
``actor_pose`` topic and all but one node's ``diagnostics``. The node instead keeps the newest per
(topic, sender, actor) in its store; a short socket queue bounds what a stalled loop can hold.
"""
from __future__ import annotations

import importlib
import json
import queue
import secrets
import threading
import webbrowser
from typing import Any, Callable

from ..bus import Input, Interface, Node, Output, Param
from ..bus.user_dir import UnsafeDirError, secret_file
from ..messages import Message, NodeCommand
from ..viewer.server import COMMANDS, LatestStore, ViewerServer, ViewerStartError
from .stage_inputs import stage_inputs

FRAME_QUEUE = 64  # messages a per-frame input's socket holds before dropping (counted as gaps)
# The field naming a stream inside a topic, per type (several actors on one actor_pose topic).
_IDENT_FIELD = {"ActorPose": "actor", "SkeletonPose": "source_id", "CharacterPose": "character",
                "CharacterInfo": "character", "Diagnostics": "node", "NodeStatus": "node"}


class Visualizer(stage_inputs(FRAME_QUEUE), Node):
    """Serves the live 3D stage page and streams the subscribed topics to it."""

    summary = "live 3D stage in the browser (HTTP + WebSocket on 127.0.0.1, port a param)"

    # inputs: every topic of stage_inputs.STAGE_TOPICS (declared by the base), FRAME_QUEUE messages each

    calibration_command = Output("calibration_command", NodeCommand, "find_base_pose, capture_gym, process")
    player_command = Output("player_command", NodeCommand, "play, pause, step, seek {position_s: seconds} (the bag player's commands)")

    host = Param("127.0.0.1", "address the page is served on (loopback unless you mean otherwise)")
    port = Param(8765, "HTTP and WebSocket port; 0 picks a free one (printed at start)", minimum=0,
                 maximum=65535)
    max_rate_hz = Param(60.0, "most bundles per second sent to one browser, Hz", minimum=1.0)
    window = Param(2, "bundles a browser may have unacknowledged before sending pauses", minimum=1)
    extra_topics = Param([], "further topics to list on the page (any type; unknown types are not drawn)")
    reference_topics = Param(["ground_truth"], "topics drawn as a neutral reference (e.g. a synthetic actor's "
                             "ground truth) instead of by quality")
    message_modules = Param([], "modules to import so that their message types decode (plugins)")
    open_browser = Param(False, "open the page in the default browser at start")
    title = Param("mocapgraph", "page title")
    allowed_origins = Param([], "further page origins allowed to connect, e.g. ['http://render-pc:8765'] "
                            "(the page's own origin always is)")
    allowed_hosts = Param([], "further names this viewer is reached by, as host:port (DNS-rebinding defence: "
                          "any other Host header is refused)")
    token = Param("", "access token every connection must present (empty: a random one, kept per user and "
                  "port in the 0700 run directory so an open tab reconnects after a restart; in the printed URL)")

    @classmethod
    def interface(cls, params: dict[str, Any]) -> Interface:
        iface = super().interface(params)
        for i, topic in enumerate(params.get("extra_topics", cls.extra_topics.default)):
            name = f"extra{i}"
            iface.inputs[name] = Input(str(topic), None, f"listed topic {topic}", queue=FRAME_QUEUE,
                                       required=False, name=name)
        return iface

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring: Any = None) -> None:
        super().__init__(name, params, wiring)
        for module in self.params["message_modules"]:
            importlib.import_module(module)
        self.store = LatestStore()
        self.server: ViewerServer | None = None

    def input_handler(self, port_name: str) -> Callable[[Message], Any]:
        port = self.bound_port(port_name)
        put = self.store.put

        def store(msg: Message) -> None:
            env = port.envelope
            ident = getattr(msg, _IDENT_FIELD.get(env.type_name, ""), "") if env.type_name in _IDENT_FIELD else ""
            put(port.topic, ident, env, msg)

        return store

    def setup(self) -> None:
        super().setup()
        topics = {name: {"topic": p.topic, "type": p.decl.type_name, "latched": p.decl.latched}
                  for name, p in self.input_ports.items()}
        hello = {"node": self.name, "title": self.title, "topics": topics,
                 "reference_topics": list(self.reference_topics),
                 "commands": {ch: list(cmds) for ch, cmds in COMMANDS.items()},
                 "command_topics": {"calibration": self.calibration_command.topic,
                                    "player": self.player_command.topic}}
        try:
            token = self.token or (secret_file(f"viewer-{self.port}.token", lambda: secrets.token_urlsafe(18))
                                   if self.port else "")
        except (UnsafeDirError, OSError) as exc:
            self.log.error("viewer token: %s", exc)
            raise SystemExit(2) from None
        self.server = ViewerServer(self.store, hello, self.host, self.port, self.max_rate_hz, self.window,
                                   token=token, allowed_origins=list(self.allowed_origins),
                                   allowed_hosts=list(self.allowed_hosts))
        try:
            self.server.start()
        except ViewerStartError as exc:
            self.log.error("%s", exc)
            raise SystemExit(2) from None
        self.log.info("viewer at %s", self.server.url)
        self._find_source_videos()
        self.add_timer(0.02, self._publish_commands)

    def _find_source_videos(self) -> None:
        """The video readers' clips named in the graph's manifest, for the page's video panel."""
        from ..bus.manifest import fetch_manifest
        from ..viewer.media import source_videos

        try:
            videos = source_videos(fetch_manifest(timeout_s=1.0))
        except (RuntimeError, OSError, ValueError) as exc:   # no launcher (a node run on its own)
            self.log.debug("no manifest for source videos: %s", exc)
            return
        self.server.set_source_videos(videos)
        for v in videos.values():
            self.log.info("video panel can follow %s: %s at %g fps", v.node, v.path.name, v.fps)

    def on_start(self) -> None:
        if self.open_browser:
            threading.Thread(target=webbrowser.open, args=(self.server.url,), daemon=True).start()

    def _publish_commands(self) -> None:
        while True:
            try:
                cmd = self.server.commands.get_nowait()
            except queue.Empty:
                return
            out = self.calibration_command if cmd["channel"] == "calibration" else self.player_command
            out.publish(NodeCommand(target=cmd["target"], command=cmd["command"],
                                    args_json=json.dumps(cmd["args"])))
            self.log.info("sent %s to %s on %s", cmd["command"], cmd["target"] or "every listener", out.topic)

    def on_stop(self) -> None:
        if self.server is not None:
            self.server.stop()
