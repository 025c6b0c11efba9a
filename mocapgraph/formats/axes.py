"""Axis conventions: turning a file's up/forward axes into the world frame (Z up, X forward).

An axis is written as a signed letter: "+X", "-z", "Y" (sign defaults to +). An empty or
absent value means "not given" (:func:`optional_axis` returns None); only a non-empty value that
is not an axis is an error.
"""
from __future__ import annotations

import numpy as np

_LETTERS = "XYZ"


def parse_axis(spec: str) -> np.ndarray:
    """Unit vector for "+X" / "-Y" / "z"...; ValueError for anything else (empty included)."""
    s = str(spec).strip().upper()
    sign = 1.0
    # s[:1] is "" for an empty string, and "" in "+-" is True: test the length first
    if len(s) > 1 and s[0] in "+-":
        sign = -1.0 if s[0] == "-" else 1.0
        s = s[1:]
    if len(s) != 1 or s not in _LETTERS:
        raise ValueError(f"not an axis: {spec!r} (expected e.g. '+Z', '-Y')")
    v = np.zeros(3)
    v[_LETTERS.index(s)] = sign
    return v


def optional_axis(spec: str | None) -> np.ndarray | None:
    """Like :func:`parse_axis`, but None, "" (and whitespace) mean "not given" -> None."""
    if spec is None or not str(spec).strip():
        return None
    return parse_axis(spec)


UP_CHOICES = ("auto", "x", "y", "z", "+x", "-x", "+y", "-y", "+z", "-z")


def up_option(value: str | None) -> str | None:
    """A user's up-axis choice ("auto", "", None, "y", "-Z"...) -> "+Y"-style name, or None for
    "auto" (the file's own declaration, else the format's convention). ValueError otherwise."""
    if value is None or str(value).strip().lower() in ("", "auto"):
        return None
    return axis_name(parse_axis(value))


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
