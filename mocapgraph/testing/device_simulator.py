"""A simulated marker device: the synthetic actor sent over a serial line (or a pseudo-terminal),
UDP datagrams or a LabStreamingLayer outlet, in a device's own frame, units and channel order.

It is the other end of the serial, UDP and LSL readers, for trying a lab graph without hardware
(``mocapgraph device simulate ...``) and for tests and benchmarks. What it sends is exactly what
the reader should reconstruct: world positions of :class:`SyntheticActor` mapped into the device
frame with the inverse of the device file's ``to_world``, in the device's channel order.

Clock faults, for the readers' clock estimate (:mod:`mocapgraph.messages.clock_sync`): with
``drift_ppm`` the device's clock runs that much fast, so its frames (stamped ``k / rate`` on its
own clock) are captured every ``1 / (rate * (1 + drift))`` s of ours; with ``delay_ms`` each frame
leaves 0..delay_ms (uniform, independently) after its capture, so a frame may overtake the one
before it when the delay exceeds the frame period (as ``netem delay`` with jitter does).
:meth:`SimulatedDevice.capture_ns` gives the true capture time of the k-th frame sent, on our
clock, once :meth:`SimulatedDevice.paced` has started.
"""
from __future__ import annotations

import heapq
import os
import socket
import time
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from ..formats.wire_protocol import encode_binary, encode_text
from ..kinematics.labels import missing_labels, place_labels
from ..kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from ..formats.device_file import DeviceConfig, device_or_default


@dataclass
class DeviceFrame:
    frame: int
    t_us: int
    positions: np.ndarray  # [n, 3] device frame, metres (wire encoders take metres)


class SimulatedDevice:
    """Frames of a synthetic performer as a device would send them (see module doc)."""

    def __init__(self, layout: str = "plug_in_gait", device: str | DeviceConfig = "", rate_hz: float = 120.0,
                 seed: int = 0, noise_mm: float = 0.0, dropout_rate_hz: float = 0.0, start_frame: int = 0,
                 drift_ppm: float = 0.0, delay_ms: float = 0.0) -> None:
        self.dev = device if isinstance(device, DeviceConfig) else device_or_default(device)
        self.actor = SyntheticActor(layout, rate=rate_hz, seed=seed,
                                    options=CaptureOptions(noise_mm=noise_mm, dropout_rate_hz=dropout_rate_hz))
        labels = list(self.actor.skeleton.marker_labels)
        self.channels = self.dev.channels or labels
        # device channel -> layout marker, by the same label rule as every reader
        where, _ = place_labels(self.channels, labels)
        missing = missing_labels(self.channels, where)
        if missing:
            raise ValueError(f"device channels not in layout {layout!r}: {', '.join(missing[:5])}")
        self.order = where
        self.rate_hz = float(rate_hz)
        self.start_frame = int(start_frame)
        self.drift_ppm = float(drift_ppm)
        self.delay_ms = float(delay_ms)
        self.delay_seed = seed
        self.t0_ns: int | None = None   # our wall clock at the first frame's capture (set by paced)

    def frames(self, count: int = 0, chunk: int = 120) -> Iterator[DeviceFrame]:
        """``count`` frames (0 = endless, the session looping), device time from 0 µs."""
        n_session = self.actor.n_frames
        k = 0
        while not count or k < count:
            a = (self.start_frame + k) % n_session
            b = min(a + chunk, n_session)
            if count:
                b = min(b, a + count - k)
            cap = self.actor.capture(a, b)
            dev = self.dev.points_from_world(cap.markers[:, self.order]) / self.dev.scale
            for i in range(dev.shape[0]):
                yield DeviceFrame(self.start_frame + k, round((self.start_frame + k) * 1e6 / self.rate_hz), dev[i])
                k += 1

    def capture_ns(self, k: int | np.ndarray) -> int | np.ndarray:
        """True capture time on our wall clock (ns) of the k-th frame :meth:`paced` sent (from 0)."""
        if self.t0_ns is None:
            raise RuntimeError("capture_ns: the frames have not been sent yet")
        period_ns = 1e9 / (self.rate_hz * (1 + self.drift_ppm * 1e-6))
        return self.t0_ns + np.round(np.asarray(k) * period_ns).astype(np.int64)

    def paced(self, frames: Iterator[DeviceFrame]) -> Iterator[DeviceFrame]:
        """Yield ``frames`` when they leave the device, in real time (see module doc: the device's
        clock drift, the link's delay); sets ``t0_ns`` for :meth:`capture_ns`."""
        rng = np.random.default_rng(self.delay_seed)
        period = 1.0 / (self.rate_hz * (1 + self.drift_ppm * 1e-6))
        t0 = time.monotonic()
        self.t0_ns = time.time_ns()
        due: list[tuple[float, int, DeviceFrame]] = []      # (leaves at, k, frame): a heap
        source = enumerate(frames)
        k_next, ahead = -1, None
        while True:
            # take frames while the next one could leave before the earliest waiting one
            while ahead is None or not due or k_next * period <= due[0][0]:
                if ahead is not None:
                    delay = rng.uniform(0.0, self.delay_ms * 1e-3) if self.delay_ms else 0.0
                    heapq.heappush(due, (k_next * period + delay, k_next, ahead))
                k_next, ahead = next(source, (-1, None))
                if ahead is None:
                    break
            if not due:
                return
            leave, _, f = heapq.heappop(due)
            wait = t0 + leave - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            yield f

    def world_positions(self, frame: int) -> np.ndarray:
        """What a reader should publish for ``frame``: world metres in LAYOUT order."""
        f = frame % self.actor.n_frames
        return self.actor.capture(f, f + 1).markers[0]


def run_serial(sim: SimulatedDevice, write: Callable[[bytes], object], protocol: str = "text",
               count: int = 0, garbage_every: int = 0, seed: int = 0) -> int:
    """Write frames with ``write`` (a port's or a pty master's), paced; returns frames sent.

    ``garbage_every`` N > 0 puts 1-64 random bytes before every Nth frame (line noise)."""
    rng = np.random.default_rng(seed)
    enc = encode_text if protocol == "text" else encode_binary
    n = 0
    for f in sim.paced(sim.frames(count)):
        data = enc(f.frame, f.t_us, f.positions)
        if garbage_every and f.frame % garbage_every == garbage_every - 1:
            data = rng.integers(0, 256, int(rng.integers(1, 65)), dtype=np.uint8).tobytes() + data
        write(data)
        n += 1
    return n


def run_udp(sim: SimulatedDevice, host: str, port: int, protocol: str = "binary", count: int = 0) -> int:
    """Send one datagram per frame to ``host:port``, paced; returns frames sent."""
    enc = encode_text if protocol == "text" else encode_binary
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        n = 0
        for f in sim.paced(sim.frames(count)):
            s.sendto(enc(f.frame, f.t_us, f.positions), (host, port))
            n += 1
    return n


def run_lsl(sim: SimulatedDevice, name: str, stream_type: str = "Mocap", count: int = 0,
            source_id: str = "") -> int:
    """Publish an LSL outlet of 3 float32 channels per marker (labels LASI_X...), paced."""
    import pylsl

    n_ch = 3 * len(sim.channels)
    info = pylsl.StreamInfo(name, stream_type, n_ch, sim.rate_hz, "float32", source_id or f"mocapgraph-{name}")
    chans = info.desc().append_child("channels")
    for lab in sim.channels:
        for axis in "XYZ":
            c = chans.append_child("channel")
            c.append_child_value("label", f"{lab}_{axis}")
            c.append_child_value("unit", {"m": "meters", "mm": "millimeters", "cm": "centimeters",
                                          "in": "inches"}[sim.dev.units])
    outlet = pylsl.StreamOutlet(info)
    n = 0
    t0 = pylsl.local_clock()
    for f in sim.paced(sim.frames(count)):
        # Stamped with the frame's capture time, as a device does, not with when this process got
        # round to pushing it (a late push on a busy machine would squeeze the stamps together).
        outlet.push_sample(f.positions.ravel().astype(np.float32), t0 + n / sim.rate_hz)
        n += 1
    return n


def open_pty() -> tuple[int, int, str]:
    """A pseudo-terminal pair in raw mode (no echo, no line editing): (master fd to write, slave
    fd to keep open so the path stays valid, slave path for the reader's ``port``)."""
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)
