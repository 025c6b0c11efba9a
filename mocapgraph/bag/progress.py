"""A small progress bar for long conversions and recoveries (stderr, only on a terminal)."""
from __future__ import annotations

import sys
import time
from typing import IO


class ProgressBar:
    """``bar(done, total)`` redraws at most 10 times a second; ``close()`` ends the line."""

    def __init__(self, label: str, stream: IO[str] | None = None, enabled: bool | None = None,
                 unit: str = "") -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.unit = unit
        self._last = 0.0
        self._t0 = time.monotonic()
        self._drawn = False

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last < 0.1 and done < total:
            return
        self._last = now
        frac = min(1.0, done / total) if total > 0 else 0.0
        width = 30
        fill = int(frac * width)
        amount = f"{done / 1e6:.1f}/{total / 1e6:.1f} MB" if self.unit == "bytes" else f"{done}/{total}"
        self.stream.write(f"\r{self.label} [{'#' * fill}{'.' * (width - fill)}] {100 * frac:5.1f}% {amount} "
                          f"{now - self._t0:5.1f} s")
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False

    def __enter__(self) -> "ProgressBar":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
