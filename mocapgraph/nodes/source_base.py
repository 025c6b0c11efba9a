"""What every source node shares: a status topic, a clean failure exit, rate-limited warnings,
data-file lookup, and file playback (real time scaled, loop, start/end frame).

Failure: a source whose input is unusable (missing or broken file, bad layout or device file)
logs ONE line and exits with code 1 after the graph has started, so that with ``required: false``
the rest of the graph keeps running and with ``required: true`` the launcher stops it.

Playback time: frame ``k`` of the file is published at ``t0 + file_time(k) / rate_scale`` of the
monotonic clock (``rate_scale`` 0 = as fast as possible) and stamped with the capture time
``wall_t0 + file_time(k)``, so bags and the solver see the file's own spacing whatever the speed.
Looping continues the capture time (the next pass starts one frame period after the last frame).
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..bus import Node, Output, Param
from ..bus.diagnostics import EdgeRecord
from ..bus.input_files import PROJECT_ROOT, InputFileError, resolve_input_file  # noqa: F401 (re-export)
from ..formats import FormatError
from ..kinematics.layout import LayoutError
from ..messages import NodeStatus
from ..formats.device_file import DeviceConfigError

STATUS_PERIOD_S = 1.0


class SourceError(ValueError):
    """A source cannot run with its input (one line naming the file or device and the fault)."""


#: exceptions that mean "this input is unusable": reported in one line, never as a traceback
INPUT_ERRORS = (FormatError, LayoutError, DeviceConfigError, SourceError)


def resolve_data_path(path: str) -> Path:
    """A data file named in a graph: absolute, relative to the working directory, or relative to
    the project root (so ``../shared/data/...`` works from anywhere). SourceError if absent.
    The graph check applies the same rule (:mod:`mocapgraph.bus.input_files`)."""
    try:
        return resolve_input_file(path)
    except InputFileError as exc:
        raise SourceError(str(exc) if path else "no file given (set the 'file' parameter)") from None


class SourceNode(Node):
    """Base of the readers: ``fail()``, a latched NodeStatus on ``reader_status``, limited logs.

    Subclasses may list extra per-device incoming edges in ``device_edges()``; they are appended
    to the node's Diagnostics so ``topic echo diagnostics`` shows device rates and rejects.
    """

    status = Output("reader_status", NodeStatus, "latched state of this source (playing, streaming, "
                    "reconnecting, finished, error) with its counters as JSON", latched=True)

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.exit_code = 0
        self.state = "starting"
        self.detail = ""
        self.progress = math.nan
        self._warned: dict[str, list[float]] = {}  # key -> [count, last log time]
        # Timers run only once the graph has started: no status before the sockets exist.
        self.add_timer(STATUS_PERIOD_S, self.publish_status)

    # ----- state and failure --------------------------------------------------------------
    def status_data(self) -> dict[str, Any]:
        """Counters shown in the status message (subclasses add theirs)."""
        return {}

    def set_state(self, state: str, detail: str = "", progress: float = math.nan) -> None:
        """Change state; published at once on change, else once a second."""
        changed = (state, detail) != (self.state, self.detail)
        self.state, self.detail, self.progress = state, detail, progress
        if changed:  # sources change state only once started (in on_start or later)
            self.publish_status()

    def publish_status(self) -> None:
        self.status.publish(NodeStatus(node=self.name, state=self.state, detail=self.detail,
                                       progress=float(self.progress),
                                       data_json=json.dumps(self.status_data(), default=float)))

    def fail(self, message: str) -> None:
        """Log ``message`` (one line), publish state 'error' and leave with exit code 1."""
        self.log.error("%s", message)
        self.set_state("error", message)
        self.exit_code = 1
        self.request_stop()

    def warn_limited(self, key: str, message: str, *args: Any, every_s: float = 5.0, count: bool = True) -> None:
        """Log the first 3 occurrences of ``key``, then at most one line per ``every_s`` (with the
        number of occurrences unless ``count`` is False because the message carries its own)."""
        rec = self._warned.setdefault(key, [0, -math.inf])
        rec[0] += 1
        now = time.monotonic()
        if rec[0] <= 3 or now - rec[1] >= every_s:
            suffix = f" ({int(rec[0])} so far)" if rec[0] > 3 and count else ""
            self.log.warning(message + suffix, *args)
            rec[1] = now

    # ----- diagnostics ------------------------------------------------------------------------
    def device_edges(self) -> list[dict[str, Any]]:
        """Incoming device streams as edges: dicts with topic, sender, rate_hz, received, gaps, rejected."""
        return []

    def edge_records(self) -> list[EdgeRecord]:
        return super().edge_records() + [EdgeRecord(**e) for e in self.device_edges()]


class Playback:
    """Which frames of a recording are due when (see module doc). Pure timing, no I/O.

    times_ns: int64[T] file time of every frame (any origin); frames ``first..last`` are played.
    """

    def __init__(self, times_ns: np.ndarray, first: int, last: int, rate_hz: float,
                 rate_scale: float = 1.0, loop: bool = False, batch: int = 256) -> None:
        times = np.asarray(times_ns, dtype=np.int64)
        self.first = int(first)
        self.rel = times[first:last + 1] - times[first]
        self.n = int(self.rel.shape[0])
        if self.n == 0:
            raise SourceError("no frames to play")
        step = 1e9 / rate_hz
        steps = np.diff(self.rel)
        self.uniform = bool(steps.size == 0 or np.all(np.abs(steps - step) <= 1e-3 * step + 1000))
        self.span = int(self.rel[-1] + round(step))  # one pass, including the last frame's period
        self.rate_scale = float(rate_scale)
        self.loop = bool(loop)
        self.batch = int(batch)
        # timer period: one frame for evenly spaced files; finer for irregular ones (Kinect drops)
        if self.rate_scale == 0:
            self.period_s = 0.0
        else:
            self.period_s = step / 1e9 / self.rate_scale / (1 if self.uniform else 4)
        # Timer ticks land on the frame grid (a tick fires at or after its due time), so only
        # rounding needs absorbing: a frame is never sent early by more than 0.1 ms of wall time.
        self._tol_ns = 1e5 * self.rate_scale
        self.k = 0  # frames played so far (over all passes)
        self.mono0 = 0.0
        self.wall0 = 0

    def start(self, mono_s: float, wall_ns: int) -> None:
        self.mono0, self.wall0, self.k = mono_s, int(wall_ns), 0

    @property
    def finished(self) -> bool:
        return not self.loop and self.k >= self.n

    @property
    def passes(self) -> int:
        return self.k // self.n

    @property
    def progress(self) -> float:
        return (self.k % self.n) / self.n if not self.finished else 1.0

    def due(self, mono_s: float) -> list[tuple[int, int]]:
        """(file frame index, capture stamp ns) of every frame due by ``mono_s`` (at most ``batch``)."""
        out: list[tuple[int, int]] = []
        if self.rate_scale == 0:
            limit = math.inf
        else:
            limit = (mono_s - self.mono0) * self.rate_scale * 1e9 + self._tol_ns
        rel, n = self.rel, self.n
        while len(out) < self.batch:
            p, j = divmod(self.k, n)
            if p and not self.loop:
                break
            file_ns = p * self.span + int(rel[j])
            if file_ns > limit:
                break
            out.append((self.first + j, self.wall0 + file_ns))
            self.k += 1
        return out


class FilePlayback(SourceNode):
    """A source replaying a recording: ``file``, ``loop``, ``rate_scale``, ``start_frame``, ``end_frame``.

    Subclasses implement ``load(path)`` (read the file; set ``self.times_ns``, ``self.frame_numbers``,
    ``self.rate_hz``), ``announce()`` (publish latched definitions) and ``emit(index, capture_ns)``.
    """

    file = Param("", "file to play; relative paths are tried from the working directory, then the project root "
                     "(the graph check refuses a missing or unreadable one)", kind="file", required=True)
    loop = Param(False, "start again at start_frame after end_frame (capture stamps keep increasing)")
    rate_scale = Param(1.0, "playback speed: 1 = the file's own rate, 2 = twice as fast, 0 = as fast as possible",
                       minimum=0.0)
    start_frame = Param(-1, "first frame to play, as the file numbers it (C3D header frame, TRC Frame#, "
                            "BVH/Kinect 0-based index); -1 = the first frame")
    end_frame = Param(-1, "last frame to play (inclusive, numbered like start_frame); -1 = the last frame")

    times_ns: np.ndarray
    frame_numbers: np.ndarray
    rate_hz: float

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.load_error = ""
        self.playback: Playback | None = None
        self.path: Path | None = None  # the file read, resolved (shown in the status)
        try:  # before the graph starts, so playback begins the moment it does
            self.path = resolve_data_path(self.file)
            self.load(self.path)
        except INPUT_ERRORS as exc:
            self.load_error = str(exc)
        except OSError as exc:
            self.load_error = f"{Path(self.file).name}: cannot read ({exc.strerror or exc})"

    def load(self, path: Path) -> None:
        raise NotImplementedError

    def announce(self) -> None:
        raise NotImplementedError

    def emit(self, index: int, capture_ns: int) -> None:
        raise NotImplementedError

    def frame_range(self) -> tuple[int, int]:
        """Indices of start_frame and end_frame; SourceError when outside the file."""
        nums = self.frame_numbers
        lo, hi = int(nums[0]), int(nums[-1])
        a = lo if self.start_frame < 0 else self.start_frame
        b = hi if self.end_frame < 0 else self.end_frame
        for key, v in (("start_frame", a), ("end_frame", b)):
            if not lo <= v <= hi:
                raise SourceError(f"{Path(self.file).name}: {key} {v} is outside the file's frames {lo}..{hi}")
        if b < a:
            raise SourceError(f"{Path(self.file).name}: end_frame {b} is before start_frame {a}")
        return a - lo, b - lo

    def on_start(self) -> None:
        if self.load_error:
            self.fail(self.load_error)
            return
        try:
            first, last = self.frame_range()
            self.playback = Playback(self.times_ns, first, last, self.rate_hz, self.rate_scale, self.loop)
            self.announce()
        except INPUT_ERRORS as exc:
            self.fail(str(exc))
            return
        self.set_state("playing", f"{Path(self.file).name} frames {self.frame_numbers[first]}.."
                                  f"{self.frame_numbers[last]} at {self.rate_hz:g} Hz x {self.rate_scale:g}", 0.0)
        self.playback.start(time.monotonic(), time.time_ns())
        self.add_timer(self.playback.period_s, self._tick, first_delay_s=0.0)

    def _tick(self) -> None:
        pb = self.playback
        for index, capture_ns in pb.due(time.monotonic()):
            self.emit(index, capture_ns)
        self.progress = pb.progress
        if pb.finished:
            self.set_state("finished", f"{pb.n} frames played", 1.0)
            self.log.info("finished: %d frames played", pb.n)
            self.request_stop()

    def status_data(self) -> dict[str, Any]:
        pb = self.playback
        d: dict[str, Any] = {"file": str(self.path.resolve()) if self.path is not None else self.file}
        if pb:
            d.update(frames_sent=pb.k, passes=pb.passes)
        return d
