"""A node for the physics tests: sends scripted NodeCommands at set times after it starts."""
from __future__ import annotations

import json
import time

from mocapgraph.bus import Node, Output, Param
from mocapgraph.messages import NodeCommand


class CommandScript(Node):
    """Publishes each ``{at_s, command, args}`` of ``script`` on ``physics_command`` at its time."""

    summary = "scripted NodeCommands for tests"
    physics_command = Output("physics_command", NodeCommand, "the scripted commands")
    script = Param([], "[{at_s: seconds after start, command: name, args: {...}}]")

    def on_start(self) -> None:
        self.t0 = time.monotonic()
        self.todo = sorted(self.script, key=lambda c: c["at_s"])
        self.add_timer(0.01, self._tick)

    def _tick(self) -> None:
        now = time.monotonic() - self.t0
        while self.todo and self.todo[0]["at_s"] <= now:
            c = self.todo.pop(0)
            self.physics_command.publish(NodeCommand(target="", command=c["command"],
                                                     args_json=json.dumps(c.get("args", {}))))
