"""Input-file parameters (``Param(kind="file")``): where a named file is looked for, and whether
it can be read, so the graph check can refuse a missing capture before any process starts.

A relative path is tried from the working directory, then from the project root (so
``../shared/data/...`` in a shipped graph works from anywhere); the node and the check use this
same rule, so they cannot disagree about which file is meant.
"""
from __future__ import annotations

import os
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[2]


class InputFileError(ValueError):
    """A named input file that is absent or cannot be read (one line, no path prefix)."""


def resolve_input_file(value: str) -> Path:
    """The file ``value`` names (see module doc); InputFileError when absent."""
    if not value:
        raise InputFileError("no file given")
    p = Path(value).expanduser()
    if p.is_absolute() or p.exists():
        if not p.exists():
            raise InputFileError(f"{p}: file not found")
        return p
    alt = PROJECT_ROOT / p
    if alt.exists():
        return alt
    where = sorted({str(Path.cwd()), str(PROJECT_ROOT)})
    raise InputFileError(f"{value}: file not found (looked in {' and '.join(where)})")


def check_input_file(value: str) -> Path:
    """The resolved file, checked to be a regular file this process can open and read."""
    p = resolve_input_file(value)
    if p.is_dir():
        raise InputFileError(f"{value}: is a directory, not a file")
    if not p.is_file():  # a device (/dev/zero: endless) or a fifo (the open blocks): never a capture
        raise InputFileError(f"{value}: is a device, fifo or socket, not a regular file")
    try:
        with open(p, "rb") as fh:
            fh.read(1)
    except OSError as exc:
        raise InputFileError(f"{value}: cannot read ({exc.strerror or exc})") from None
    if not os.access(p, os.R_OK):  # root opens anything; others are told here, not at launch
        raise InputFileError(f"{value}: cannot read (permission denied)")
    return p
