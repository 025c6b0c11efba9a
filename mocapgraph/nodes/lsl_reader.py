"""LabStreamingLayer inlet node (pylsl): a marker stream resolved by name/type, channels mapped
to markers, LSL time stamps mapped to our clock."""
from __future__ import annotations

import socket
import time
from typing import Any

import numpy as np
import pylsl
from pylsl.util import InternalError, LostError, TimeoutError as LSLTimeoutError

from ..bus import Param
from ..bus.diagnostics import ClockRecord
from ..formats.device_file import DeviceConfig, device_or_default
from .marker_source import LayoutMap, MarkerSourceNode, check_device_param, device_up_axis
from .source_base import INPUT_ERRORS, SourceError

AXIS_SUFFIXES = ("_x", "_y", "_z", ".x", ".y", ".z", " x", " y", " z", "x", "y", "z")


def channel_labels(info: pylsl.StreamInfo) -> list[str]:
    """Channel labels from the stream's description (desc/channels/channel/label), '' where absent."""
    out: list[str] = []
    ch = info.desc().child("channels").child("channel")
    while not ch.empty() and len(out) < info.channel_count():
        out.append(ch.child_value("label"))
        ch = ch.next_sibling()
    return out + [""] * (info.channel_count() - len(out))


def marker_names_from_channels(labels: list[str]) -> list[str] | None:
    """``LASI_X, LASI_Y, LASI_Z, ...`` -> ``LASI, ...``; None unless every triple names one marker."""
    if not labels or len(labels) % 3 or not all(labels):
        return None
    names = []
    for k in range(0, len(labels), 3):
        stems = set()
        for lab, axis in zip(labels[k:k + 3], "xyz"):
            low = lab.lower()
            suf = next((s for s in AXIS_SUFFIXES if low.endswith(s) and s.strip("_. ") == axis), None)
            if suf is None:
                return None
            stems.add(lab[: len(lab) - len(suf)])
        if len(stems) != 1:
            return None
        names.append(stems.pop())
    return names


class LSLReader(MarkerSourceNode):
    """Reads a LabStreamingLayer marker stream and publishes ``markers`` + latched ``marker_layout``.

    The stream is found by ``stream_name`` and/or ``stream_type`` (resolution runs in the
    background and never blocks the node). Channels are x, y, z per marker, in ``units``; marker
    labels come from the device file's ``channels``, else the stream's channel labels
    (``LASI_X, LASI_Y, LASI_Z``...), else the layout's markers in order. A stream whose channel
    count does not fit (not 3 per marker) is refused with a one-line error, counted, and skipped
    while the node keeps looking for a stream that fits. Capture stamps are the LSL time stamps
    (clock-synchronised to this host) mapped to our clock. A lost stream is looked for again.
    Axes: the device file's ``to_world``, or ``up_axis`` where the file sets no up axis.
    """

    summary = "LabStreamingLayer marker stream (resolve by name/type, channels -> markers, LSL stamps)"
    stream_name = Param("", "LSL stream name to resolve ('' = any name)")
    stream_type = Param("Mocap", "LSL stream type to resolve ('' = any type)")
    device = Param("", "device configuration (graph_configs/devices name or path): channel labels, units, "
                       "device-to-world transform; '' = labels from the stream, metres, world frame")
    units = Param("", "units of the stream's coordinates: m, cm, mm, in; '' = the device file's (default m)",
                  choices=("", "m", "cm", "mm", "in"))
    up_axis = device_up_axis()
    poll_s = Param(0.002, "how often to pull samples from the inlet, s", minimum=0.0005)
    resolve_s = Param(0.25, "how often to look for the stream while none fits, s", minimum=0.05)

    @classmethod
    def graph_check(cls, params: dict[str, Any]) -> None:
        """The graph check refuses a device file this reader would refuse (the node itself reports it)."""
        check_device_param(params)

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.config_error = ""
        try:
            self.dev: DeviceConfig = device_or_default(self.device, self.up_axis)
        except INPUT_ERRORS as exc:
            self.config_error = str(exc)
            self.dev = DeviceConfig()
        if self.units:
            self.dev.units = self.units
        self.inlet: pylsl.StreamInlet | None = None
        self.stream_desc = ""
        self.refused: dict[str, str] = {}  # stream uid -> why
        self.frames = 0
        self.streams_lost = 0
        self._pull_timer: list | None = None
        self._resolve_timer: list | None = None
        self._rate = 0.0
        self._fresh_after: float | None = None
        self._opened_at = 0.0
        self._tc: float | None = None
        self._tc_at = 0.0
        self.stale_dropped = 0

    def _predicate(self) -> str:
        parts = [f"name='{self.stream_name}'"] if self.stream_name else []
        parts += [f"type='{self.stream_type}'"] if self.stream_type else []
        return " and ".join(parts) or "count(channel_count)>0"

    def on_start(self) -> None:
        if self.config_error:
            self.fail(self.config_error)
            return
        # wall clock = LSL clock + offset, taken once (both clocks tick at the same rate)
        self._lsl_to_wall_ns = time.time_ns() - int(pylsl.local_clock() * 1e9)
        self.resolver = pylsl.ContinuousResolver(pred=self._predicate(), forget_after=2.0)
        self.set_state("waiting", f"looking for an LSL stream with {self._predicate()}")
        self._resolve_timer = self.add_timer(self.resolve_s, self._resolve, first_delay_s=0.0)

    # ----- finding the stream ----------------------------------------------------------------
    def _resolve(self) -> None:
        for info in self.resolver.results():
            uid = info.uid()
            if uid in self.refused:
                continue
            try:
                self._check_count(info)
                # Clock correction is applied here, from a non-blocking estimate: with LSL's
                # proc_clocksync flag the first pull blocks (~0.7 s) until its estimate exists.
                inlet = pylsl.StreamInlet(info, max_buflen=10, recover=False, as_numpy=True)
                full = inlet.info(timeout=1.0)  # resolution gives the header only, no channel labels
                lmap = self._map_channels(full)
            except INPUT_ERRORS as exc:
                self.refused[uid] = str(exc)
                self.log.error("%s", exc)
                self.set_state("waiting", str(exc))
                continue
            except (LSLTimeoutError, LostError, InternalError) as exc:
                self.warn_limited("open", "LSL stream '%s' could not be opened (%s); retrying", info.name(), exc)
                continue
            self._open(inlet, full, lmap)
            return

    def _what(self, info: pylsl.StreamInfo) -> str:
        return f"LSL stream '{info.name()}' ({info.type()}, {info.hostname()})"

    def _check_count(self, info: pylsl.StreamInfo) -> None:
        n_ch, what = info.channel_count(), self._what(info)
        if info.channel_format() == pylsl.cf_string:
            raise SourceError(f"{what}: carries strings, not numbers")
        if self.dev.channels and n_ch != 3 * len(self.dev.channels):
            raise SourceError(f"{what}: has {n_ch} channels, expected {3 * len(self.dev.channels)} "
                              f"(x, y, z for the {len(self.dev.channels)} markers of device '{self.dev.name}')")
        if n_ch % 3 or n_ch == 0:
            raise SourceError(f"{what}: has {n_ch} channels, not x, y, z per marker (a multiple of 3)")

    def _map_channels(self, info: pylsl.StreamInfo) -> LayoutMap:
        n_ch, what = info.channel_count(), self._what(info)
        labels = self.dev.channels or marker_names_from_channels(channel_labels(info))
        if labels is None:
            if self.layout:
                return LayoutMap.in_order(self.layout, n_ch // 3)
            labels = [f"M{i}" for i in range(n_ch // 3)]
        return LayoutMap.build(self.layout, labels, what)

    def _open(self, inlet: pylsl.StreamInlet, info: pylsl.StreamInfo, lmap: LayoutMap) -> None:
        self.inlet = inlet
        inlet.open_stream(timeout=1.0)
        # A live source: the outlet's backlog from before we connected is stale.
        self._fresh_after = pylsl.local_clock() - 0.05
        self._opened_at = time.monotonic()
        # Same host, same clock: no correction needed while LSL's own estimate is pending.
        self._tc = 0.0 if info.hostname() == socket.gethostname() else None
        self._tc_at = self._opened_at
        self._rate = info.nominal_srate() or self.dev.rate_hz
        self.stream_desc = f"LSL stream '{info.name()}' ({info.type()}) from {info.hostname()}, uid {info.uid()}"
        note = f"LSL {self.dev.units} -> m; LSL time stamps -> host clock; {self.dev.describe()}"
        self.publish_layout(lmap, note, self.stream_desc)
        self._resolve_timer.cancel()
        self._pull_timer = self.add_timer(self.poll_s, self._pull, first_delay_s=0.0)
        self.log.info("connected to %s: %d markers at %g Hz", self.stream_desc, lmap.n_source, self._rate)
        self.set_state("streaming", self.stream_desc)

    def _lost(self, why: str) -> None:
        self.streams_lost += 1
        self.log.warning("lost %s (%s); looking for it again", self.stream_desc, why)
        self._pull_timer.cancel()
        self.inlet = None
        self.set_state("waiting", f"lost {self.stream_desc}: {why}")
        self._resolve_timer = self.add_timer(self.resolve_s, self._resolve, first_delay_s=self.resolve_s)

    # ----- samples ---------------------------------------------------------------------------
    def _clock_correction(self) -> float | None:
        """Seconds to add to the stream's stamps (LSL's estimate, refreshed once a second);
        None while the first estimate is pending (samples then wait in the inlet)."""
        now = time.monotonic()
        if self._tc is not None and now - self._tc_at < 1.0:
            return self._tc
        try:
            self._tc = self.inlet.time_correction(timeout=0.0)
        except LSLTimeoutError:
            if self._tc is not None:
                self._tc_at = now
                return self._tc
            if now - self._opened_at < 3.0:
                return None
            self.log.warning("%s: no clock correction after 3 s; using its time stamps as they are",
                             self.stream_desc)
            self._tc = 0.0
        self._tc_at = now
        return self._tc

    def _pull(self) -> None:
        try:
            tc = self._clock_correction()
            if tc is None:
                return
            samples, stamps = self.inlet.pull_chunk(timeout=0.0, max_samples=4096)
        except (LostError, InternalError) as exc:
            self._lost(str(exc) or "the outlet is gone")
            return
        stamps = np.asarray(stamps) + tc
        if self._fresh_after is not None and len(stamps):
            keep = stamps >= self._fresh_after
            self.stale_dropped += int((~keep).sum())
            if keep.any():
                self._fresh_after = None
            samples, stamps = np.asarray(samples)[keep], stamps[keep]
        if len(stamps) == 0:
            return
        lmap = self.lmap
        data = np.asarray(samples, dtype=np.float64).reshape(len(stamps), lmap.n_source, 3) * self.dev.scale
        data[~np.isfinite(data)] = np.nan
        pos = lmap.positions(self.dev.points_to_world(data))            # [K, M, 3], one call per chunk
        valid = ~np.isnan(pos).any(axis=2)
        capture = (stamps * 1e9).astype(np.int64) + self._lsl_to_wall_ns
        for k in range(len(stamps)):
            self.publish_frame(self.frames, self._rate, pos[k], int(capture[k]), valid=valid[k])
            self.frames += 1

    def status_data(self) -> dict[str, Any]:
        return {"frames": self.frames, "stream": self.stream_desc, "refused_streams": list(self.refused.values()),
                "streams_lost": self.streams_lost, "stale_dropped": self.stale_dropped}

    def clock_records(self) -> list[ClockRecord]:
        """LSL's own clock correction of the outlet's host (local minus remote), as a followed clock."""
        if self._tc is None or self.inlet is None:
            return super().clock_records()
        return super().clock_records() + [ClockRecord(f"lsl:{self._predicate()}", self._tc * 1e3)]

    def device_edges(self) -> list[dict[str, Any]]:
        return [{"topic": f"lsl:{self._predicate()}", "sender": self.stream_desc or "?", "rate_hz": self._rate,
                 "received": self.frames, "gaps": 0, "rejected": len(self.refused)}]

    def on_stop(self) -> None:
        if self.inlet is not None:
            self.inlet.close_stream()
            # liblsl's own threads go with the inlet: none left retrying a vanished outlet in a
            # process that goes on (a node run in a thread, a composed process)
            self.inlet = None
