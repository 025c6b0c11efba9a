"""Where a node may write or read a file it is told about: only inside the folders its graph names.

A graph's params are written by whoever launches it; a command, a message or a replayed bag
comes from anyone who can reach the bus. So a path from the bus (``save {"path": P}``) is honoured
only when, with every symlink followed, it lies inside a folder the graph names for that node
(the folder of its ``model_file``, of its output ``path``...), and a path from a param must stay
in its own folder (a symlink planted at the named place pointing elsewhere is refused). Either way
the target must be a regular file or not exist yet: a device (``/dev/null``), a fifo (whose open
would block the node) or a socket is never written or read. Refusals are one line, PathRefused.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Iterable, Sequence


class PathRefused(ValueError):
    """A path outside the folders the graph names, or one naming no regular file (one line)."""


def _real(path: str | Path) -> Path:
    """``path`` made absolute from the working folder, every symlink on the way followed."""
    return Path(os.path.realpath(Path(path).expanduser()))


def named_folders(paths: Iterable[str | Path]) -> list[Path]:
    """The real folders holding each non-empty path of ``paths`` (the places a graph names)."""
    out: list[Path] = []
    for p in paths:
        if p:
            folder = _real(Path(p).expanduser().absolute().parent)
            if folder not in out:
                out.append(folder)
    return out


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a fifo"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def checked_path(path: str | Path, places: Sequence[str | Path], what: str = "path") -> Path:
    """The real path of ``path`` when it lies inside one of ``places`` and names a regular file or
    nothing yet; PathRefused (one line, naming ``what``) otherwise. Relative paths are taken from
    the working folder, as the node's own open would."""
    text = str(path)
    if not text or "\x00" in text:
        raise PathRefused(f"{what}: {text[:80]!r} is not a path")
    real = _real(text)
    folders = [_real(p) for p in places]
    if not any(real == f or real.is_relative_to(f) for f in folders):
        where = ", ".join(str(f) for f in folders) or "none (no file param of this node names a folder)"
        shown = text[:120] + ("" if real == Path(text) else f" (resolves to {str(real)[:120]})")
        raise PathRefused(f"{what} {shown} is outside the folders this node's graph names: {where}")
    try:
        st = os.stat(real)
    except FileNotFoundError:
        return real
    except OSError as exc:
        raise PathRefused(f"{what} {text[:120]}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise PathRefused(f"{what} {text[:120]} is {_kind(st.st_mode)}, not a regular file")
    return real


def own_folder_path(path: str | Path, what: str = "path") -> Path:
    """A path the graph names itself (a param): checked to stay in its own folder (see module doc)."""
    return checked_path(path, named_folders([path]), what)
