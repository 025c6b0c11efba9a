"""What a retargeting source offers: named points and named rotations, their rest pose, and rotations from points.

Three kinds of source, all in the world frame (m, Z up, X forward, wxyz):

* ``skeleton`` with orientations (BVH playback, SkeletonPose with joint_orientations): the points
  are the joints, the rotations are the joints' world orientations (identity in the BVH rest pose).
* ``skeleton`` without orientations (Kinect CSV: positions only): rotations are derived from the
  points by :func:`rotations_from_points`, identity in the source's rest pose.
* ``optical`` (ActorPose + SkeletonModel): the points are the solved joint centres plus ``pelvis``
  (the mid-point of the hip joints); the rotations are the limbs' world rotations from the base
  pose (identity there), named by limb.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics.quaternion import matrix_to_quat, quat_between, quat_multiply, quat_rotate
from ..kinematics.rest_offsets import offsets_from_rest

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


@dataclass(frozen=True, eq=False)
class SourceSkeleton:
    """Names and rest pose of a source (see the module docstring for the kinds)."""

    kind: str                      # "skeleton" or "optical"
    point_names: tuple[str, ...]
    point_parents: np.ndarray      # int [P], -1 for roots (a forest; any order)
    rest_points: np.ndarray        # float [P, 3] m, world, the source's rest (or base) pose
    rotation_names: tuple[str, ...]
    rest_rotations: np.ndarray     # float [R, 4] wxyz: each rotation's value in the rest pose
    derived_rotations: bool = False  # True: rotations come from the points (rotations_from_points)
    kinect_like: str = ""          # "kinect_v1", "kinect_v2", "bvh", "optical:<layout>"

    def point(self, name: str) -> int:
        try:
            return self.point_names.index(name)
        except ValueError:
            raise KeyError(name) from None

    def rotation(self, name: str) -> int:
        try:
            return self.rotation_names.index(name)
        except ValueError:
            raise KeyError(name) from None

    @property
    def fingerprint(self) -> tuple:
        return (self.kind, self.point_names, self.rotation_names)


def observed_bone_lengths(positions: np.ndarray, parents) -> np.ndarray:
    """Median distance from each joint to its parent over frames [F, J, 3] (m; NaN for roots)."""
    par = np.asarray(parents, dtype=np.int64)
    d = np.linalg.norm(positions - positions[:, np.maximum(par, 0)], axis=-1)
    out = np.nanmedian(np.where(np.isfinite(d), d, np.nan), axis=0) if len(positions) else np.full(len(par), np.nan)
    out[par < 0] = np.nan
    return out


def skeleton_source(names, parents, rest_offsets, *, has_orientations: bool, kind_hint: str = "") -> SourceSkeleton:
    """A SkeletonInfo-like source: ``rest_offsets`` [J, 3] from the parent (the root's: its rest position)."""
    names = tuple(names)
    parents = np.asarray(parents, dtype=np.int64)
    offs = np.asarray(rest_offsets, dtype=np.float64)
    rest = np.zeros_like(offs)
    for j in _topological(parents):
        rest[j] = offs[j] + (rest[parents[j]] if parents[j] >= 0 else 0.0)
    return SourceSkeleton("skeleton", names, parents, rest, names, np.tile(IDENTITY, (len(names), 1)),
                          derived_rotations=not has_orientations, kinect_like=kind_hint)


def pelvis_hips(joint_names) -> list[int]:
    """The joints whose mean is an optical actor's ``pelvis`` point: the hips (``hip*``), else the first."""
    return [i for i, n in enumerate(joint_names) if n.startswith("hip")] or [0]


def optical_source(joint_names, joint_parent, joint_limbs, limb_names, base_joints, layout: str = "") -> SourceSkeleton:
    """An optical actor (SkeletonModel): joint points plus ``pelvis``; limb rotations (identity at base)."""
    names = tuple(joint_names) + ("pelvis",)
    base = np.asarray(base_joints, dtype=np.float64)
    pelvis = base[pelvis_hips(joint_names)].mean(axis=0)
    parents = np.append(np.asarray(joint_parent, dtype=np.int64), -1)
    return SourceSkeleton("optical", names, parents, np.vstack([base, pelvis]), tuple(limb_names),
                          np.tile(IDENTITY, (len(limb_names), 1)), kinect_like=f"optical:{layout}")


def optical_points(joint_positions: np.ndarray, joint_names) -> np.ndarray:
    """[F, J+1, 3]: the solved joints plus the pelvis point (mean of the hip joints)."""
    p = np.asarray(joint_positions, dtype=np.float64)
    pelvis = p[..., pelvis_hips(joint_names), :].mean(axis=-2, keepdims=True)
    return np.concatenate([p, pelvis], axis=-2)


class OpticalFrames:
    """:func:`optical_points` and the point masks for one live frame, the hip indices found once."""

    def __init__(self, joint_names) -> None:
        self.hips = np.array(pelvis_hips(joint_names), dtype=np.int64)
        self.J = len(joint_names)

    def frame(self, joint_positions: np.ndarray, joint_quality: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points [1, J+1, 3] (m; the pelvis point last) and their masks [1, J+1] (quality >= 1)."""
        from .kernels import optical_frame   # compiled: six numpy calls cost ~30 us a frame
        J = self.J
        if joint_positions.shape != (J, 3) or joint_quality.shape != (J,):
            raise ValueError(f"a frame of {J} joints wants positions [{J}, 3] and quality [{J}]")
        pts = np.empty((1, J + 1, 3))
        ok = np.empty((1, J + 1), bool)
        jp = joint_positions if joint_positions.dtype == np.float64 and joint_positions.flags.c_contiguous \
            else np.ascontiguousarray(joint_positions, np.float64)
        jq = joint_quality if joint_quality.dtype == np.int8 and joint_quality.flags.c_contiguous \
            else np.ascontiguousarray(joint_quality, np.int8)
        optical_frame(jp, jq, self.hips, pts[0], ok[0])
        return pts, ok


def _topological(parents: np.ndarray) -> list[int]:
    order, seen = [], set()
    pending = list(range(len(parents)))
    while pending:
        rest = []
        for j in pending:
            if parents[j] < 0 or parents[j] in seen:
                order.append(j)
                seen.add(j)
            else:
                rest.append(j)
        if len(rest) == len(pending):
            raise ValueError("source parents form a cycle")
        pending = rest
    return order


@dataclass(frozen=True, eq=False)
class PointRotationPlan:
    """Precomputed index arrays of :func:`rotations_from_points` for one source."""

    levels: tuple[np.ndarray, ...]     # joints per depth, roots first
    parents: np.ndarray
    primary: np.ndarray                # aim child per joint (-1: leaf)
    secondary: np.ndarray              # [P, 2] points whose difference is the second axis (-1: none)
    rest_primary: np.ndarray           # [P, 3] unit
    rest_frames: np.ndarray            # [P, 3, 3] rest frames of two-axis joints (NaN: none)
    fit_joints: np.ndarray             # joints with three or more children (girdles): best fit over them
    fit_kids: np.ndarray               # [G, K] the points they fit their bones to (-1: padding)
    fit_rest: np.ndarray               # [G, K, 3] unit rest directions to those (0: padding)
    fit_levels: tuple[tuple[np.ndarray, np.ndarray], ...]   # per level: fit mask, their rows in fit_*
    # the one-frame kernel's view (source_kernels.point_rotations), packed: few arguments
    # make a cheap call. Columns: [P, 7] int64 (order: the levels concatenated, a parent before its
    # children; then per joint: parent, kind, primary, secondary a, b, row in fit_*; kind 0 carries
    # its parent's rotation, 1 shortest arc, 2 TRIAD, 3 best fit); [P, 12] rest_primary, rest_frames
    frame_index: np.ndarray = None
    frame_rest: np.ndarray = None

    @property
    def kind(self) -> np.ndarray:
        """[P] how each joint's rotation is derived (0 carried, 1 shortest arc, 2 TRIAD, 3 best fit)."""
        return self.frame_index[:, 2]


def plan_point_rotations(src: SourceSkeleton, *, best_fit: bool = True) -> PointRotationPlan:
    """For every joint: the child it aims at (the one continuing its incoming bone, else the one
    with most descendants), for two-child joints the other child spanning the second axis, and for
    joints with three or more children (a pelvis, a chest) all of them for a best fit (a child that
    only passes through to a leaf on the same line by that leaf, see :func:`_through_to_leaf`).
    ``best_fit=False`` gives those the TRIAD of their aim child and two others instead (the rule
    before the best fit, kept as the benchmark's baseline)."""
    par = src.point_parents
    n = len(par)
    rest = src.rest_points
    order = _topological(par)
    depth = np.zeros(n, dtype=np.int64)
    for j in order:
        depth[j] = depth[par[j]] + 1 if par[j] >= 0 else 0
    ndesc = np.zeros(n, dtype=np.int64)
    for j in reversed(order):
        if par[j] >= 0:
            ndesc[par[j]] += ndesc[j] + 1
    primary = -np.ones(n, dtype=np.int64)
    secondary = -np.ones((n, 2), dtype=np.int64)
    fit: dict[int, list[int]] = {}
    for j in range(n):
        kids = [int(k) for k in np.flatnonzero(par == j) if np.linalg.norm(rest[k] - rest[j]) > 1e-6]
        if not kids:
            continue
        if len(kids) >= 3 and best_fit:
            fit[j] = [_through_to_leaf(par, rest, j, k) for k in kids]
        incoming = rest[j] - rest[par[j]] if par[j] >= 0 else np.array([0.0, 0.0, 1.0])
        if np.linalg.norm(incoming) < 1e-9:
            incoming = np.array([0.0, 0.0, 1.0])
        dirs = [(rest[k] - rest[j]) / np.linalg.norm(rest[k] - rest[j]) for k in kids]
        cos = [float(d @ incoming) / np.linalg.norm(incoming) for d in dirs]
        best = int(np.argmax(cos))
        primary[j] = kids[best] if cos[best] > 0.5 or par[j] < 0 else kids[int(np.argmax(ndesc[kids]))]
        others = [k for k in kids if k != primary[j]]
        if len(others) >= 2:   # e.g. the pelvis (hips) or the chest (shoulders): their difference
            a, b = others[0], others[1]
            secondary[j] = (a, b)
        elif len(others) == 1:
            secondary[j] = (others[0], j)
    rest_primary = np.full((n, 3), np.nan)
    frames = np.full((n, 3, 3), np.nan)
    has = primary >= 0
    rest_primary[has] = _unit(rest[primary[has]] - rest[has])
    two = secondary[:, 0] >= 0
    if two.any():
        frames[two] = _triad(rest_primary[two], rest[secondary[two, 0]] - rest[secondary[two, 1]])
    fit_joints = np.array(sorted(fit), dtype=np.int64)
    K = max((len(v) for v in fit.values()), default=0)
    fit_kids = -np.ones((len(fit_joints), K), dtype=np.int64)
    fit_rest = np.zeros((len(fit_joints), K, 3))
    for g, j in enumerate(fit_joints):
        kids = fit[int(j)]
        fit_kids[g, :len(kids)] = kids
        fit_rest[g, :len(kids)] = _unit(rest[kids] - rest[j])
    secondary[fit_joints] = -1      # a fit joint is no two-axis joint
    levels = tuple(np.flatnonzero(depth == d) for d in range(int(depth.max()) + 1))
    fit_levels = tuple((np.isin(lv, fit_joints), np.searchsorted(fit_joints, lv[np.isin(lv, fit_joints)])) for lv in levels)
    kind = np.where(primary >= 0, 1, 0)
    kind[secondary[:, 0] >= 0] = 2
    kind[fit_joints] = 3
    fit_row = -np.ones(n, dtype=np.int64)
    fit_row[fit_joints] = np.arange(len(fit_joints))
    index = np.column_stack([np.concatenate(levels), par, kind, primary, secondary, fit_row]).astype(np.int64)
    c = np.ascontiguousarray
    return PointRotationPlan(levels, par, primary, secondary, rest_primary, frames, fit_joints, c(fit_kids),
                             c(fit_rest), fit_levels, c(index), c(np.hstack([rest_primary, frames.reshape(n, 9)])))


def _through_to_leaf(par: np.ndarray, rest: np.ndarray, j: int, k: int) -> int:
    """The point a girdle joint j fits its child bone to: k itself, or, when k only passes through
    to a leaf lying on the rest line j->k beyond it (Kinect v2's Neck on the way to the Head), that
    leaf: a character without the pass-through joint carries the whole segment on j."""
    kk = np.flatnonzero(par == k)
    if len(kk) != 1 or (par == kk[0]).any():
        return k
    a, b = rest[k] - rest[j], rest[kk[0]] - rest[j]
    if np.linalg.norm(b) <= np.linalg.norm(a) or float(a @ b) < 0.9999 * np.linalg.norm(a) * np.linalg.norm(b):
        return k
    return int(kk[0])


# Below these a derived rotation is undetermined and NaN (held and flagged downstream), never an
# arbitrary twist flagged good: a triad's two axes within this sine of parallel; a best fit whose
# maximum over rotations is not unique to this margin per bone (all bones on one line, or a mirror
# image of bones spread equally in two directions). Both far below anything a body does.
TRIAD_MIN_SIN = 1e-6
FIT_MIN_GAP = 1e-6


def best_fit_rotations(rest_dirs: np.ndarray, cur: np.ndarray, min_gap: float = FIT_MIN_GAP) -> np.ndarray:
    """Rotation matrices [F, G, 3, 3] best turning unit rest directions [G, K, 3] (0 rows: padding)
    onto the current bone vectors [F, G, K, 3] (any length; 0 rows: padding), every bone weighted
    equally (each current vector made unit): Kabsch by SVD, batched over frames and joints, a
    proper rotation always. NaN where a current vector is not finite or of zero length, and where
    the best rotation is not unique: its objective sum_k cur_k . R rest_k beats the next stationary
    rotation's by less than ``min_gap`` times the bone count (2 (s2 + d s3) in singular values)."""
    n = np.linalg.norm(cur, axis=-1, keepdims=True)
    pad = ~(np.abs(rest_dirs).sum(-1) > 0)                                 # [G, K]
    unit = cur / np.where(n > 0, n, 1.0)
    bad = ~(np.isfinite(unit).all(-1) & ((n[..., 0] > 1e-12) | pad)).all(-1)   # [F, G]
    unit = np.where(np.isfinite(unit), unit, 0.0)
    M = np.einsum("fgki,gkj->fgij", unit, rest_dirs)                        # sum over bones cur rest^T
    M = np.where(bad[..., None, None], np.eye(3), M)
    u, sv, vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    u[..., :, 2] *= d[..., None]
    out = u @ vt
    bad |= ~(2.0 * (sv[..., 1] + d * sv[..., 2]) >= min_gap * (~pad).sum(-1))
    out[bad] = np.nan
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _triad(primary: np.ndarray, secondary: np.ndarray) -> np.ndarray:
    """Orthonormal frames [..., 3, 3] (columns: primary, secondary made orthogonal, their cross)."""
    a = _unit(primary)
    b = secondary - np.sum(secondary * a, axis=-1, keepdims=True) * a
    b = _unit(b)
    return np.stack([a, b, np.cross(a, b)], axis=-1)


def _spanned(primary: np.ndarray, secondary: np.ndarray) -> np.ndarray:
    """[...] True where secondary's part orthogonal to primary is at least TRIAD_MIN_SIN of it."""
    a = _unit(primary)
    b = secondary - np.sum(secondary * a, axis=-1, keepdims=True) * a
    with np.errstate(invalid="ignore"):
        return np.linalg.norm(b, axis=-1) > TRIAD_MIN_SIN * np.linalg.norm(secondary, axis=-1)


def rotations_from_points(plan: PointRotationPlan, points: np.ndarray) -> np.ndarray:
    """World rotations [F, P, 4] of a positions-only source from its points [F, P, 3], identity
    in the rest pose: joints with three or more children (girdles) by the best fit over all their
    child bones (:func:`best_fit_rotations`, no bone favoured: a rigid girdle cannot match a shape
    that changes, so the residual is shared), two-child joints from their aim child and the span of
    the other (TRIAD: a limb's axis follows its main bone exactly), one-child joints by the shortest
    arc from the parent-carried rest direction (so no twist flips), leaves with their parent. NaN
    where a needed point is missing or the rotation is undetermined (TRIAD_MIN_SIN, FIT_MIN_GAP).
    The batch path and the reference of :func:`rotations_from_points_frame` (the live path's)."""
    p = np.asarray(points, dtype=np.float64)
    F, n = p.shape[0], p.shape[1]
    q = np.full((F, n, 4), np.nan)
    for level, (fit, g) in zip(plan.levels, plan.fit_levels):
        par = plan.parents[level]
        carried = np.where((par >= 0)[None, :, None], q[:, np.maximum(par, 0)], IDENTITY)
        out = carried.copy()
        prim = plan.primary[level]
        two = plan.secondary[level, 0] >= 0
        one = (prim >= 0) & ~two & ~fit
        if one.any():
            js = level[one]
            cur = p[:, prim[one]] - p[:, js]
            from_dir = quat_rotate(carried[:, one], plan.rest_primary[js])
            out[:, one] = quat_multiply(quat_between(from_dir, cur), carried[:, one])
        if two.any():
            js = level[two]
            sec = plan.secondary[js]
            a, b = p[:, prim[two]] - p[:, js], p[:, sec[:, 0]] - p[:, sec[:, 1]]
            cur = _triad(a, b)
            out[:, two] = matrix_to_quat(cur @ np.swapaxes(plan.rest_frames[js], -1, -2)[None])
            bad = ~np.isfinite(cur).all(axis=(-1, -2)) | ~_spanned(a, b)
            out[:, two] = np.where(bad[..., None], np.nan, out[:, two])
        if g.size:
            kids = plan.fit_kids[g]                                              # [G, K]
            cur = np.where((kids >= 0)[None, :, :, None], p[:, np.maximum(kids, 0)] - p[:, level[fit], None], 0.0)
            out[:, fit] = matrix_to_quat(best_fit_rotations(plan.fit_rest[g], cur))
        q[:, level] = out
    return q


def rotations_from_points_frame(plan: PointRotationPlan, points: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """One frame of :func:`rotations_from_points`: world rotations [P, 4] (wxyz) from points [P, 3]
    (m, world; NaN: missing) by the compiled kernel, the same to rounding. ``out``: a [P, 4]
    float64 array to fill (a new one if None)."""
    kern = _FRAME_KERNEL or _load_frame_kernel()
    p = np.ascontiguousarray(points, dtype=np.float64)    # one compiled layout (C) for every caller
    if out is None:
        out = np.empty((p.shape[0], 4))
    kern(p, plan.frame_index, plan.frame_rest, plan.fit_kids, plan.fit_rest, TRIAD_MIN_SIN, FIT_MIN_GAP, out)
    return out


_FRAME_KERNEL = None


def _load_frame_kernel():
    """The kernel, imported on first use (numba is no import-time cost of this module's other users)."""
    global _FRAME_KERNEL
    from .source_kernels import point_rotations
    _FRAME_KERNEL = point_rotations
    return point_rotations


def kinect_tpose(names, parents) -> np.ndarray:
    """A canonical T-pose [J, 3] (m, world) for Kinect v1/v2 joint names: a Kinect stream has no
    rest pose of its own, so its derived rotations are identity in this pose (arms along ±Y, palms
    down, legs straight down, facing +X). Proportions of standard_20 at 1.75 m."""
    from .character import standard_20
    s20 = standard_20(1.75)
    p20, _ = s20.rest_pose()
    v1 = {n: p20[i] for i, n in enumerate(s20.joint_names)}
    alias = {"SpineBase": "HipCenter", "SpineMid": "Spine", "SpineShoulder": "ShoulderCenter"}
    out = np.full((len(names), 3), np.nan)
    for i, n in enumerate(names):
        key = alias.get(n, n)
        if key in v1:
            out[i] = v1[key]
    for i, n in enumerate(names):
        if n == "Neck":
            out[i] = v1["ShoulderCenter"] + 0.35 * (v1["Head"] - v1["ShoulderCenter"])
        elif n.startswith("HandTip"):
            side = n[len("HandTip"):]
            out[i] = v1[f"Hand{side}"] + (0.0, 0.06 if side == "Left" else -0.06, 0.0)
        elif n.startswith("Thumb"):
            side = n[len("Thumb"):]
            out[i] = v1[f"Hand{side}"] + (0.04, 0.0, 0.0)
    missing = [names[i] for i in range(len(names)) if not np.isfinite(out[i]).all()]
    if missing:
        raise ValueError(f"no T-pose place for Kinect joints {', '.join(missing)}")
    return out


def kinect_source(names, parents, kind_hint: str = "", bone_lengths: np.ndarray | None = None) -> SourceSkeleton:
    """A positions-only Kinect source with the canonical T-pose (:func:`kinect_tpose`) as its rest:
    its bone directions, with the performer's observed ``bone_lengths`` [J] (m, to the parent;
    NaN or None keeps the canonical length) so that the leg-length ratio is the performer's."""
    rest = kinect_tpose(names, parents)
    par = np.asarray(parents, dtype=np.int64)
    offs = offsets_from_rest(rest, par)
    if bone_lengths is not None:
        L = np.asarray(bone_lengths, dtype=np.float64)
        n = np.linalg.norm(offs, axis=1)
        use = (par >= 0) & np.isfinite(L) & (L > 1e-3) & (n > 1e-9)
        offs[use] *= (L[use] / n[use])[:, None]
    src = skeleton_source(names, par, offs, has_orientations=False,
                          kind_hint=kind_hint or ("kinect_v2" if len(names) == 25 else "kinect_v1"))
    # The performer's T-pose stands on the floor: with shorter (or longer) legs than the canonical
    # pose the root comes down (up) by the difference, else the standing root height the retargeter
    # scales from is the canonical one (a 1.37 m performer's feet came out 21 cm under the floor).
    root = np.flatnonzero(par < 0)
    offs[root, 2] -= float(np.nanmin(src.rest_points[:, 2]) - np.nanmin(rest[:, 2]))
    return skeleton_source(names, par, offs, has_orientations=False,
                           kind_hint=kind_hint or ("kinect_v2" if len(names) == 25 else "kinect_v1"))


def character_from_actor(joint_names, joint_parent, base_joints, name: str = "actor"):
    """A character with an optical actor's skeleton: root ``pelvis`` (mid-hips) and the actor's
    joints, rest offsets from the base pose (a T-pose), identity rest rotations."""
    from .character import Character
    src = optical_source(joint_names, joint_parent, np.zeros((len(joint_names), 2), int), ("lower_torso",), base_joints)
    names = src.point_names
    n = len(names)
    parents = np.where(src.point_parents < 0, n - 1, src.point_parents)
    parents[n - 1] = -1
    order = [n - 1] + [j for j in _topological(parents) if j != n - 1]
    remap = {old: new for new, old in enumerate(order)}
    par = np.array([-1 if parents[o] < 0 else remap[int(parents[o])] for o in order])
    rest = src.rest_points[order]
    offs = offsets_from_rest(rest, par)
    return Character(name, tuple(names[o] for o in order), par, offs, np.tile(IDENTITY, (n, 1)))
