"""C3D files written byte by byte (no C3D library), to reproduce parameter layouts that
ezc3d's writer never produces: parameters stored before their group's record, scalars as
one-element arrays, locked entries (negative name length). The C3D spec allows all of them
("groups and parameters may appear in any order")."""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

POINT_GROUP = 1


def _entry(name: str, gid: int, body: bytes, locked: bool = False) -> bytes:
    """One parameter-section record: name length, group id, name, offset to the next, body."""
    nb = name.encode("ascii")
    nlen = -len(nb) if locked else len(nb)
    return struct.pack("<bb", nlen, gid) + nb + struct.pack("<h", 2 + len(body)) + body


def _group(name: str, gid: int) -> bytes:
    return _entry(name, -gid, b"\x00")  # empty description


def _param(name: str, gid: int, ptype: int, dims: list[int], data: bytes, locked: bool = False) -> bytes:
    body = struct.pack("<bB", ptype, len(dims)) + bytes(dims) + data + b"\x00"
    return _entry(name, gid, body, locked)


def _int16(name: str, value: int, scalar_dims: list[int]) -> bytes:
    return _param(name, POINT_GROUP, 2, scalar_dims, struct.pack("<h", value))


def _float(name: str, value: float, scalar_dims: list[int]) -> bytes:
    return _param(name, POINT_GROUP, 4, scalar_dims, struct.pack("<f", value))


def _chars(name: str, words: list[str], width: int) -> bytes:
    data = b"".join(w.encode("ascii").ljust(width) for w in words)
    dims = [width, len(words)] if len(words) > 1 else [width]
    return _param(name, POINT_GROUP, -1, dims, data)


def write_float_c3d(path: Path, labels: list[str], points_mm: np.ndarray, *, header_last: int,
                    point_frames: int, rate: float = 100.0, layout: str = "groups_first") -> Path:
    """A float, analog-free, Intel C3D of ``points_mm`` [T, M, 3] (NaN = missing).

    header_last: the header's last frame number (first is 1); point_frames: POINT:FRAMES, an
    int16 parameter. layout: "groups_first" (what ezc3d writes), "params_first" (every
    parameter before its group's record), "array_scalars" (scalars as 1-element arrays,
    locked FRAMES).
    """
    T, M = points_mm.shape[:2]
    sdims = [1] if layout == "array_scalars" else []
    data_start_block = 4  # header block 1, parameters 2-3, data from block 4
    params = [
        _int16("USED", M, sdims),
        _param("FRAMES", POINT_GROUP, 2, sdims, struct.pack("<h", point_frames),
               locked=layout == "array_scalars"),
        _float("SCALE", -1.0, sdims),
        _float("RATE", rate, sdims),
        _int16("DATA_START", data_start_block, sdims),
        _chars("LABELS", labels, max(len(lab) for lab in labels)),
        _chars("UNITS", ["mm"], 2),
    ]
    group = _group("POINT", POINT_GROUP)
    entries = params + [group] if layout == "params_first" else [group] + params
    section = b"\x01\x50\x02\x54" + b"".join(entries)
    section += b"\x00" * 2  # a zero name length ends the section
    if len(section) > 2 * 512:
        raise ValueError("parameter section larger than two blocks")
    section = section.ljust(2 * 512, b"\x00")

    header = bytearray(512)
    header[0], header[1] = 2, 0x50
    struct.pack_into("<HHHHHfHHf", header, 2, M, 0, 1, header_last, 10, -1.0, data_start_block, 0, rate)

    miss = np.isnan(points_mm).any(axis=2)
    frame = np.zeros((T, M, 4), dtype="<f4")
    frame[..., :3] = np.where(miss[..., None], 0.0, points_mm)
    frame[..., 3] = np.where(miss, -1.0, 0.0)  # residual word: negative = missing
    path.write_bytes(bytes(header) + section + frame.tobytes())
    return path
