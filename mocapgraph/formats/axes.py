"""Axis conventions: turning a file's up/forward axes into the world frame (Z up, X forward).

An axis is written as a signed letter: "+X", "-z", "Y" (sign defaults to +).
"""
from __future__ import annotations

import numpy as np

_LETTERS = "XYZ"


def parse_axis(spec: str) -> np.ndarray:
    """Unit vector for "+X" / "-Y" / "z"...; ValueError for anything else."""
    s = str(spec).strip().upper()
    sign = 1.0
    if s[:1] in "+-":
        sign = -1.0 if s[0] == "-" else 1.0
        s = s[1:]
    if len(s) != 1 or s not in _LETTERS:
        raise ValueError(f"not an axis: {spec!r} (expected e.g. '+Z', '-Y')")
    v = np.zeros(3)
    v[_LETTERS.index(s)] = sign
    return v


def axis_name(v: np.ndarray) -> str:
    """"+X"-style name of a signed unit axis vector."""
    i = int(np.argmax(np.abs(v)))
    return ("+" if v[i] > 0 else "-") + _LETTERS[i]


def to_world_rotation(up: str, forward: str) -> np.ndarray:
    """Proper rotation R (3x3, column-vector convention) with world = R @ file.

    ``up`` and ``forward`` are the file's axes that become world +Z and world +X; world +Y
    (left) follows from right-handedness. They must be perpendicular.
    """
    z = parse_axis(up)
    x = parse_axis(forward)
    if abs(float(z @ x)) > 0.5:
        raise ValueError(f"up {up!r} and forward {forward!r} are not perpendicular")
    y = np.cross(z, x)
    return np.stack([x, y, z])  # rows: world axes expressed in file coordinates


def describe_rotation(R: np.ndarray) -> str:
    """Human sentence for a file->world axis map, e.g. "axes (x, -z, y) -> (X, Y, Z)"."""
    parts = []
    for row in R:
        i = int(np.argmax(np.abs(row)))
        parts.append(("-" if row[i] < 0 else "") + "xyz"[i])
    return f"file axes ({', '.join(parts)}) -> world (X forward, Y left, Z up)"


def default_forward(up: str) -> str:
    """The file axis used as forward when only the up axis is known: +X unless X is up."""
    letter = axis_name(parse_axis(up))[1]
    return "+Y" if letter == "X" else "+X"
