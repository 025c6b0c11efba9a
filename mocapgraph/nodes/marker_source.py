"""What every marker reader shares: frames in LAYOUT order and a latched MarkerLayout.

Every marker source (synthetic actor, C3D, TRC, serial, UDP, LSL) publishes

- ``markers`` [MarkerFrame]: positions in metres, world frame, in the order of the layout's
  markers; a layout marker the source does not have (or did not see this frame) is NaN with
  ``valid`` False;
- ``marker_layout`` [MarkerLayout, latched]: labels, limbs, what the reader converted, and the
  source labels the layout could not place (``unplaced``, also logged).

The ``layout`` parameter names a file under ``graph_configs/marker_layouts`` (or a path);
``""`` publishes the source's own labels in the source's order. Labels match case-insensitively,
ignoring a Vicon ``Subject:`` prefix. Reordering is one fancy-index per frame (or per file).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..bus import Output, Param
from ..formats import MarkerTrial
from ..kinematics.skeleton import SkeletonDefinition
from ..messages import MarkerFrame, MarkerLayout
from .source_base import FilePlayback, SourceError, SourceNode


@dataclass
class LayoutMap:
    """Where each layout marker comes from in the source's marker order.

    index: int64[M] source column of each layout marker, -1 where the source lacks it.
    """

    name: str
    labels: list[str]
    index: np.ndarray
    n_source: int
    limb_names: list[str] = field(default_factory=list)
    marker_limb: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    unplaced: list[str] = field(default_factory=list)

    @classmethod
    def build(cls, layout: str, source_labels: list[str], source: str = "source") -> "LayoutMap":
        """Match ``source_labels`` to ``layout`` ("" keeps them as they are).

        SourceError when a layout is given and not one label matches it (a wrong layout, most
        likely); LayoutError for a broken layout file.
        """
        n = len(source_labels)
        if not layout:
            return cls("", list(source_labels), np.arange(n, dtype=np.int64), n,
                       marker_limb=np.full(n, -1, np.int32))
        sk = SkeletonDefinition.from_layout_file(layout)
        index, unplaced = sk.match_labels(list(source_labels))
        if n and not (index >= 0).any():
            shown = ", ".join(source_labels[:6]) + (", ..." if n > 6 else "")
            raise SourceError(f"{source}: none of its {n} labels ({shown}) is a marker of layout "
                              f"'{sk.name}' (set layout: \"\" to pass the labels through)")
        return cls(sk.name, list(sk.marker_labels), index, n, list(sk.limb_names),
                   np.asarray(sk.marker_limb, dtype=np.int32), list(unplaced))

    @classmethod
    def in_order(cls, layout: str, n_channels: int) -> "LayoutMap":
        """A device without channel labels: its channels ARE the layout's markers, in order."""
        sk = SkeletonDefinition.from_layout_file(layout)
        if sk.n_markers != n_channels:
            raise SourceError(f"layout '{sk.name}' has {sk.n_markers} markers but the device sends "
                              f"{n_channels} (give the device's channel labels in its configuration)")
        return cls.build(layout, list(sk.marker_labels))

    @property
    def n_markers(self) -> int:
        return len(self.labels)

    @property
    def missing(self) -> list[str]:
        """Layout markers the source never provides."""
        return [lab for lab, i in zip(self.labels, self.index) if i < 0]

    def _take(self) -> np.ndarray:
        return np.where(self.index < 0, self.n_source, self.index)

    def positions(self, src: np.ndarray) -> np.ndarray:
        """Source positions [..., n_source, 3] -> layout order [..., M, 3] (NaN where absent)."""
        pad = np.full(src.shape[:-2] + (1, 3), np.nan)
        return np.concatenate([src, pad], axis=-2)[..., self._take(), :]

    def values(self, src: np.ndarray, fill: float) -> np.ndarray:
        """Per-marker source values [..., n_source] -> layout order [..., M] (``fill`` where absent)."""
        pad = np.full(src.shape[:-1] + (1,), fill, dtype=np.result_type(src, type(fill)))
        return np.concatenate([src, pad], axis=-1)[..., self._take()]

    def message(self, units_note: str, source: str) -> MarkerLayout:
        return MarkerLayout(name=self.name, labels=self.labels, limb_names=self.limb_names,
                            marker_limb=self.marker_limb, units_note=units_note,
                            unplaced=[str(u) for u in self.unplaced], source=source)


class MarkerSourceNode(SourceNode):
    """Base of marker readers: ``markers`` + latched ``marker_layout``, the ``layout`` param."""

    markers = Output("markers", MarkerFrame, "marker frames in layout order: m, world frame (Z up, X forward); "
                     "NaN and valid False where a marker is missing")
    marker_layout = Output("marker_layout", MarkerLayout, "latched: marker labels, limbs, unit/axis conversions, "
                           "source labels the layout could not place")
    layout = Param("", "marker layout: a name under graph_configs/marker_layouts or a .yaml path; "
                       "'' = the source's own labels, in its order")

    lmap: LayoutMap | None = None

    def bind_layout(self, source_labels: list[str], units_note: str, source: str) -> LayoutMap:
        """Match labels to the layout, log what did not fit, publish the latched MarkerLayout."""
        lmap = LayoutMap.build(self.layout, source_labels, source)
        self.publish_layout(lmap, units_note, source)
        return lmap

    def publish_layout(self, lmap: LayoutMap, units_note: str, source: str) -> None:
        self.lmap = lmap
        if lmap.unplaced:
            self.log.warning("%d source label(s) not in layout '%s', left out: %s", len(lmap.unplaced),
                             lmap.name, ", ".join(map(str, lmap.unplaced[:12])) + (" ..." if len(lmap.unplaced) > 12 else ""))
        if lmap.name and lmap.missing:
            self.log.warning("%d layout marker(s) the source does not have (always missing): %s",
                             len(lmap.missing), ", ".join(lmap.missing[:12]) + (" ..." if len(lmap.missing) > 12 else ""))
        if units_note:
            self.log.info("converted: %s", units_note)
        self.marker_layout.publish(lmap.message(units_note, source))

    def publish_frame(self, frame_number: int, rate_hz: float, positions: np.ndarray, capture_ns: int,
                      residual: np.ndarray | None = None, valid: np.ndarray | None = None) -> None:
        """One frame already in layout order (positions [M, 3] m, world; NaN where missing)."""
        if valid is None:
            valid = ~np.isnan(positions).any(axis=1)
        if residual is None:
            residual = np.full(positions.shape[0], np.nan, np.float32)
        self.markers.publish(MarkerFrame(frame_number=int(frame_number), rate_hz=float(rate_hz),
                                         positions=positions, valid=valid, residual=residual),
                             capture_ns=int(capture_ns))


#: values the ``up_axis`` parameter takes: "auto" ("" too, for older graphs) or a signed axis
UP_AXIS_CHOICES = ("auto", "") + tuple(f"{s}{a}" for a in "XYZxyz" for s in ("", "+", "-"))


def device_up_axis() -> Param:
    """The ``up_axis`` param of a device reader (serial, UDP, LSL): see formats/device_file.py."""
    return Param("auto", "the device axis that points up, made world Z: 'auto' = the device file's "
                         "to_world (none: the device frame is the world); or x, y, z with an optional "
                         "sign, where the device file sets no to_world.up (both set and different: "
                         "refused)", choices=UP_AXIS_CHOICES)


def check_device_param(params: dict[str, Any]) -> None:
    """The graph check's look at a device reader's ``device`` file (with its ``up_axis``): a file the
    reader would refuse (NaN or inf in it, a bad key...) fails the check, naming the device file's line."""
    from ..bus.node import NodeConfigError
    from ..formats.device_file import DeviceConfigError, device_or_default

    try:
        device_or_default(str(params.get("device", "")), params.get("up_axis"))
    except DeviceConfigError as exc:
        raise NodeConfigError(f"parameter 'device': {exc}") from None


class MarkerFilePlayer(FilePlayback, MarkerSourceNode):
    """Replays a MarkerTrial (C3D, TRC) in real time or faster; subclasses only read the file."""

    up_axis = Param("auto", "the file's up axis, made world Z: 'auto' = what the file says (C3D "
                            "POINT:Y_SCREEN, else Z; TRC: Y, the OpenSim convention), or x, y, z "
                            "with an optional sign ('+Y', '-z')", choices=UP_AXIS_CHOICES)

    #: False for formats without per-sample residuals (their MarkerTrial holds 0): sent as NaN
    has_residuals = True

    def read_trial(self, path: Path) -> MarkerTrial:
        raise NotImplementedError

    def load(self, path: Path) -> None:
        trial = self.read_trial(path)
        if trial.n_frames == 0:
            raise SourceError(f"{path.name}: has no frames")
        self.trial = trial
        self.source = f"{type(self).__name__.lower()} {path.name}"
        self.units_note = "; ".join(trial.conversions)
        self.lmap = LayoutMap.build(self.layout, trial.labels, path.name)
        # Reorder the whole file once: per-frame work is then a row lookup.
        self.positions = np.ascontiguousarray(self.lmap.positions(trial.positions))
        self.valid = ~np.isnan(self.positions).any(axis=2)
        res = trial.residuals if self.has_residuals else np.full(trial.residuals.shape, np.nan)
        self.residuals = self.lmap.values(res, np.nan).astype(np.float32)
        self.times_ns = trial.timestamps_ns
        self.frame_numbers = trial.first_frame + np.arange(trial.n_frames)
        self.rate_hz = trial.rate_hz
        for note in trial.notes:
            # a renamed duplicate changes what a layout sees: worth a warning, not an info line
            level = self.log.warning if note.startswith("duplicate label") else self.log.info
            level("%s: %s", path.name, note)

    def announce(self) -> None:
        self.publish_layout(self.lmap, self.units_note, self.source)

    def emit(self, index: int, capture_ns: int) -> None:
        self.markers.publish(MarkerFrame(frame_number=int(self.frame_numbers[index]), rate_hz=self.rate_hz,
                                         positions=self.positions[index], valid=self.valid[index],
                                         residual=self.residuals[index]), capture_ns=capture_ns)

    def status_data(self) -> dict[str, Any]:
        d = super().status_data()
        d.update(markers=self.lmap.n_markers if self.lmap else 0,
                 unplaced=len(self.lmap.unplaced) if self.lmap else 0)
        return d
