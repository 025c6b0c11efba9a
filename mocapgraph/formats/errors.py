"""The one exception every reader in :mod:`mocapgraph.formats` raises on bad input."""
from __future__ import annotations

from pathlib import Path


class FormatError(Exception):
    """A file (or byte stream) that cannot be read as the format it claims to be.

    ``str(err)`` is always ONE line: ``"<file name>: <fault>"``, fit to show a user as is.
    The full path stays available as ``err.path``.
    """

    def __init__(self, path: str | Path | None, fault: str) -> None:
        self.path = None if path is None else Path(path)
        self.fault = " ".join(str(fault).split())  # one line, whatever the library said
        name = self.path.name if self.path is not None else "<stream>"
        super().__init__(f"{name}: {self.fault}")
