"""What the serial and UDP readers share: the wire decoder, channel labels, the device-to-world
transform, the device clock, counters, and waking the node's loop when the device has bytes.

- Bytes go through :mod:`mocapgraph.formats.wire_protocol`'s streaming decoders, which never
  raise: garbage is skipped and counted (``rejected_bytes``, ``rejected_frames``, ``crc_errors``).
  The counts appear in the node's Diagnostics as an incoming device edge, in ``reader_status``
  and in the log (rate-limited).
- Axes: the device file's ``to_world``, or the ``up_axis`` param where the file sets no up axis
  (:meth:`~mocapgraph.formats.device_file.DeviceConfig.with_up_axis`).
- Frame numbers: a jump forward counts the frames skipped as ``device_gaps``; one of the last
  ``REORDER_FRAMES`` skipped numbers arriving later was overtaken on the way (UDP): it is
  published, counted as ``reordered`` and takes its gap back. Any other step back is a device
  that renumbered (restarted).
- Channel labels come from the device file's ``channels``; without them the channels are the
  layout's markers in layout order (the counts must agree), or ``M0..`` with ``layout: ""``.
  A frame with another marker count is rejected and counted.
- Capture stamps: the device's own time stamps, mapped to our clock by a
  :class:`~mocapgraph.messages.clock_sync.ClockSync` that follows the device clock's offset and
  drift continuously from the frames that arrive fastest (so no one frame's delay is baked into
  every stamp). A device clock that restarts or jumps is re-seeded and counted (``clock_resyncs``);
  a reopened stream starts the estimate again (not counted). Offset, drift and jitter are in the
  node's Diagnostics (``clock_*``) and in ``reader_status`` (``clock``).
- The device's file descriptor is registered with the node's poller, so its bytes wake the
  event loop at once (no polling timer); they are read right after each loop turn.
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np
import zmq

from ..bus import Param
from ..bus.diagnostics import ClockRecord, device_clock
from ..messages.clock_sync import ClockSync
from ..formats.wire_protocol import WireFrame, make_decoder
from ..formats.device_file import DeviceConfig, device_or_default
from .marker_source import LayoutMap, MarkerSourceNode, check_device_param, device_up_axis
from .source_base import INPUT_ERRORS

RESYNC_S = 0.5   # a device clock that jumps further than this (either way) is re-seeded
REORDER_FRAMES = 64   # the last this many skipped frame numbers may still come (overtaken on a UDP link)


class WireDeviceSource(MarkerSourceNode):
    """Base of the serial and UDP readers (see module doc). Subclasses open the device in
    ``on_start`` (then call ``watch_fd``) and implement ``read_device`` (drain without blocking)."""

    device = Param("", "device configuration (graph_configs/devices name or path): channel labels, "
                       "device-to-world transform, nominal rate; '' = device frame is the world frame")
    rate_hz = Param(0.0, "nominal frame rate written into MarkerFrames, Hz; 0 = the device file's, "
                         "else measured from the device time stamps", minimum=0.0)
    up_axis = device_up_axis()

    endpoint = ""

    def wire_protocol(self) -> str:
        """'text' or 'binary' (see mocapgraph.formats.wire_protocol)."""
        return "binary"

    @classmethod
    def graph_check(cls, params: dict[str, Any]) -> None:
        """The graph check refuses a device file this reader would refuse (the node itself reports it)."""
        check_device_param(params)

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.decoder = make_decoder(self.wire_protocol())
        self.config_error = ""
        try:
            self.dev: DeviceConfig = device_or_default(self.device, self.up_axis)
        except INPUT_ERRORS as exc:
            self.config_error = str(exc)
            self.dev = DeviceConfig()
        self._fd: int | None = None
        self.frames = 0
        self.device_gaps = 0
        self.reordered = 0
        self._missing: dict[int, None] = {}   # skipped frame numbers that may still come, oldest first
        self.count_mismatches = 0
        self.disconnects = 0
        self.clock = ClockSync(reset_s=RESYNC_S)
        self._resets_seen = 0
        self._last_frame: int | None = None
        self._last_dev_ns = 0
        self._rate_est = 0.0
        self._seen_rejects = (0, 0)
        self.last_arrival = 0.0

    # ----- event loop integration -----------------------------------------------------------
    def watch_fd(self, fd: int) -> None:
        self.add_reader(fd, self.read_device)
        self._fd = fd

    def unwatch_fd(self) -> None:
        if self._fd is not None:
            self.remove_reader(self._fd)
            self._fd = None

    def read_device(self) -> None:
        raise NotImplementedError

    # ----- layout --------------------------------------------------------------------------
    def start_layout(self) -> bool:
        """Publish the layout now when the channel labels are known; False after a failure."""
        if self.config_error:
            self.fail(self.config_error)
            return False
        if self.dev.channels:
            try:
                self.bind_layout(self.dev.channels, self.units_note(), self.source_text())
            except INPUT_ERRORS as exc:
                self.fail(str(exc))
                return False
        return True

    def units_note(self) -> str:
        return f"wire protocol millimetres -> m; {self.dev.describe()}"

    def source_text(self) -> str:
        return f"{self.wire_protocol()} {type(self).__name__.replace('Reader', '').lower()} {self.endpoint}"

    def _bind_from_count(self, n: int) -> bool:
        """First frame of a device without channel labels: its count defines the channels."""
        try:
            if self.layout:
                lmap = LayoutMap.in_order(self.layout, n)
            else:
                lmap = LayoutMap.build("", [f"M{i}" for i in range(n)])
        except INPUT_ERRORS as exc:
            self.warn_limited("bind", "frame with %d markers rejected: %s", n, exc)
            return False
        self.publish_layout(lmap, self.units_note(), self.source_text())
        return True

    # ----- frames ---------------------------------------------------------------------------
    def handle_bytes(self, data: bytes, arrival_ns: int, end_of_message: bool = False) -> None:
        """Decode ``data`` (a chunk of a stream, or a whole datagram) and publish its frames."""
        frames = self.decoder.feed(data)
        if end_of_message:
            frames += self.decoder.flush()
        for wf in frames:
            self.handle_frame(wf, arrival_ns)
        st = self.decoder.stats
        seen = (st.rejected_bytes, st.rejected_frames)
        if seen != self._seen_rejects:
            self._seen_rejects = seen
            self.warn_limited("rejects", "%s: skipped %d bad byte(s), %d bad frame(s), %d CRC error(s) so far "
                              "(last: %s)", self.endpoint, st.rejected_bytes, st.rejected_frames,
                              st.crc_errors, st.last_error or "bytes outside any frame", every_s=5.0,
                              count=False)

    def handle_frame(self, wf: WireFrame, arrival_ns: int) -> None:
        n = wf.positions.shape[0]
        if self.lmap is None and not self._bind_from_count(n):
            self.count_mismatches += 1
            return
        if n != self.lmap.n_source:
            self.count_mismatches += 1
            self.warn_limited("count", "frame %d has %d markers, the device is configured for %d: rejected",
                              wf.frame, n, self.lmap.n_source)
            return
        self._count_frame(wf)
        capture = self.map_clock(wf.device_time_ns, arrival_ns)
        pos = self.lmap.positions(self.dev.points_to_world(wf.positions))
        self.publish_frame(wf.frame, self.nominal_rate(), pos, capture)
        self.frames += 1
        self.last_arrival = time.monotonic()

    def _count_frame(self, wf: WireFrame) -> None:
        """Gaps and the measured rate from frame numbers; a frame overtaken on the way (one of the
        last gaps' numbers) fills its gap; any other step back is a renumbered (restarted) device."""
        if self._last_frame is not None:
            step = wf.frame - self._last_frame
            if step < 0 and wf.frame in self._missing:
                del self._missing[wf.frame]
                self.reordered += 1
                self.device_gaps -= 1
                return
            if step > 1:
                self.device_gaps += step - 1
                if step - 1 <= REORDER_FRAMES:
                    self._missing.update(dict.fromkeys(range(self._last_frame + 1, wf.frame)))
                    while len(self._missing) > REORDER_FRAMES:
                        del self._missing[next(iter(self._missing))]
            if step > 0 and wf.device_time_ns > self._last_dev_ns:
                inst = step * 1e9 / (wf.device_time_ns - self._last_dev_ns)
                self._rate_est = inst if not self._rate_est else 0.9 * self._rate_est + 0.1 * inst
        self._last_frame, self._last_dev_ns = wf.frame, wf.device_time_ns

    def map_clock(self, device_ns: int, arrival_ns: int, latency_ns: int = 0) -> int:
        """Device time -> capture time on our clock (the ClockSync estimate; restarts logged)."""
        capture = self.clock.update(device_ns, arrival_ns, latency_ns)
        if self.clock.resets != self._resets_seen:
            self._resets_seen = self.clock.resets
            self.warn_limited("clock", "%s: device clock restarted or jumped (%d so far): re-seeded",
                              self.endpoint, self.clock.resets, count=False)
        return capture

    @property
    def clock_resyncs(self) -> int:
        return self.clock.resets

    def nominal_rate(self) -> float:
        return self.rate_hz or self.dev.rate_hz or round(self._rate_est, 3)

    def reset_stream(self) -> None:
        """The byte stream broke (device lost): drop a half frame, forget frame numbering and the
        clock estimate (a reconnected device may have restarted: its next frames seed it again)."""
        self.decoder.flush()
        self._last_frame = None
        self._missing.clear()
        self.clock.forget()

    # ----- reporting -------------------------------------------------------------------------
    def status_data(self) -> dict[str, Any]:
        st = self.decoder.stats
        return {"frames": self.frames, "device_gaps": self.device_gaps, "bytes_in": st.bytes_in,
                "rejected_bytes": st.rejected_bytes, "rejected_frames": st.rejected_frames,
                "crc_errors": st.crc_errors, "count_mismatches": self.count_mismatches,
                "reject_reasons": dict(st.errors), "clock_resyncs": self.clock_resyncs,
                "reordered": self.reordered,
                "disconnects": self.disconnects, "rate_hz": self.nominal_rate(),
                "clock": self.clock.stats().as_dict(),
                "last_frame_age_s": (time.monotonic() - self.last_arrival) if self.last_arrival else None}

    def device_topic(self) -> str:
        return f"{type(self).__name__.replace('Reader', '').lower()}:{self.endpoint}"

    def clock_records(self) -> list[ClockRecord]:
        return super().clock_records() + device_clock(self.device_topic(), self.clock)

    def device_edges(self) -> list[dict[str, Any]]:
        st = self.decoder.stats
        return [{"topic": self.device_topic(),
                 "sender": self.dev.name, "rate_hz": self._rate_est, "received": self.frames,
                 "gaps": self.device_gaps, "rejected": st.rejected_frames + self.count_mismatches}]

    def on_stop(self) -> None:
        self.unwatch_fd()
