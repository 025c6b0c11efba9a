"""Progress bars of the batch commands (tqdm on stderr; silent when stderr is not a terminal).

Library code reports progress through a plain ``progress(done, total)`` callable and never
imports tqdm; the commands hand it a `Progress`. ``MOCAPGRAPH_PROGRESS=1`` forces bars on (tests
in a pseudo-terminal do not need it; a CI log captured through a pipe stays clean without it),
``MOCAPGRAPH_PROGRESS=0`` forces them off.
"""
from __future__ import annotations

import os
import sys
from typing import IO

from tqdm import tqdm


def _disable(stream: IO[str]) -> bool | None:
    """tqdm's ``disable`` value: None lets tqdm decide from the stream being a terminal."""
    force = os.environ.get("MOCAPGRAPH_PROGRESS", "")
    if force == "1":
        return False
    if force == "0":
        return True
    return None


class Progress:
    """``bar(done, total)`` moves a tqdm bar to ``done`` of ``total``; a context manager.

    unit: "bytes" shows sizes scaled (kB, MB); anything else counts items of that unit.
    """

    def __init__(self, label: str, unit: str = "frame", total: int | None = None,
                 stream: IO[str] | None = None) -> None:
        stream = stream or sys.stderr
        scale = unit == "bytes"
        self._bar = tqdm(total=total, desc=label, unit="B" if scale else unit, unit_scale=scale,
                         unit_divisor=1024 if scale else 1000, file=stream, disable=_disable(stream),
                         dynamic_ncols=True, leave=True, mininterval=0.1)

    @property
    def enabled(self) -> bool:
        return not self._bar.disable

    def __call__(self, done: int, total: int | None = None) -> None:
        bar = self._bar
        if bar.disable:
            return
        if total is not None and total != bar.total:
            if done >= total and bar.n > total:
                bar.total = bar.n  # "finished" said on another scale (progress(1, 1))
                bar.refresh()
                return
            bar.total = total
            bar.refresh()
        bar.update(max(0, done - bar.n))

    def advance(self, n: int = 1) -> None:
        """Count ``n`` more items done."""
        self._bar.update(n)

    def close(self) -> None:
        if not self._bar.disable and self._bar.total is not None and self._bar.n < self._bar.total:
            self._bar.update(self._bar.total - self._bar.n)  # a finished command ends at 100 %
        self._bar.close()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc: object) -> None:
        if exc and exc[0] is not None:
            self._bar.close()  # an error leaves the bar where it stopped
        else:
            self.close()
