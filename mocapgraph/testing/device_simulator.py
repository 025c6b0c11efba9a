"""A simulated marker device: the synthetic actor sent over a serial line (or a pseudo-terminal),
UDP datagrams or a LabStreamingLayer outlet, in a device's own frame, units and channel order.

It is the other end of the serial, UDP and LSL readers, for trying a lab graph without hardware
(``mocapgraph device simulate ...``) and for tests and benchmarks. What it sends is exactly what
the reader should reconstruct: world positions of :class:`SyntheticActor` mapped into the device
frame with the inverse of the device file's ``to_world``, in the device's channel order.
"""
from __future__ import annotations

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
                 seed: int = 0, noise_mm: float = 0.0, dropout_rate_hz: float = 0.0, start_frame: int = 0) -> None:
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

    def world_positions(self, frame: int) -> np.ndarray:
        """What a reader should publish for ``frame``: world metres in LAYOUT order."""
        f = frame % self.actor.n_frames
        return self.actor.capture(f, f + 1).markers[0]


def paced(frames: Iterator[DeviceFrame], rate_hz: float) -> Iterator[DeviceFrame]:
    """Yield frames at their device time in real time (monotonic clock, no drift)."""
    t0 = time.monotonic()
    for k, f in enumerate(frames):
        delay = t0 + k / rate_hz - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        yield f


def run_serial(sim: SimulatedDevice, write: Callable[[bytes], object], protocol: str = "text",
               count: int = 0, garbage_every: int = 0, seed: int = 0) -> int:
    """Write frames with ``write`` (a port's or a pty master's), paced; returns frames sent.

    ``garbage_every`` N > 0 puts 1-64 random bytes before every Nth frame (line noise)."""
    rng = np.random.default_rng(seed)
    enc = encode_text if protocol == "text" else encode_binary
    n = 0
    for f in paced(sim.frames(count), sim.rate_hz):
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
        for f in paced(sim.frames(count), sim.rate_hz):
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
    for f in paced(sim.frames(count), sim.rate_hz):
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
