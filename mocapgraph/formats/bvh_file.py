"""BVH (Biovision hierarchy) motion files: :func:`read_bvh`, :func:`write_bvh`,
:meth:`BvhMotion.forward_kinematics`, :func:`bvh_to_skeleton`.

:class:`BvhMotion` keeps the file as it is (offsets in file units, raw channel values in
degrees and file units, BVH axes) so :func:`write_bvh` round-trips exactly; conversion to the
world frame happens in :meth:`BvhMotion.forward_kinematics`:

* Axes: BVH is Y up; characters face +Z with their left along +X (CMU, Mixamo). World is
  Z up, X forward, Y left, so world = A @ bvh with A mapping (x, y, z)_bvh -> (z, x, y).
  Joint orientations are conjugated the same way (A R A^T), so in the rest pose (all
  rotation channels 0) every joint frame has the identity orientation in the world.
* Units: ``scale`` metres per file unit. When not given, it is guessed from the rest-pose
  height of the skeleton (head-top end site to toe along the up axis): among metres, cm,
  mm, inches and CMU units (0.056444 m, the CMU database's "(1/0.45) * 2.54 / 100"), the
  one giving a height closest to 1.7 m wins. Pass ``scale`` for anything not a standing
  human. The choice is written in ``motion.conversions``.
* Rotations: a joint's rotation channels, in file order, are intrinsic rotations:
  "Zrotation Xrotation Yrotation" is R = Rz @ Rx @ Ry, i.e. scipy's ``from_euler("ZXY")``.
  Any order per joint is allowed (CMU mixes ZYX and ZXY).
* Offsets and position channels (the rule of Blender's importer and MotionBuilder): a joint's
  OFFSET is its rest position in the parent frame; a position channel is that coordinate's
  absolute value in the parent frame, so it REPLACES the offset's component (it is not added
  to it). A root with OFFSET 0 90 0 and Yposition 90 stands at 90, not 180; the rest pose
  (:meth:`BvhMotion.rest_positions`) keeps every offset. Axes without a position channel keep
  the offset's component.
* End sites are joints without channels, named ``<parent>_End`` (``is_end_site`` marks them).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import FormatError
from .skeleton_trial import TRACKED, SkeletonTrial

# world = BVH_TO_WORLD @ bvh: (x, y, z)_bvh -> (z, x, y)
BVH_TO_WORLD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
UNIT_CANDIDATES: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254,
                                     "CMU units": (1.0 / 0.45) * 2.54 / 100.0}
HUMAN_HEIGHT_M = 1.7
# bounds on what a BVH may declare (a flipped digit or a hostile file must not size the arrays):
# the richest rigs (faces and fingers) have a few hundred joints
MAX_JOINTS = 4096
MAX_HIERARCHY_CHARS = 8 << 20  # 2 KB per joint at MAX_JOINTS: room for deep tab indentation
MAX_FRAME_TIME_S = 3600.0  # an hour per frame; above this no motion is meant
_CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")


@dataclass
class BvhMotion:
    """A BVH file as read: hierarchy plus raw channel values.

    names: [J] joint names in file order (parents first), end sites included.
    parents: int [J], -1 for the root.
    offsets: float64 [J, 3] file units, BVH axes (Y up).
    channels: [J] list of channel names per joint (e.g. ["Zrotation", "Xrotation",
        "Yrotation"]); empty for end sites.
    is_end_site: bool [J].
    frame_time_s: seconds per frame.
    values: float64 [T, C] raw channel values (degrees, file units), joints' channels in file
        order.
    scale: metres per file unit (given or guessed; see module doc).
    """

    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    channels: list[list[str]]
    is_end_site: np.ndarray
    frame_time_s: float
    values: np.ndarray
    scale: float = 1.0
    source: str = ""
    conversions: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.parents = np.asarray(self.parents, dtype=np.int64)
        self.offsets = np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3)
        self.is_end_site = np.asarray(self.is_end_site, dtype=bool)
        self.values = np.asarray(self.values, dtype=np.float64).reshape(-1, self.n_channels)
        starts = np.cumsum([0] + [len(c) for c in self.channels])
        self.channel_start = starts[:-1]  # first column of each joint's channels in values

    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def n_frames(self) -> int:
        return int(self.values.shape[0])

    @property
    def n_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    @property
    def rate_hz(self) -> float:
        """Frames per second; snapped to a whole number when Frame Time is a rounded
        1/integer (".0083333" -> 120)."""
        r = 1.0 / self.frame_time_s
        return float(round(r)) if abs(r - round(r)) < 1e-4 * r else r

    def index(self, name: str) -> int:
        return self.names.index(name)

    def rotation_orders(self) -> list[str]:
        """Per joint the intrinsic Euler order of its rotation channels ("ZXY"...; "" if none)."""
        return ["".join(c[0] for c in ch if c.endswith("rotation")) for ch in self.channels]

    def forward_kinematics(self, frames: slice | np.ndarray | None = None,
                           values: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World joint positions [T, J, 3] (metres) and orientations [T, J, 4] (w, x, y, z).

        World frame: Z up, X forward (the character's rest-pose facing), Y left. Position
        channels replace offset components (module doc). ``values`` [T, C] replaces the file's
        channel values (e.g. a rest pose). Vectorised over frames; the Python loop runs over
        joints only.
        """
        if values is None:
            vals = self.values if frames is None else self.values[frames]
        else:
            vals = np.asarray(values, dtype=np.float64).reshape(-1, self.n_channels)
        T, J = vals.shape[0], self.n_joints
        Rg = np.empty((T, J, 3, 3))
        pg = np.empty((T, J, 3))
        orders = self.rotation_orders()
        rot_cols = [[self.channel_start[j] + k for k, c in enumerate(self.channels[j])
                     if c.endswith("rotation")] for j in range(J)]
        # one scipy call per distinct rotation order, batched over joints and frames
        local_R = np.broadcast_to(np.eye(3), (J, T, 3, 3)).copy()
        for order in set(orders) - {""}:
            js = [j for j in range(J) if orders[j] == order]
            ang = vals[:, [c for j in js for c in rot_cols[j]]].reshape(T, len(js), len(order))
            mats = Rotation.from_euler(order, ang.transpose(1, 0, 2).reshape(-1, len(order)),
                                       degrees=True).as_matrix()
            local_R[js] = mats.reshape(len(js), T, 3, 3)
        for j in range(J):
            ch = self.channels[j]
            c0 = self.channel_start[j]
            local_t = np.broadcast_to(self.offsets[j], (T, 3)).copy()
            for k, name in enumerate(ch):
                if name.endswith("position"):
                    local_t[:, "XYZ".index(name[0])] = vals[:, c0 + k]
            R = local_R[j]
            p = self.parents[j]
            if p < 0:
                Rg[:, j] = R
                pg[:, j] = local_t
            else:
                Rg[:, j] = Rg[:, p] @ R
                pg[:, j] = pg[:, p] + np.einsum("tij,tj->ti", Rg[:, p], local_t)
        A = BVH_TO_WORLD
        pos = np.einsum("ij,tkj->tki", A * self.scale, pg)
        Rw = A @ Rg @ A.T
        # products of rotation matrices: valid by construction, no SVD projection needed
        quat = Rotation.from_matrix(Rw.reshape(-1, 3, 3), assume_valid=True).as_quat(scalar_first=True)
        return pos, quat.reshape(T, J, 4)

    def rest_values(self) -> np.ndarray:
        """[C] channel values of the rest pose: rotations 0, positions equal to the offsets."""
        rest = np.zeros(self.n_channels)
        for j, ch in enumerate(self.channels):
            for k, name in enumerate(ch):
                if name.endswith("position"):
                    rest[self.channel_start[j] + k] = self.offsets[j, "XYZ".index(name[0])]
        return rest

    def rest_positions(self) -> np.ndarray:
        """[J, 3] world positions (metres) of the rest pose (every offset, no rotation)."""
        return self.forward_kinematics(values=self.rest_values()[None])[0][0]


def guess_scale(offsets: np.ndarray, parents: np.ndarray) -> tuple[float, str, float]:
    """(metres per unit, unit name, rest height in file units) from the rest-pose height."""
    J = len(parents)
    pos = np.zeros((J, 3))
    for j in range(J):
        pos[j] = offsets[j] + (pos[parents[j]] if parents[j] >= 0 else 0.0)
    height = float(np.ptp(pos[:, 1])) if J else 0.0
    if height <= 0:
        return 1.0, "m", height
    best = min(UNIT_CANDIDATES.items(),
               key=lambda kv: abs(math.log(height * kv[1] / HUMAN_HEIGHT_M)))
    return best[1], best[0], height


def _read_motion(path: Path, motion: str, C: int) -> tuple[np.ndarray, float, list[str]]:
    """(values [T, C], frame time s, notes) of the text after MOTION; FormatError when broken."""
    lines = motion.strip().splitlines()
    try:
        n_frames = int(lines[0].split(":")[1])
        frame_time = float(lines[1].split(":")[1])
    except (IndexError, ValueError):
        raise FormatError(path, "BVH motion header is broken (expected 'Frames:' and "
                                "'Frame Time:')") from None
    if not (0 < frame_time <= MAX_FRAME_TIME_S):  # NaN fails too
        raise FormatError(path, f"BVH Frame Time {frame_time} is not a positive number of seconds "
                                f"(at most {MAX_FRAME_TIME_S:g})")
    if n_frames < 0:
        raise FormatError(path, f"BVH declares {n_frames} frames")
    try:
        flat = np.array(" ".join(lines[2:]).split(), dtype=np.float64)
    except ValueError as e:
        raise FormatError(path, f"BVH motion data is not numeric ({e})") from None
    if C == 0 or flat.size % C:
        raise FormatError(path, f"BVH motion data holds {flat.size} values, not a multiple of "
                                f"the {C} channels")
    vals = flat.reshape(-1, C)
    bad = ~np.isfinite(vals)
    if bad.any():
        t, c = np.argwhere(bad)[0]
        raise FormatError(path, f"BVH motion data holds {int(bad.sum())} non-finite values (first: frame "
                                f"{t}, channel {c} = {vals[t, c]})")
    notes: list[str] = []
    if vals.shape[0] < n_frames:
        raise FormatError(path, f"BVH is truncated: declares {n_frames} frames, holds "
                                f"{vals.shape[0]}")
    if vals.shape[0] > n_frames:
        notes.append(f"declares {n_frames} frames but holds {vals.shape[0]}; kept all")
    return vals, frame_time, notes


def _read_text(path: Path) -> str:
    """The whole file as text (bad UTF-8 bytes replaced); FormatError when it cannot be read."""
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise FormatError(path, f"cannot read file ({e.strerror or e})") from None


def _hierarchy_tokens(path: Path, text: str) -> tuple[list[str], str]:
    """(tokens of the HIERARCHY block, text after MOTION); FormatError when either is missing."""
    head, sep, motion = text.partition("MOTION")
    if not sep:
        raise FormatError(path, "BVH has no MOTION section")
    if len(head) > MAX_HIERARCHY_CHARS:  # checked before tokenising: a token list costs ~10x the text
        raise FormatError(path, f"BVH hierarchy is {len(head) / 2**20:.0f} MB of text, more than any skeleton "
                                f"(at most {MAX_JOINTS} joints, {MAX_HIERARCHY_CHARS >> 20} MB)")
    tok = head.split()
    if not tok or tok[0] != "HIERARCHY":
        raise FormatError(path, "not a BVH file (does not start with HIERARCHY)")
    return tok, motion


@dataclass
class _Hierarchy:
    """The joints of a HIERARCHY block in file order: offsets in file units, BVH axes."""

    names: list[str] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    offsets: list[list[float]] = field(default_factory=list)
    channels: list[list[str]] = field(default_factory=list)
    end_site: list[bool] = field(default_factory=list)

    @property
    def n_channels(self) -> int:
        return sum(len(c) for c in self.channels)


class _HierarchyParser:
    """Walks the HIERARCHY tokens once into a :class:`_Hierarchy`; FormatError when broken."""

    def __init__(self, path: Path, tok: list[str]) -> None:
        self.path = path
        self.tok = tok
        self.joints = _Hierarchy()
        self.stack: list[int] = []      # joints whose "{" is open, innermost last
        self.pending: int | None = None  # joint whose "{" is expected
        self.i = 1                       # next token; tok[0] is "HIERARCHY"

    def fail(self, msg: str) -> FormatError:
        return FormatError(self.path, f"BVH hierarchy is broken ({msg})")

    def parse(self) -> _Hierarchy:
        """The joints read, checked to form one tree with unique names."""
        try:
            while self.i < len(self.tok):
                self._step(self.tok[self.i])
        except (IndexError, ValueError) as e:  # a keyword cut short or a word where a number belongs
            raise self.fail(f"near token {self.i}: {e}") from None
        self._check_tree()
        return self.joints

    def _step(self, t: str) -> None:
        """Consume the keyword ``t`` at token ``self.i`` and its arguments."""
        if t in ("ROOT", "JOINT") or (t == "End" and self.tok[self.i + 1] == "Site"):
            self._add_joint(t)
        elif t == "{":
            self._open_brace()
        elif t == "}":
            self._close_brace()
        elif t == "OFFSET":
            self._read_offset()
        elif t == "CHANNELS":
            self._read_channels()
        else:
            raise self.fail(f"unexpected token {t!r}")

    def _add_joint(self, t: str) -> None:
        """A ROOT, JOINT or End Site: a new joint under the open one, awaiting its "{"."""
        j, stack = self.joints, self.stack
        if t == "End":
            if not stack:
                raise self.fail("End Site outside a joint")
            name = j.names[stack[-1]] + "_End"
        else:
            name = self.tok[self.i + 1]
            if t == "JOINT" and not stack:
                raise self.fail(f"JOINT {name} outside the root")
        self.i += 2
        if len(j.names) >= MAX_JOINTS:
            raise self.fail(f"more than {MAX_JOINTS} joints")
        j.names.append(name)
        j.parents.append(stack[-1] if stack else -1)
        j.offsets.append([0.0, 0.0, 0.0])
        j.channels.append([])
        j.end_site.append(t == "End")
        self.pending = len(j.names) - 1

    def _open_brace(self) -> None:
        if self.pending is None:
            raise self.fail("'{' without a joint")
        self.stack.append(self.pending)
        self.pending = None
        self.i += 1

    def _close_brace(self) -> None:
        if not self.stack:
            raise self.fail("unbalanced '}'")
        self.stack.pop()
        self.i += 1

    def _read_offset(self) -> None:
        """OFFSET x y z of the open joint (file units, parent frame)."""
        args = self.tok[self.i + 1:self.i + 4]
        off = [float(x) for x in args]
        if len(off) != 3 or not all(math.isfinite(v) for v in off):
            raise self.fail(f"joint {self.joints.names[self.stack[-1]]} has OFFSET {' '.join(args)}, "
                            "not three finite numbers")
        self.joints.offsets[self.stack[-1]] = off  # IndexError outside a joint
        self.i += 4

    def _read_channels(self) -> None:
        """CHANNELS n name... of the open joint, each one of the six BVH channel names."""
        n = int(self.tok[self.i + 1])
        ch = self.tok[self.i + 2:self.i + 2 + n]
        bad = [c for c in ch if c not in _CHANNELS]
        if bad or len(ch) != n:
            raise self.fail(f"joint {self.joints.names[self.stack[-1]]} has bad channels {bad or ch}")
        self.joints.channels[self.stack[-1]] = ch  # IndexError outside a joint
        self.i += 2 + n

    def _check_tree(self) -> None:
        """Braces closed, exactly one ROOT, no joint name twice."""
        names = self.joints.names
        if self.stack or not names:
            raise self.fail("unbalanced braces" if self.stack else "no joints")
        if len([p for p in self.joints.parents if p < 0]) != 1:
            raise self.fail("more than one ROOT")
        seen: dict[str, int] = {}
        for k, nm in enumerate(names):
            if nm in seen:  # joints are looked up by name (retarget maps, skeleton_info): refuse
                raise self.fail(f"joint name {nm!r} is used twice (joints {seen[nm]} and {k})")
            seen[nm] = k


def _unit_conversions(offsets: np.ndarray, parents: np.ndarray,
                      scale: float | None) -> tuple[float, list[str]]:
    """(metres per file unit, the conversions to note): ``scale`` if given, else guessed."""
    conversions: list[str] = []
    if scale is None:
        scale, unit, height = guess_scale(offsets, parents)
        conversions.append(f"units {unit} -> m (guessed from the rest-pose height "
                           f"{height:.4g} units = {height * scale:.2f} m; pass scale= to override)")
    else:
        conversions.append(f"units -> m with scale {scale:g} m per unit (given)")
    conversions.append("Y-up, +Z-facing BVH -> Z-up, X-forward world "
                       "(x, y, z)_bvh -> (z, x, y); orientations conjugated likewise")
    return float(scale), conversions


def read_bvh(path: str | Path, *, scale: float | None = None) -> BvhMotion:
    """Parse a BVH file. ``scale``: metres per file unit (None = guess, see module doc).

    Raises FormatError (one line naming the file) for a broken hierarchy or motion block.
    """
    path = Path(path)
    tok, motion = _hierarchy_tokens(path, _read_text(path))
    joints = _HierarchyParser(path, tok).parse()
    vals, frame_time, notes = _read_motion(path, motion, joints.n_channels)
    off = np.array(joints.offsets)
    par = np.array(joints.parents)
    scale, conversions = _unit_conversions(off, par, scale)
    return BvhMotion(joints.names, par, off, joints.channels, np.array(joints.end_site), frame_time,
                     vals, scale, str(path), conversions, notes)


def write_bvh(path: str | Path, motion: BvhMotion, *, decimals: int = 6) -> None:
    """Write ``motion`` back as BVH (file units and axes as held; exact to ``decimals``)."""
    path = Path(path)
    out = ["HIERARCHY"]
    J = motion.n_joints
    children: list[list[int]] = [[] for _ in range(J)]
    for j in range(J):
        if motion.parents[j] >= 0:
            children[motion.parents[j]].append(j)
    fmt = f"{{:.{decimals}f}}"

    walked: list[int] = []

    def emit(j: int, depth: int) -> None:
        walked.append(j)
        ind = "\t" * depth
        if motion.is_end_site[j]:
            out.append(f"{ind}End Site")
        elif motion.parents[j] < 0:
            out.append(f"{ind}ROOT {motion.names[j]}")
        else:
            out.append(f"{ind}JOINT {motion.names[j]}")
        out.append(f"{ind}{{")
        out.append(f"{ind}\tOFFSET " + " ".join(fmt.format(v) for v in motion.offsets[j]))
        if not motion.is_end_site[j]:
            ch = motion.channels[j]
            out.append(f"{ind}\tCHANNELS {len(ch)} " + " ".join(ch))
        for c in children[j]:
            emit(c, depth + 1)
        out.append(f"{ind}}}")

    root = int(np.flatnonzero(motion.parents < 0)[0])
    emit(root, 0)
    out += ["MOTION", f"Frames: {motion.n_frames}", f"Frame Time: {motion.frame_time_s:.7f}"]
    # a BVH's columns follow the depth-first walk, which may differ from the joint order held
    cols = np.concatenate([np.arange(motion.channel_start[j], motion.channel_start[j]
                                     + len(motion.channels[j])) for j in walked]).astype(int)
    out += [" ".join(fmt.format(v) for v in row) for row in motion.values[:, cols].tolist()]
    try:
        path.write_text("\n".join(out) + "\n", encoding="utf-8")
    except OSError as e:
        raise FormatError(path, f"cannot write file ({e.strerror or e})") from None


def bvh_to_skeleton(motion: BvhMotion, *, include_end_sites: bool = True,
                    start_ns: int = 0) -> SkeletonTrial:
    """A :class:`SkeletonTrial` (world positions, orientations) from a BVH motion.

    Time stamps are ``start_ns`` + frame index / ``motion.rate_hz``.
    """
    pos, quat = motion.forward_kinematics()
    keep = np.arange(motion.n_joints) if include_end_sites else np.flatnonzero(~motion.is_end_site)
    remap = -np.ones(motion.n_joints, dtype=np.int64)
    remap[keep] = np.arange(len(keep))
    parents = np.array([remap[motion.parents[j]] if motion.parents[j] >= 0 else -1 for j in keep])
    T = motion.n_frames
    ts = start_ns + np.round(np.arange(T) * (1e9 / motion.rate_hz)).astype(np.int64)
    return SkeletonTrial(
        names=[motion.names[j] for j in keep], parents=parents,
        positions=pos[:, keep], orientations=quat[:, keep],
        tracking_state=np.full((T, len(keep)), TRACKED, dtype=np.int8),
        timestamps_ns=ts, rate_hz=motion.rate_hz, source=motion.source,
        conversions=list(motion.conversions), notes=list(motion.notes),
        extra={"is_end_site": motion.is_end_site[keep]},
    )
