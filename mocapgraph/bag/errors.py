"""The one exception of :mod:`mocapgraph.bag`: one line naming the file, the fault and what to do."""
from __future__ import annotations

from pathlib import Path


class BagError(Exception):
    """A bag (or a conversion source/target) that cannot be used as asked.

    ``str(err)`` is one line: ``"<file>: <fault>[; <hint>]"``. ``damaged`` is True when
    ``mocapgraph bag recover`` may help.
    """

    def __init__(self, path: str | Path | None, fault: str, hint: str = "", damaged: bool = False) -> None:
        self.path = None if path is None else Path(path)
        self.fault = " ".join(str(fault).split())
        self.hint = hint
        self.damaged = damaged
        name = str(self.path) if self.path is not None else "<bag>"
        super().__init__(f"{name}: {self.fault}" + (f"; {hint}" if hint else ""))
