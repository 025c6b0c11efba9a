"""Skeleton definition (limb tree, joints, marker ownership) read from a marker layout.

Indices: limbs ``0..L-1`` in tree order (root first, every parent before its children); joint
``j`` is the joint at the proximal end of limb ``j + 1`` so joints are in tree order too; markers
``0..M-1`` in layout order (limb by limb, as listed in the file).

Sharing a marker between two limbs (see :mod:`mocapgraph.kinematics.layout` for the file format):
a limb lists ``shared: [LABEL, ...]`` naming markers *owned* by an adjacent limb. Ownership stays
single (``marker_limb[m]`` is the owner), while the per-limb fit set ``limb_marker_index()``
contains the limb's own markers followed by its shared ones. A rigid-body fit should use
``limb_marker_index()`` rows (padded with -1), not ``marker_limb``. A shared marker is rigid with
both limbs only if it sits on the axis of a hinge joint between them; the synthetic actor places
shared markers on hinge axes. ``limb_joint_points`` lists joints (indices) whose centre the layout
allows as an extra fit point for a limb (Plug-in Gait thigh and upper arm have 2 markers).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .labels import place_labels

from mocapgraph.kinematics.layout import (
    LayoutError,
    layout_path,
    parse_layout,
    read_layout_yaml,
)

__all__ = ["SkeletonDefinition", "LayoutError"]


@dataclass(frozen=True, eq=False)
class SkeletonDefinition:
    """Limb tree, joints and marker ownership of one marker layout (no geometry)."""

    name: str
    limb_names: tuple[str, ...]
    limb_parent: np.ndarray
    joint_names: tuple[str, ...]
    joint_limbs: np.ndarray
    joint_parent: np.ndarray
    joint_hinge: np.ndarray
    marker_labels: tuple[str, ...]
    marker_limb: np.ndarray
    limb_shared: tuple[tuple[int, ...], ...] = field(default=())
    """Per limb: indices of markers owned by an adjacent limb but also in this limb's fit set."""
    limb_joint_points: tuple[tuple[int, ...], ...] = field(default=())
    """Per limb: joint indices whose centre may serve as an extra rigid-fit point."""
    joint_landmarks: tuple[tuple[int, ...], ...] = field(default=())
    """Per joint: the two landmark marker indices whose midpoint is its anatomical centre, or ()."""
    joint_regression: tuple = field(default=())
    """Per joint: a layout.Regression with marker roles as marker indices, or None."""
    description: str = ""
    source: str = "<dict>"

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_layout_file(cls, path: str | Path) -> "SkeletonDefinition":
        """Read a layout YAML (path, or a name under graph_configs/marker_layouts)."""
        p = layout_path(path)
        data, line_of = read_layout_yaml(p)
        return cls._from_parsed(parse_layout(data, str(p), line_of), str(p))

    @classmethod
    def from_layout_dict(cls, data: dict, source: str = "<dict>") -> "SkeletonDefinition":
        """Build from an already-loaded layout mapping (same schema as the YAML file)."""
        return cls._from_parsed(parse_layout(data, source), source)

    @classmethod
    def _from_parsed(cls, lay, source: str) -> "SkeletonDefinition":
        limb_names = tuple(lb.name for lb in lay.limbs)
        lidx = {n: i for i, n in enumerate(limb_names)}
        limb_parent = np.array([lidx[lb.parent] if lb.parent else -1 for lb in lay.limbs], dtype=np.int64)
        labels: list[str] = []
        owner: list[int] = []
        for i, lb in enumerate(lay.limbs):
            labels.extend(lb.markers)
            owner.extend([i] * len(lb.markers))
        midx = {m.lower(): k for k, m in enumerate(labels)}
        joint_names = tuple(lb.joint_name for lb in lay.limbs[1:])
        jidx = {n: j for j, n in enumerate(joint_names)}
        joint_limbs = np.array([[limb_parent[i], i] for i in range(1, len(limb_names))],
                               dtype=np.int64).reshape(-1, 2)
        # joint at the proximal end of limb i is joint i-1 (root has none)
        joint_parent = np.array([jl[0] - 1 if jl[0] > 0 else -1 for jl in joint_limbs], dtype=np.int64)
        joint_hinge = np.array([lb.joint_type == "hinge" for lb in lay.limbs[1:]], dtype=bool)
        shared = tuple(tuple(midx[m.lower()] for m in lb.shared) for lb in lay.limbs)
        jpts = tuple(tuple(dict.fromkeys(jidx[n] for n in lb.joint_points)) for lb in lay.limbs)
        landmarks = tuple(tuple(midx[m.lower()] for m in lb.landmarks) for lb in lay.limbs[1:])
        regression = tuple(
            None if lb.regression is None else type(lb.regression)(
                lb.regression.method, lb.regression.side,
                {k: midx[v.lower()] for k, v in lb.regression.markers.items()})
            for lb in lay.limbs[1:])
        return cls(
            joint_landmarks=landmarks, joint_regression=regression,
            name=lay.name, limb_names=limb_names, limb_parent=limb_parent,
            joint_names=joint_names, joint_limbs=joint_limbs, joint_parent=joint_parent,
            joint_hinge=joint_hinge, marker_labels=tuple(labels),
            marker_limb=np.array(owner, dtype=np.int64), limb_shared=shared,
            limb_joint_points=jpts, description=lay.description, source=source,
        )

    # ------------------------------------------------------------------ sizes
    @property
    def n_limbs(self) -> int:
        return len(self.limb_names)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_markers(self) -> int:
        return len(self.marker_labels)

    # ------------------------------------------------------------------ queries
    def limb_markers(self, limb: int) -> tuple[int, ...]:
        """Fit set of one limb: own markers (layout order) then shared markers."""
        own = tuple(int(k) for k in np.flatnonzero(self.marker_limb == limb))
        return own + (self.limb_shared[limb] if self.limb_shared else ())

    def limb_marker_index(self) -> np.ndarray:
        """int64[L, Kmax]: per limb its fit-set marker indices (own, then shared), padded with -1."""
        rows = [self.limb_markers(i) for i in range(self.n_limbs)]
        kmax = max((len(r) for r in rows), default=0)
        out = np.full((self.n_limbs, kmax), -1, dtype=np.int64)
        for i, r in enumerate(rows):
            out[i, : len(r)] = r
        return out

    def limb_index(self, name: str) -> int:
        return self.limb_names.index(name)

    def joint_index(self, name: str) -> int:
        return self.joint_names.index(name)

    def limb_joint(self, limb: int) -> int:
        """Joint at the proximal end of ``limb`` (-1 for the root)."""
        return limb - 1

    def match_labels(self, labels: list[str]) -> tuple[np.ndarray, list[str]]:
        """Place capture labels on layout markers (:func:`~mocapgraph.kinematics.labels.place_labels`)."""
        return place_labels(self.marker_labels, labels)

    def __repr__(self) -> str:
        return (f"SkeletonDefinition({self.name!r}: {self.n_limbs} limbs, {self.n_joints} joints, "
                f"{self.n_markers} markers)")
