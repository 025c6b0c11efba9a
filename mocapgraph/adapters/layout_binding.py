"""Bind a marker stream's latched MarkerLayout to a skeleton definition, and pick its markers from frames.

``where[m]`` is the stream index of the definition's marker ``m`` (labels placed by
:func:`mocapgraph.kinematics.labels.place_labels`); a stream lacking any of them cannot be bound.
"""
from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from ..kinematics.labels import missing_labels, place_labels
from ..kinematics.layout import LayoutError, layout_path
from ..kinematics.model import ActorModel
from ..kinematics.skeleton import SkeletonDefinition
from ..messages import MarkerFrame, MarkerLayout


class BindError(ValueError):
    """A stream that cannot be bound: one line, plus JSON ``data`` for the status (may be empty)."""

    def __init__(self, detail: str, data: dict[str, Any] | None = None) -> None:
        super().__init__(detail)
        self.data = data


def bind_stream(definition: SkeletonDefinition | None,
                stream: MarkerLayout) -> tuple[SkeletonDefinition, np.ndarray]:
    """(definition, where: int[M]) for ``stream``; without a definition, the layout the stream names.

    BindError when the stream names no layout (and none is given), its layout cannot be read, or
    it lacks some of the definition's markers (listed in ``data["missing_markers"]``).
    """
    if definition is None:
        if not stream.name:
            raise BindError("no `layout` param and the marker stream names no layout")
        try:
            definition = SkeletonDefinition.from_layout_file(layout_path(stream.name))
        except LayoutError as exc:
            raise BindError(f"layout '{stream.name}' of the marker stream: {exc}") from None
    where, _ = place_labels(definition.marker_labels, list(stream.labels))
    missing = missing_labels(definition.marker_labels, where)
    if missing:
        raise BindError(f"layout '{definition.name}' names markers the marker stream "
                        f"('{stream.name or stream.source}') lacks: {', '.join(missing)}",
                        {"missing_markers": missing})
    return definition, where


def layout_markers(frame: MarkerFrame, where: np.ndarray,
                   n_stream: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(x: float[M,3] m, world, NaN unseen; ok: bool[M] seen) of the bound markers in ``frame``,
    or None for a frame whose marker count is not the stream layout's ``n_stream``."""
    pos = frame.positions
    if pos.shape[0] != n_stream:
        return None
    x = pos[where]
    ok = np.isfinite(x).all(1)
    if frame.valid.shape == (pos.shape[0],):
        ok &= frame.valid[where]
    x[~ok] = np.nan
    return x, ok


class StreamBinding:
    """One consumer's binding to a marker stream: its definition (from a layout param, else the
    stream's own layout), the stream's latched layout, ``where``, and frames held until then.

    The latched layout travels on its own socket and may land just after the first frames:
    up to ``hold`` early frames are kept so that frame 0 can still count.
    """

    def __init__(self, layout: str = "", hold: int = 64) -> None:
        self.definition: SkeletonDefinition | None = None
        self.error = ""                        # the layout param's fault, if any
        self.stream: MarkerLayout | None = None
        self.where: np.ndarray | None = None   # int[M]: layout marker -> stream index
        self.early: deque = deque(maxlen=hold)
        if layout:
            try:
                self.definition = SkeletonDefinition.from_layout_file(layout)
            except LayoutError as exc:
                self.error = str(exc)

    def bind(self) -> None:
        """Bind to the stream's layout (see :func:`bind_stream`); BindError leaves it unbound."""
        self.where = None
        self.definition, self.where = bind_stream(self.definition, self.stream)

    def check(self, model: ActorModel, source: str) -> None:
        """ModelFileError if ``model`` was calibrated for another layout than the bound one."""
        if self.definition is not None and self.where is not None:
            model.check_layout(self.definition.name, self.definition.marker_labels, source=source)

    def release(self) -> list[tuple[MarkerFrame, int]]:
        """The held (frame, capture ns) pairs, oldest first; the hold is emptied."""
        out = list(self.early)
        self.early.clear()
        return out

    def pick(self, frame: MarkerFrame) -> tuple[np.ndarray, np.ndarray] | None:
        """:func:`layout_markers` of a frame of the bound stream."""
        return layout_markers(frame, self.where, len(self.stream.labels))
