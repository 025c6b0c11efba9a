"""Turns decoded NatNet frames into arrays in the fixed order of the model definitions (labels, bodies).

Pure, vectorised per frame. A :class:`NatNetModel` is built once per NAT_MODELDEF:

- **Labelled markers**: one source label per marker of each marker set, ``"SET:MARKER"`` (a
  layout matches the part after the colon, as it ignores a Vicon subject prefix; a marker named
  ``SET_MARKER`` loses the repeated ``SET_``). A marker set
  named like a rigid body or skeleton takes its frame positions from the labelled-marker list,
  where a marker's id is ``model id << 16 | marker index (1-based)`` and the model id is that rigid
  body's or skeleton's id: there the occluded flag and residual live, so an occluded marker is NaN,
  never its stale position. A set with no such owner takes the frame's marker-set positions (a
  point at exactly 0, 0, 0 is Motive's "not seen": NaN). Motive's ``all`` set repeats the others
  and is left out. A rigid body without a marker set (NatNet 4.0+ gives marker names in its
  description) gets ``"BODY:NAME"`` labels, or ``"BODY:MarkerK"``.
- **Unlabelled markers**: the frame's "other markers" section, then the labelled-list markers of
  model id 0 (Motive 2+ sends its unlabelled markers there; 3.x leaves the legacy section empty).
- **Rigid bodies**: in description order; a body missing from the frame or whose tracking-valid
  bit is clear is NaN (position, orientation, error) with quality 0.
- **Skeletons**: a skeleton's bones in description order (:class:`SkeletonBones`); a bone's id in
  a frame is ``skeleton id << 16 | bone id`` (Motive) or the bare bone id (only its low 16 bits
  are matched); a bone missing from the frame or untracked is NaN with valid False. Bone poses
  come global, or (Motive's "Local" skeleton coordinates) relative to the parent bone, composed
  into global poses by :func:`local_to_global` (one vectorised step per depth of the hierarchy).
- **Unknown ids**: a labelled marker whose model id is not 0 and not described, or a rigid body
  id not described, sets ``unknown`` so the reader asks for the model definitions again.

Units stay NatNet's (metres, Motive axes); quaternions come out w, x, y, z.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import natnet as nn

#: Motive's marker set that lists every labelled marker again
ALL_SET = "all"


@dataclass
class Labelled:
    """One frame's labelled markers in source-label order (NaN where missing)."""

    positions: np.ndarray   # float64[S, 3], m, NatNet axes
    residual: np.ndarray    # float32[S], m, NaN where unknown
    unknown: bool           # a labelled marker of an undescribed model was in the frame


@dataclass
class Bodies:
    """One frame's rigid bodies in description order."""

    positions: np.ndarray   # float64[R, 3], NaN where not tracked
    quat_wxyz: np.ndarray   # float64[R, 4], NaN where not tracked
    error: np.ndarray       # float32[R], mean marker error m, NaN where not tracked
    valid: np.ndarray       # bool[R]
    unknown: bool           # an undescribed rigid body id was in the frame


class NatNetModel:
    """Label and body order from one NAT_MODELDEF, and the per-frame lookups (see module doc)."""

    def __init__(self, defs: nn.ModelDefs) -> None:
        self.defs = defs
        owners = {rb.name: rb.id for rb in defs.rigid_bodies}
        owners.update({name: sid for name, (sid, _) in defs.skeletons.items()})
        labels: list[str] = []
        keys: list[int] = []
        cols: list[int] = []
        self.set_columns: dict[str, np.ndarray] = {}  # marker sets read from the frame's set data
        for name, markers in defs.marker_sets.items():
            if name == ALL_SET and len(defs.marker_sets) > 1:
                continue
            start = len(labels)
            labels += [f"{name}:{_unprefixed(m, name)}" for m in markers]
            if name in owners:
                keys += [(owners[name] << 16) | (k + 1) for k in range(len(markers))]
                cols += range(start, start + len(markers))
            else:
                self.set_columns[name] = np.arange(start, start + len(markers))
        for rb in defs.rigid_bodies:
            if rb.name in defs.marker_sets:
                continue
            n = len(rb.marker_positions)
            names = rb.marker_names if len(rb.marker_names) == n else [f"Marker{k + 1}" for k in range(n)]
            keys += [(rb.id << 16) | (k + 1) for k in range(n)]
            cols += range(len(labels), len(labels) + n)
            labels += [f"{rb.name}:{m}" for m in names]
        self.labels = labels
        order = np.argsort(np.asarray(keys, np.int64), kind="stable")
        self._keys = np.asarray(keys, np.int64)[order]
        self._cols = np.asarray(cols, np.int64)[order]
        self.body_names = [rb.name for rb in defs.rigid_bodies]
        self.body_ids = np.asarray([rb.id for rb in defs.rigid_bodies], np.int64)
        by_id = {rb.id: i for i, rb in enumerate(defs.rigid_bodies)}
        self.body_parents = np.asarray([by_id.get(rb.parent_id, -1) for rb in defs.rigid_bodies], np.int32)
        self._body_order = np.argsort(self.body_ids, kind="stable")

    @property
    def n_labels(self) -> int:
        return len(self.labels)

    def _lookup(self, keys: np.ndarray, table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions of ``keys`` in the sorted ``table`` and whether each was found."""
        if table.size == 0:
            return np.zeros(keys.shape, np.int64), np.zeros(keys.shape, bool)
        at = np.minimum(np.searchsorted(table, keys), table.size - 1)
        return at, table[at] == keys

    def labelled(self, f: nn.Frame) -> Labelled:
        pos = np.full((self.n_labels, 3), np.nan)
        res = np.full(self.n_labels, np.nan, np.float32)
        lm = f.labelled_markers
        ids = lm["id"].astype(np.int64) & 0xFFFFFFFF
        at, found = self._lookup(ids, self._keys)
        seen = found & ((lm["params"] & nn.MARKER_OCCLUDED) == 0)
        cols = self._cols[at[seen]]
        pos[cols] = lm["pos"][seen]
        res[cols] = lm["residual"][seen]
        unknown = bool(((ids >> 16) != 0)[~found].any())
        for name, columns in self.set_columns.items():
            p = f.marker_sets.get(name)
            if p is None or len(p) != len(columns):
                unknown |= p is not None
                continue
            p = p.astype(np.float64)
            p[(p == 0).all(axis=1)] = np.nan
            pos[columns] = p
        return Labelled(pos, res, unknown)

    def bodies(self, f: nn.Frame) -> Bodies:
        r = len(self.body_ids)
        pos = np.full((r, 3), np.nan)
        quat = np.full((r, 4), np.nan)
        err = np.full(r, np.nan, np.float32)
        rb = f.rigid_bodies
        at, found = self._lookup(rb["id"].astype(np.int64), self.body_ids[self._body_order])
        ok = found & f.rigid_body_valid
        rows = self._body_order[at[ok]]
        pos[rows] = rb["pos"][ok]
        quat[rows] = rb["quat_xyzw"][ok][:, [3, 0, 1, 2]]
        err[rows] = rb["error"][ok]
        valid = np.zeros(r, bool)
        valid[rows] = True
        return Bodies(pos, quat, err, valid, bool((~found).any()))


@dataclass
class SkeletonBones:
    """One skeleton asset of the model definitions: bone names, ids, parent indices, offsets."""

    name: str
    id: int
    names: list[str]
    ids: np.ndarray          # int64[B], the bones' ids (1-based in Motive)
    parents: np.ndarray      # int32[B], parent bone index, -1 for the root
    offsets: np.ndarray      # float64[B, 3], m, from the parent bone, NatNet axes
    levels: list[np.ndarray]  # bone indices by depth in the hierarchy, roots first


def skeleton_bones(defs: nn.ModelDefs, name: str = "") -> SkeletonBones | None:
    """The skeleton ``name`` ('' = the first one that has bones), or None."""
    for sname, (sid, bones) in defs.skeletons.items():
        if (name and sname == name) or (not name and bones):
            ids = np.asarray([b.id for b in bones], np.int64)
            by_id = {b.id: i for i, b in enumerate(bones)}
            parents = np.asarray([by_id.get(b.parent_id, -1) for b in bones], np.int32)
            offsets = np.asarray([b.offset for b in bones], np.float64).reshape(-1, 3)
            return SkeletonBones(sname, sid, [b.name for b in bones], ids, parents, offsets, depth_levels(parents))
    return None


def depth_levels(parents: np.ndarray) -> list[np.ndarray]:
    """Indices of a hierarchy's nodes by depth (roots first; a node whose parent chain loops or
    leaves the hierarchy counts as a root)."""
    p = np.asarray(parents, np.int64)
    n = len(p)
    pc = np.clip(p, 0, max(n - 1, 0))
    depth = np.zeros(n, np.int64)
    known = (p < 0) | (p >= n)
    for _ in range(n):                          # once per definition, not per frame
        ready = ~known & known[pc]
        if not ready.any():
            break
        depth[ready] = depth[pc[ready]] + 1
        known |= ready
    return [np.flatnonzero(depth == d) for d in range(int(depth.max()) + 1)] if n else []


def local_to_global(pos: np.ndarray, quat_wxyz: np.ndarray, parents: np.ndarray,
                    levels: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Bone poses relative to their parent bone -> global (NaN where a bone or an ancestor is NaN)."""
    from ..kinematics.quaternion import quat_multiply, quat_rotate

    gp, gq = pos.copy(), quat_wxyz.copy()
    for lv in levels[1:]:
        par = parents[lv]
        gq[lv] = quat_multiply(gq[par], quat_wxyz[lv])
        gp[lv] = gp[par] + quat_rotate(gq[par], pos[lv])
    return gp, gq


def bone_poses(f: nn.Frame, sk: SkeletonBones) -> Bodies:
    """The frame's poses of skeleton ``sk``'s bones in description order (module doc); all NaN when
    the frame does not carry that skeleton."""
    b = len(sk.ids)
    pos = np.full((b, 3), np.nan)
    quat = np.full((b, 4), np.nan)
    err = np.full(b, np.nan, np.float32)
    valid = np.zeros(b, bool)
    rb = f.skeletons.get(sk.id)
    if rb is None or b == 0:
        return Bodies(pos, quat, err, valid, False)
    order = np.argsort(sk.ids, kind="stable")
    table = sk.ids[order]
    at = np.minimum(np.searchsorted(table, rb["id"].astype(np.int64) & 0xFFFF), b - 1)
    found = table[at] == (rb["id"].astype(np.int64) & 0xFFFF)
    ok = found & ((rb["params"] & nn.RIGID_BODY_TRACKING_VALID) != 0)
    rows = order[at[ok]]
    pos[rows] = rb["pos"][ok]
    quat[rows] = rb["quat_xyzw"][ok][:, [3, 0, 1, 2]]
    err[rows] = rb["error"][ok]
    valid[rows] = True
    return Bodies(pos, quat, err, valid, bool((~found).any()))


def _unprefixed(marker: str, asset: str) -> str:
    """``Actor_LFHD`` in set ``Actor`` -> ``LFHD``: the asset name once, before the colon."""
    head = asset + "_"
    return marker[len(head):] if marker.startswith(head) and len(marker) > len(head) else marker


def unlabelled(f: nn.Frame) -> tuple[np.ndarray, np.ndarray]:
    """(positions float64[K, 3], residual float32[K]) of the frame's unlabelled markers (module doc)."""
    lm = f.labelled_markers
    free = ((lm["id"].astype(np.int64) & 0xFFFFFFFF) >> 16) == 0
    free &= (lm["params"] & nn.MARKER_OCCLUDED) == 0
    pos = np.concatenate([f.other_markers.astype(np.float64), lm["pos"][free].astype(np.float64)])
    res = np.concatenate([np.full(len(f.other_markers), np.nan, np.float32), lm["residual"][free]])
    return pos, res.astype(np.float32)


def system_latency_ns(f: nn.Frame, clock_hz: int) -> int:
    """Mid-exposure to transmit, ns, from the frame's high-resolution stamps; 0 when not given
    (no clock rate, stamps absent or out of order, or a latency over a second: not believable)."""
    if clock_hz <= 0 or not 0 < f.mid_exposure_ticks <= f.transmit_ticks:
        return 0
    lat = (f.transmit_ticks - f.mid_exposure_ticks) * 1_000_000_000 // clock_hz
    return int(lat) if lat < 1_000_000_000 else 0


def device_time_ns(f: nn.Frame, clock_hz: int) -> tuple[int, int]:
    """(the frame's transmit time on the server's clock, ns; mid-exposure to transmit, ns) from the
    high-resolution stamps, for ClockSync.update(device, arrival, latency): the capture stamp is the
    mapped transmit time less that latency. Without them (no clock rate, no transmit stamp):
    (Motive's frame timestamp, 0)."""
    if clock_hz > 0 and f.transmit_ticks > 0:
        return f.transmit_ticks * 1_000_000_000 // clock_hz, system_latency_ns(f, clock_hz)
    return int(round(f.timestamp * 1e9)), 0


def rotation_quat(R: np.ndarray) -> np.ndarray:
    """A rotation matrix as a unit quaternion (w, x, y, z), once per device (not per frame)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R, float)).as_quat(scalar_first=True)
