"""Parses OptiTrack's SampleClient printout (../shared/data/natnet/SampleClient_output.txt) into
per-frame reference values, and pulls the NatNet datagrams out of the session's capture."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapgraph.formats import natnet as nn
from mocapgraph.testing.pcapng import Datagram, read_udp

#: the SampleClient prints 2 decimals: a value agrees when within half a unit of the last digit
PRINT_TOL = 0.005 + 1e-6

_NUM = r"(-?\d+(?:\.\d+)?)"


@dataclass
class RefFrame:
    """One frame as the SampleClient printed it (m, Motive axes, quaternion x y z w, ms)."""

    frame_id: int
    timestamp: float = 0.0
    software_ms: float = 0.0
    system_ms: float = 0.0
    timecode: str = ""
    other: list[list[float]] = field(default_factory=list)
    bodies: list[tuple[int, float, bool, list[float]]] = field(default_factory=list)  # id, error, valid, xyz+q
    labelled: list[tuple[int, int, int, list[float]]] = field(default_factory=list)  # model, marker, occluded, xyz


def parse_sample_client(path: Path) -> dict[int, RefFrame]:
    """FrameID -> RefFrame."""
    frames: dict[int, RefFrame] = {}
    cur: RefFrame | None = None
    lines = path.read_text(errors="replace").splitlines()
    for i, line in enumerate(lines):
        if m := re.match(r"FrameID : (\d+)", line):
            cur = frames.setdefault(int(m[1]), RefFrame(int(m[1])))
        elif cur is None:
            continue
        elif m := re.match(rf"Timestamp : {_NUM}", line):
            cur.timestamp = float(m[1])
        elif m := re.match(rf"Software latency : {_NUM}", line):
            cur.software_ms = float(m[1])
        elif m := re.match(rf"System latency : {_NUM}", line):
            cur.system_ms = float(m[1])
        elif m := re.match(r"Timecode : (\S+)", line):
            cur.timecode = m[1]
        elif m := re.match(rf"Other Marker \d+ : {_NUM}\s+{_NUM}\s+{_NUM}", line):
            cur.other.append([float(v) for v in m.groups()])
        elif m := re.match(rf"Rigid Body \[ID=(\d+)\s+Error={_NUM}\s+Valid=(\d)\]", line):
            values = [float(v) for v in lines[i + 2].split()]
            cur.bodies.append((int(m[1]), float(m[2]), m[3] == "1", values))
        elif m := re.match(rf"Labeled Marker \[ModelID=(\d+), MarkerID=(\d+), Occluded=(\d).*"
                           rf"\[pos={_NUM},{_NUM},{_NUM}\]", line):
            cur.labelled.append((int(m[1]), int(m[2]), int(m[3]), [float(v) for v in m.groups()[3:]]))
    return frames


def natnet_datagrams(pcap: Path) -> list[Datagram]:
    """The capture's NatNet datagrams (command port 1510 and data port 1511 traffic)."""
    return [d for d in read_udp(pcap) if {d.src[1], d.dst[1]} & {1510, 1511}]


def frames_of(datagrams: list[Datagram], version: nn.Version = (3, 0)) -> list[tuple[int, nn.Frame]]:
    """(capture ns, decoded Frame) of every frame-of-data datagram."""
    return [(d.time_ns, nn.decode_frame(d.payload, version)) for d in datagrams
            if nn.message_id(d.payload) == nn.NAT_FRAMEOFDATA]


def max_abs(a: list[list[float]] | np.ndarray, b: np.ndarray) -> float:
    a = np.asarray(a, float)
    return float(np.abs(a - b).max()) if a.size else 0.0
