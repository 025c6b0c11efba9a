"""The per-user run directory ($TMPDIR/mocapgraph-<uid>): created 0700, refused when not safely ours.

It holds the manifest socket and the viewer's token files. Another local user who creates it
first (or makes it group/world-writable) could swap the socket and answer our tools, so a
directory we do not own, a symlink, or one others may write into is refused with one line, never
used; one of ours that others may only read (made 0755 by an older version) is closed to 0700.
"""
from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path
from typing import Callable


class UnsafeDirError(RuntimeError):
    """The run directory exists but is not owned by us with mode 0700."""


def check_private_dir(path: Path) -> Path:
    """``path`` if it is a real directory owned by this user with no group/other access."""
    st = os.lstat(path)
    if not stat.S_ISDIR(st.st_mode):
        raise UnsafeDirError(f"{path} is not a directory (a symlink or file there is refused); remove it")
    if st.st_uid != os.getuid():
        raise UnsafeDirError(f"{path} belongs to uid {st.st_uid}, not to you (uid {os.getuid()}): refusing to use "
                             "it; remove it or set TMPDIR elsewhere")
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o022:
        raise UnsafeDirError(f"{path} has mode {mode:04o}, others may write into it (and swap its sockets): "
                             f"refusing to use it; run 'chmod 700 {path}' after checking its contents")
    if mode & 0o077:
        # Ours and writable by us alone (an older version made it 0755): nobody else can have
        # changed what is in it, so closing it is safe.
        os.chmod(path, 0o700)
    return path


def user_dir_path() -> Path:
    """Where the per-user run directory is ($TMPDIR/mocapgraph-<uid>); nothing checked."""
    return Path(tempfile.gettempdir()) / f"mocapgraph-{os.getuid()}"


def user_dir(create: bool = True) -> Path:
    """$TMPDIR/mocapgraph-<uid>, made 0700 when absent; UnsafeDirError when it is not safely ours
    (FileNotFoundError when absent and not ``create``)."""
    path = user_dir_path()
    if create:
        try:
            os.mkdir(path, 0o700)
        except FileExistsError:
            pass
    return check_private_dir(path)


def secret_file(name: str, make: Callable[[], str]) -> str:
    """The text of ``name`` in the user dir, written 0600 by ``make()`` when absent."""
    path = user_dir() / name
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        st = os.lstat(path)
        if stat.S_ISREG(st.st_mode) and st.st_uid == os.getuid() and not stat.S_IMODE(st.st_mode) & 0o077:
            text = path.read_text().strip()
            if text:
                return text
        path.unlink()
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    text = make()
    with os.fdopen(fd, "w") as f:
        f.write(text + "\n")
    return text
