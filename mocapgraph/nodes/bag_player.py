"""Replays a bag into the graph with the recorded timing (see mocapgraph.bag.player)."""
from __future__ import annotations

import json
import math
import os
import time
from typing import Any

from ..bag.errors import BagError
from ..bag.player import Outgoing, Playback, select_topics, set_publish_stamp
from ..bag.reader import BagReader
from ..bus import Input, Interface, Node, Output, Param
from ..bus.node import NodeConfigError
from ..bus.file_places import PathRefused, own_folder_path
from ..messages.commands import PLAYER_COMMANDS, parse_command
from ..messages import NodeCommand, NodeStatus
from ..messages.registry import lookup

STATUS_PERIOD_S = 0.5


class BagPlayer(Node):
    """Publishes a bag's topics with their original types, sequence numbers and capture stamps.

    One clock drives all topics (relative timing kept at any rate, nothing early or out of
    order). Latched topics go out first. Commands on ``player_command`` (NodeCommand: play,
    pause, toggle, step, seek {"position_s"}, rate {"rate"}, stop); state on ``player_status``.
    Its outputs are the bag's topics, named after them, so a graph remaps them like any port.
    """

    summary = "replay an MCAP bag with its recorded timing (pause, step, seek, rate, loop)"
    #: its frames carry the recorded senders' names, not its own (the wiring allows unnamed senders)
    relays_senders = True
    file = Param("", "the .mcap bag to play")
    rate = Param(1.0, "playback speed factor", minimum=1e-3)
    loop = Param(False, "start over at the end")
    start = Param(0.0, "start this many seconds into the bag", minimum=0.0)
    end = Param(0.0, "stop this many seconds into the bag (0: at its end)", minimum=0.0)
    topics = Param([], "bag topics to play (empty: all but diagnostics)")
    exclude = Param("", "regular expression of topics not to play")
    paused = Param(False, "start paused (send 'play' or 'step')")
    stop_at_end = Param(True, "leave the graph when the bag has been played (no loop)")
    realtime = Param(False, "ask the OS for real-time scheduling (SCHED_FIFO 10): steady timing on a busy machine")
    status = Output("player_status", NodeStatus, "state, position, rate and lag, on change and twice a second")
    command = Input("player_command", NodeCommand, "play/pause/toggle/step/seek/rate/stop", required=False)

    @classmethod
    def interface(cls, params: dict[str, Any]) -> Interface:
        iface = super().interface(params)
        path = params.get("file", "")
        if not path:
            return iface
        try:
            own_folder_path(path, "bag")  # a regular file: never a device or fifo (which would block)
            with BagReader(path) as r:
                chosen, _ = select_topics(r.topic_infos(), params.get("topics") or None,
                                          params.get("exclude") or None)
        except (BagError, PathRefused) as exc:
            iface.bag_error = str(exc)  # reported by check_params with the graph's file and line
            return iface
        for topic, info in chosen.items():
            iface.outputs[topic] = Output(topic, lookup(info.type_name), f"from the bag ({info.count} messages)",
                                          latched=info.latched, name=topic)
        return iface

    @classmethod
    def check_params(cls, given: dict[str, Any], iface: Interface | None = None) -> dict[str, Any]:
        iface = iface or cls.interface(given)
        error = getattr(iface, "bag_error", "")
        if error:
            raise NodeConfigError(f"parameter 'file': {error}")
        return super().check_params(given, iface)

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        if not self.file:
            raise NodeConfigError("parameter 'file' is empty: name the bag to play")
        try:
            own_folder_path(self.file, "parameter 'file'")
            self.reader = BagReader(self.file)
        except (BagError, PathRefused) as exc:
            raise NodeConfigError(str(exc)) from None
        try:
            self.playback = Playback(self.reader, topics=self.topics or None, exclude=self.exclude or None,
                                     rate=self.rate, start_s=self.start, end_s=self.end or None, loop=self.loop)
        except BagError as exc:
            raise NodeConfigError(str(exc)) from None
        self._timer = None
        self._last_state = ""
        self._status_at = 0.0
        self.error = ""
        self.command_error = ""  # why the last command was refused ('' when it was not)
        self.finished_at: float | None = None

    # ----- sending ---------------------------------------------------------------------------------
    def _send(self, items: list[Outgoing]) -> None:
        for o in items:
            port = self._by_topic.get(o.topic)
            if port is None:
                continue
            set_publish_stamp(o.frames[1])
            port.publish_frames(o.frames, latched=o.latched)
        self.playback.record_sent(items, time.monotonic())

    def _ask_realtime(self) -> None:
        # On a loaded machine a woken process can wait milliseconds for a CPU; a real-time class
        # lets the player preempt ordinary work. It sleeps between messages, and the kernel's RT
        # throttling caps it at 95 % of a core should it ever spin.
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
            self.log.info("real-time scheduling on (SCHED_FIFO 10)")
        except (AttributeError, OSError) as exc:
            self.log.warning("real-time scheduling refused (%s); timing may suffer on a busy machine", exc)

    def on_start(self) -> None:
        if self.realtime:
            self._ask_realtime()
        # bag topic -> bound output port (its topic may be remapped by the graph)
        self._by_topic = {}
        for name, port in self.output_ports.items():
            if name in self.playback.topics:
                self.playback.remap[name] = port.topic
                self._by_topic[port.topic] = port
        try:
            self._send(self.playback.latched_first())
            self.playback.begin(paused=self.paused)
            self.playback.fill(budget_s=0.05)  # read ahead now, not between two due messages
        except BagError as exc:
            self.error = str(exc)
            self.log.error("%s", exc)
            self.request_stop()
            return
        self._timer = self.add_timer(0.001, self._pump, first_delay_s=0.0)
        self._publish_status()

    def _pump(self) -> None:
        try:
            self._pump_once()
        except BagError as exc:  # damage found mid-file: say so and leave, no traceback
            self.error = str(exc)
            self.log.error("%s", exc)
            self.playback.state = "failed"
            self._publish_status()
            self.request_stop()

    def _pump_once(self) -> None:
        pb = self.playback
        items = pb.take_due()
        if items:
            self._send(items)
        due = pb.next_due()
        now = time.monotonic()
        if due is None:
            self._timer.reschedule(now + 0.02)
            if pb.state == "finished":
                self._finished(now)
        else:
            self._timer.reschedule(due)
        # Reading ahead and status reports only in idle time, so they never delay a due message.
        idle = (due - now) if due is not None else 1.0
        if idle > 0.003:
            pb.fill(min(0.002, idle - 0.002))
        if pb.state != self._last_state or (idle > 0.003 and now - self._status_at >= STATUS_PERIOD_S):
            self._publish_status()

    def _finished(self, now: float) -> None:
        if self.finished_at is None:
            self.finished_at = now
            p50, p99, pmax = self.playback.lag_ms()
            self.log.info("played %d messages; lag p50 %.3f ms, p99 %.3f ms, max %.3f ms",
                          self.playback.sent, p50, p99, pmax)
            self._publish_status()
        if self.stop_at_end and now - self.finished_at > 0.2:  # let the last frames leave
            self.request_stop()

    # ----- commands and status ---------------------------------------------------------------------
    def on_command(self, cmd: NodeCommand) -> None:
        if cmd.target not in ("", self.name):
            return
        self.command_error = ""
        try:
            self.handle(cmd.command, parse_command(cmd.command, cmd.args_json, PLAYER_COMMANDS))
        except (ValueError, TypeError, KeyError, OverflowError, BagError) as exc:
            # A bad command is answered on player_status and changes nothing: the player plays on.
            self.command_error = f"command {cmd.command[:40]!r} refused: {exc}"
            self.log.warning("%s", self.command_error)
        self._publish_status()

    def handle(self, command: str, args: dict[str, Any] | None = None) -> None:
        """Apply a command: play, pause, toggle, step, seek {position_s}, rate {rate}, stop."""
        args = args or {}
        pb = self.playback
        if command not in PLAYER_COMMANDS:
            raise ValueError(f"unknown command {command!r} ({', '.join(PLAYER_COMMANDS)})")
        if command == "play":
            pb.resume()
        elif command == "pause":
            pb.pause()
        elif command == "toggle":
            pb.toggle()
        elif command == "step":
            if pb.state == "playing":
                pb.pause()
            self._send(pb.step())  # BagError: reported by on_command
        elif command == "seek":
            pb.seek(_seconds(args, "position_s", pb.duration_s))
            self.finished_at = None
        elif command == "rate":
            rate = args.get("rate")
            if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (1e-3 <= rate <= 1e3):
                raise ValueError(f"rate wants a number in [0.001, 1000], got {str(rate)[:40]}")
            pb.set_rate(float(rate))
        elif command == "stop":
            self.request_stop()
        if self._timer is not None:
            self._timer.reschedule(time.monotonic())

    def status_data(self) -> dict[str, Any]:
        pb = self.playback
        p50, p99, pmax = pb.lag_ms()

        def num(x: float) -> float | None:
            return None if math.isnan(x) else round(x, 4)

        return {"error": self.command_error, "position_s": round(pb.position_s, 4),
                "duration_s": round(pb.duration_s, 4), "rate": pb.rate,
                "achieved_rate": num(pb.achieved_rate), "lag_p50_ms": num(p50), "lag_p99_ms": num(p99),
                "lag_max_ms": num(pmax), "sent": pb.sent, "loops": pb.loops, "file": str(self.reader.path)}

    def _publish_status(self) -> None:
        pb = self.playback
        self._last_state = pb.state
        self._status_at = time.monotonic()
        d = self.status_data()
        detail = f"{d['position_s']:.2f}/{d['duration_s']:.2f} s at {pb.rate:g}x"
        if self.command_error:
            detail += f"; {self.command_error}"
        progress = d["position_s"] / d["duration_s"] if d["duration_s"] > 0 else float("nan")
        self.status.publish(NodeStatus(node=self.name, state=pb.state, detail=detail, progress=progress,
                                       data_json=json.dumps(d)))

    def on_stop(self) -> None:
        self.reader.close()


def _seconds(args: dict[str, Any], key: str, duration_s: float) -> float:
    """``args[key]`` as a position in the bag, s; ValueError unless it is a finite number in [0, duration]."""
    if key not in args:
        raise ValueError(f"needs {key!r} (s)")
    v = args[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise ValueError(f"{key} wants a finite number of seconds >= 0, got {str(v)[:40]}")
    return min(float(v), duration_s)
