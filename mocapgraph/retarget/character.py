"""A character: a joint hierarchy with rest offsets and rest orientations, and its forward kinematics.

Conventions (DESIGN.md, "Characters, retargeting, physics"):

* ``parents[j]`` is the parent joint of ``j`` (-1 for the root); parents come before children.
* ``rest_offsets[j]`` is joint ``j``'s position relative to its parent joint, metres, in the
  parent joint's frame; the root's is its rest position in the world (Z up, X forward, Y left).
* ``rest_rotations[j]`` is joint ``j``'s rest orientation relative to its parent's frame, wxyz
  (the root's: relative to the world). Characters read from BVH have identity rest rotations.
* ``local_rotations[j]`` (what ``CharacterPose`` carries) is the rotation of joint ``j`` relative to
  its rest orientation, so the joint's world orientation is ``W[parent] · rest[j] · local[j]`` and
  its world position ``P[parent] + W[parent] · rest_offsets[j]``. All-identity local rotations give
  the rest pose.

Forward kinematics is batched over frames and vectorised per depth level of the hierarchy (a
loop over the few levels, never over joints).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..kinematics.quaternion import matrix_to_quat, quat_to_matrix

IDENTITY_WXYZ = np.array([1.0, 0.0, 0.0, 0.0])


#: largest rest offset component a character may have, m (a bone, or the root's place in the room)
MAX_OFFSET_M = 1000.0


def checked_shift(value: object, what: str = "offset") -> np.ndarray:
    """A world shift [x, y, z], m: finite and within MAX_OFFSET_M, else CharacterError (one line)."""
    try:
        v = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.isfinite(v).all() or np.abs(v).max() > MAX_OFFSET_M:
        raise CharacterError(f"{what} wants [x, y, z] in metres, finite and within {MAX_OFFSET_M:g} m, "
                             f"got {str(value)[:80]}")
    return v


class CharacterError(ValueError):
    """A character definition that cannot be used (message names the joint and the fault)."""


@dataclass(frozen=True, eq=False)
class Character:
    """A joint hierarchy (see the module docstring for frames and units)."""

    name: str
    joint_names: tuple[str, ...]
    parents: np.ndarray          # int64 [J]
    rest_offsets: np.ndarray     # float64 [J, 3], m, parent frame (root: world)
    rest_rotations: np.ndarray   # float64 [J, 4], wxyz, parent frame (root: world)
    end_sites: np.ndarray = field(default=None)  # bool [J]: leaf markers with no rotation of their own
    # BVH rigs may stack joints at one place (CMU's LHipJoint sits on Hips); hand-written files may not
    allow_zero_bones: bool = False

    def __post_init__(self) -> None:
        names = tuple(self.joint_names)
        n = len(names)
        parents = np.asarray(self.parents, dtype=np.int64).reshape(-1)
        offsets = np.asarray(self.rest_offsets, dtype=np.float64).reshape(-1, 3)
        rest = np.asarray(self.rest_rotations, dtype=np.float64).reshape(-1, 4)
        ends = (np.zeros(n, dtype=bool) if self.end_sites is None
                else np.asarray(self.end_sites, dtype=bool).reshape(-1))
        validate_hierarchy(names, parents, offsets, rest, allow_zero_bones=self.allow_zero_bones)
        if ends.shape != (n,):
            raise CharacterError(f"end_sites: {ends.shape[0]} flags for {n} joints")
        for attr, value in (("joint_names", names), ("parents", parents), ("rest_offsets", offsets),
                            ("rest_rotations", rest / np.linalg.norm(rest, axis=1, keepdims=True)),
                            ("end_sites", ends)):
            object.__setattr__(self, attr, value)
        depth = np.zeros(n, dtype=np.int64)
        for j in range(1, n):  # one pass at construction; parents precede children
            if parents[j] >= 0:
                depth[j] = depth[parents[j]] + 1
        levels = tuple(np.flatnonzero(depth == d) for d in range(int(depth.max(initial=0)) + 1))
        object.__setattr__(self, "_levels", levels)
        object.__setattr__(self, "_rest_matrices", quat_to_matrix(self.rest_rotations))

    # ----- structure ---------------------------------------------------------------------------
    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def root(self) -> int:
        return int(np.flatnonzero(self.parents < 0)[0])

    def index(self, name: str) -> int:
        """Joint index by name (``KeyError`` naming the close matches otherwise)."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            import difflib
            close = difflib.get_close_matches(name, self.joint_names, n=3)
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            raise KeyError(f"character {self.name!r} has no joint {name!r}{hint}") from None

    def children(self, j: int) -> np.ndarray:
        return np.flatnonzero(self.parents == j)

    @property
    def bone_lengths(self) -> np.ndarray:
        """Distance from each joint to its parent at rest, m; NaN for roots. [J]"""
        lengths = np.linalg.norm(self.rest_offsets, axis=1)
        lengths[self.parents < 0] = np.nan
        return lengths

    def chain(self, j: int) -> list[int]:
        """Joint indices from the root down to ``j`` (inclusive)."""
        out = [j]
        while self.parents[out[-1]] >= 0:
            out.append(int(self.parents[out[-1]]))
        return out[::-1]

    # ----- kinematics --------------------------------------------------------------------------
    def forward_kinematics(self, local_rotations: np.ndarray | None = None,
                           root_positions: np.ndarray | None = None,
                           *, as_matrices: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """World joint positions and orientations from local rotations.

        local_rotations: [F, J, 4] or [J, 4] wxyz relative to the rest orientation (None: rest).
        root_positions: [F, 3] or [3] world position of the root, m (None: its rest offset).
        Returns (positions [F, J, 3] m, orientations [F, J, 4] wxyz, or [F, J, 3, 3] matrices
        with ``as_matrices``), without the F axis when the inputs had none.
        """
        single = local_rotations is not None and np.ndim(local_rotations) == 2
        n = self.n_joints
        if local_rotations is None:
            frames = 1 if root_positions is None or np.ndim(root_positions) == 1 else len(root_positions)
            local_m = np.broadcast_to(np.eye(3), (frames, n, 3, 3))
            single = root_positions is None or np.ndim(root_positions) == 1
        else:
            q = np.asarray(local_rotations, dtype=np.float64).reshape(-1, n, 4)
            frames = q.shape[0]
            local_m = quat_to_matrix(q)
        if root_positions is None:
            root_p = np.broadcast_to(self.rest_offsets[self.parents < 0], (frames, int((self.parents < 0).sum()), 3))
        else:
            root_p = np.asarray(root_positions, dtype=np.float64).reshape(frames, -1, 3)
        joint_m = self._rest_matrices[None] @ local_m  # rest · local, [F, J, 3, 3]
        world_m = np.empty((frames, n, 3, 3))
        world_p = np.empty((frames, n, 3))
        roots = self._levels[0]
        world_m[:, roots] = joint_m[:, roots]
        world_p[:, roots] = root_p
        for level in self._levels[1:]:
            par = self.parents[level]
            world_m[:, level] = world_m[:, par] @ joint_m[:, level]
            world_p[:, level] = world_p[:, par] + (world_m[:, par] @ self.rest_offsets[level][:, :, None])[..., 0]
        if as_matrices:
            orient = world_m
        else:
            orient = matrix_to_quat(world_m)
        if single:
            return world_p[0], orient[0]
        return world_p, orient

    def rest_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World positions [J, 3] (m) and orientations [J, 4] (wxyz) in the rest pose."""
        return self.forward_kinematics()

    def scaled(self, factor: float, name: str | None = None) -> "Character":
        """The same hierarchy with every offset (root position included) times ``factor``."""
        if not np.isfinite(factor) or factor <= 0:
            raise CharacterError(f"scale: {factor} is not a positive finite number")
        return Character(name or self.name, self.joint_names, self.parents, self.rest_offsets * factor,
                         self.rest_rotations, self.end_sites, self.allow_zero_bones)


def validate_hierarchy(names: tuple[str, ...], parents: np.ndarray, offsets: np.ndarray,
                       rest_rotations: np.ndarray, *, allow_zero_bones: bool = False) -> None:
    """Raise :class:`CharacterError` naming the joint at fault: duplicates, unknown or later
    parents (a cycle), zero-length bones, non-finite or non-unit data."""
    n = len(names)
    if n == 0:
        raise CharacterError("a character needs at least one joint")
    if len(set(names)) != n:
        dup = sorted({x for x in names if names.count(x) > 1})
        raise CharacterError(f"joint names repeat: {', '.join(dup)}")
    if parents.shape != (n,) or offsets.shape != (n, 3) or rest_rotations.shape != (n, 4):
        raise CharacterError(f"{n} joints but {parents.shape[0]} parents, {offsets.shape[0]} offsets, "
                             f"{rest_rotations.shape[0]} rest rotations")
    for j in range(n):
        p = int(parents[j])
        if p >= n or p < -1:
            raise CharacterError(f"joint {names[j]!r}: parent index {p} is not a joint")
        if p >= j:
            raise CharacterError(f"joint {names[j]!r}: parent {names[p]!r} does not come before it "
                                 "(a cycle, or joints out of order)")
    if (parents < 0).sum() != 1:
        roots = [names[j] for j in np.flatnonzero(parents < 0)]
        raise CharacterError(f"a character needs exactly one root joint, found {len(roots)}: {', '.join(roots)}")
    bad = np.flatnonzero(~np.isfinite(offsets).all(axis=1))
    if bad.size:
        raise CharacterError(f"joint {names[bad[0]]!r}: rest offset is not finite")
    far = np.flatnonzero(np.abs(offsets).max(axis=1) > MAX_OFFSET_M)
    if far.size:   # finite but absurd (1e300): physics and drawing would fail far from here
        raise CharacterError(f"joint {names[far[0]]!r}: rest offset {np.abs(offsets[far[0]]).max():.3g} m is "
                             f"beyond {MAX_OFFSET_M:g} m (not a body; wrong units?)")
    short = np.flatnonzero((np.linalg.norm(offsets, axis=1) < 1e-6) & (parents >= 0))
    if short.size and not allow_zero_bones:
        raise CharacterError(f"joint {names[short[0]]!r}: zero-length bone to {names[parents[short[0]]]!r}")
    norms = np.linalg.norm(rest_rotations, axis=1)
    bad = np.flatnonzero(~np.isfinite(norms) | (np.abs(norms - 1.0) > 1e-6))
    if bad.size:
        raise CharacterError(f"joint {names[bad[0]]!r}: rest rotation is not a unit quaternion "
                             f"(norm {norms[bad[0]]:.6g})")


# ----- the Kinect-like character of Shum & Ho, section 4 ---------------------------------------
# Kinect v1 joint names; 19 segments between 20 joints. Proportions as fractions of standing
# height H (Drillis & Contini 1966 as tabulated by Winter, "Biomechanics and Motor Control of Human
# Movement", Fig. 4.1): hip 0.530 H, knee 0.285 H, ankle 0.039 H, shoulder 0.818 H, chin 0.870 H,
# shoulder width 0.259 H, upper arm 0.186 H, forearm 0.146 H, foot length 0.152 H. Joint places
# Winter does not give (spine, head centre, hand centre) are our choice, noted.
# The girdles take Kinect v2's shape (Shum & Ho's character is Kinect-like; a rigid girdle of another
# shape cannot follow the Kinect's bones): measured by benchmarks/kinect_girdle.py over the five
# ../shared/data/kinect2 recordings (all joints Tracked, 890 frames; H from the leg length), mean,
# left/right symmetrised. Pelvis frame (up SpineBase->SpineMid, left along the hip line): the hip
# joints 0.0246 H in front of SpineBase, 0.0557 H to the side, 0.0042 H above it (anatomically too
# the hip joints lie in front of the lumbo-sacral joint). Chest frame (up SpineShoulder->Head): the
# shoulders 0.0135 H in front of SpineShoulder and 0.0231 H below it, laterally 0.1267 H (Winter's
# 0.1295 H is kept, the direction scaled to it). Heights from Winter kept: hip joints 0.530 H,
# shoulders 0.818 H (so ShoulderCenter sits at 0.8416 H), head centre 0.930 H.
STANDARD_20_JOINTS: tuple[tuple[str, str | None, tuple[float, float, float]], ...] = (
    # name, parent, offset from the parent as a fraction of H (world axes: X forward, Y left, Z up)
    ("HipCenter", None, (0.0, 0.0, 0.5258)),       # Kinect's SpineBase: 0.0042 H below the hip joints
    ("Spine", "HipCenter", (0.0, 0.0, 0.1342)),   # lumbar at 0.660 H, our choice
    ("ShoulderCenter", "Spine", (0.0, 0.0, 0.1816)),  # 0.8416 H: 0.0236 H above the shoulders (Kinect)
    ("Head", "ShoulderCenter", (0.0, 0.0, 0.0884)),  # head centre 0.930 H, our choice
    ("ShoulderLeft", "ShoulderCenter", (0.0138, 0.1295, -0.0236)),   # Kinect v2's direction, Winter's width
    ("ElbowLeft", "ShoulderLeft", (0.0, 0.186, 0.0)),    # T-pose: arms along +-Y
    ("WristLeft", "ElbowLeft", (0.0, 0.146, 0.0)),
    ("HandLeft", "WristLeft", (0.0, 0.054, 0.0)),        # hand centre, half of 0.108 H
    ("ShoulderRight", "ShoulderCenter", (0.0138, -0.1295, -0.0236)),
    ("ElbowRight", "ShoulderRight", (0.0, -0.186, 0.0)),
    ("WristRight", "ElbowRight", (0.0, -0.146, 0.0)),
    ("HandRight", "WristRight", (0.0, -0.054, 0.0)),
    ("HipLeft", "HipCenter", (0.0246, 0.0557, 0.0042)),  # Kinect v2's pelvis shape (see above)
    ("KneeLeft", "HipLeft", (0.0, 0.0, -0.245)),
    ("AnkleLeft", "KneeLeft", (0.0, 0.0, -0.246)),
    ("FootLeft", "AnkleLeft", (0.100, 0.0, -0.030)),     # ball of the foot, near the floor
    ("HipRight", "HipCenter", (0.0246, -0.0557, 0.0042)),
    ("KneeRight", "HipRight", (0.0, 0.0, -0.245)),
    ("AnkleRight", "KneeRight", (0.0, 0.0, -0.246)),
    ("FootRight", "AnkleRight", (0.100, 0.0, -0.030)),
)


def standard_20(height_m: float = 1.75, name: str = "standard_20") -> Character:
    """Shum & Ho's 20-joint Kinect-like character (T-pose, identity rest rotations) of a height."""
    if not np.isfinite(height_m) or not 0.3 <= height_m <= 3.0:
        raise CharacterError(f"height: {height_m} m is not a plausible standing height (0.3-3 m)")
    names = tuple(j[0] for j in STANDARD_20_JOINTS)
    parents = np.array([-1 if p is None else names.index(p) for _, p, _ in STANDARD_20_JOINTS])
    offsets = np.array([o for _, _, o in STANDARD_20_JOINTS]) * height_m
    rest = np.tile(IDENTITY_WXYZ, (len(names), 1))
    return Character(name, names, parents, offsets, rest)
