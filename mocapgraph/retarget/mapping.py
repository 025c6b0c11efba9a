"""A retargeting mapping: which source rotation and point drive each character joint, with Claro's A, R, D.

For a character joint driven by the source rotation Q_k (a world orientation, see
:mod:`source`) Claro's Eq 4.1 gives its world rotation from the character's rest pose

    Q_r = A · Q_k · D · R⁻¹ · A⁻¹,   world orientation = Q_r · (rest world orientation)

* A (alignment): the rotation taking the source's world axes (its rest facing) onto the
  character's; derived as the heading difference of the two rest poses (hips, then shoulders).
* R (rest-pose correction): the value Q_k has when the performer stands in the character's rest
  pose, so that pose gives the character its rest. Derived from the two rest poses (the rotation
  that turns the character's rest bones onto the source's, per joint: shortest arc for one bone,
  best fit over several, the shortest arc also fixing the twist reference) or captured from a live
  T-pose (``capture_rest_pose``: R = Q_k · D at that instant).
* D (dependency): extra source rotations multiplied after Q_k (Claro's Q_c · Q_s · Q_h), given as
  source rotation names, or a constant quaternion; identity unless a file says otherwise.

Other modes: ``aim`` (the joint turns by the shortest arc from its parent-carried rest so its bone
points where the source bone points: clavicles, Kiip 3.5.4) and ``spread`` (the joint takes its share,
by rest length along the chain, of the rotation between the rotate-mapped joints above and below it,
then the chain is turned so its end lands on the scaled source end point: spine and neck, Kiip
3.5.3). ``roll`` joints take a fraction of a neighbour's twist about the limb axis (Kiip 3.5.5).
Unmapped joints turn with their nearest mapped ancestor.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .character import Character
from .joint_roles import AIM_ROLES, LEG_ROLES, OPTICAL_ROTATION_LIMB, roles_of
from ..kinematics.quaternion import matrix_to_quat, quat_between, quat_conjugate, quat_multiply, quat_rotate
from .source import SourceSkeleton

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
MODES = ("rotate", "aim", "spread")


class MappingError(ValueError):
    """A mapping that does not fit its character or source (one line, names file:line and key)."""


@dataclass(frozen=True)
class JointMap:
    """How one character joint is driven (see the module docstring)."""

    joint: str
    mode: str = "rotate"
    rotation: str | None = None          # source rotation name (rotate: Q_k; spread: the chain top's)
    position: str | None = None          # source point at this joint
    A: np.ndarray = field(default_factory=lambda: IDENTITY.copy())
    R: np.ndarray = field(default_factory=lambda: IDENTITY.copy())
    D: tuple[str, ...] | np.ndarray = ()  # source rotation names, or a constant quaternion
    roll_of: str | None = None           # roll joint: the neighbour joint whose twist it shares
    roll_fraction: float = 0.0
    line: int | None = None              # where it was read from (errors)


@dataclass(frozen=True)
class Mapping:
    """Every driven joint of a character from one kind of source, plus root and leg settings."""

    source: str                          # e.g. bvh, kinect_v2, optical:kiip_full_body
    character: str
    joints: tuple[JointMap, ...]
    scale: float | None = None           # root translation ratio; None: leg-length ratio
    legs: dict = field(default_factory=dict)   # side -> (hip, knee, ankle, toe or None) character joints
    file: str = "<derived>"
    line: int | None = None

    def entry(self, joint: str) -> JointMap | None:
        for e in self.joints:
            if e.joint == joint:
                return e
        return None

    def where(self, e: JointMap | None = None) -> str:
        line = e.line if e is not None and e.line else self.line
        return f"{self.file}:{line}" if line else self.file


def _fail(m: Mapping, e: JointMap | None, key: str, msg: str) -> MappingError:
    return MappingError(f"{m.where(e)}: {key}: {msg}")


def check_mapping(m: Mapping, ch: Character, src: SourceSkeleton) -> None:
    """Raise MappingError (file:line: key: message) for joints the character lacks, source names
    the source lacks, non-unit quaternions, unknown modes, bad roll fractions."""
    seen = set()
    for e in m.joints:
        key = f"joints.{e.joint}"
        if e.joint not in ch.joint_names:
            raise _fail(m, e, key, _missing(f"character {ch.name!r} has no joint", e.joint, ch.joint_names))
        if e.joint in seen:
            raise _fail(m, e, key, "mapped twice")
        seen.add(e.joint)
        if e.mode not in MODES:
            raise _fail(m, e, f"{key}.mode", f"unknown mode {e.mode!r} (known: {', '.join(MODES)})")
        if e.mode == "spread" and e.rotation is not None:
            raise _fail(m, e, f"{key}.rotation", "a spread joint takes its rotation from the chain; remove `rotation`")
        if e.rotation is not None and e.rotation not in src.rotation_names:
            raise _fail(m, e, f"{key}.rotation", _missing(f"the source ({src.kinect_like or src.kind}, "
                        f"{len(src.rotation_names)} rotations) has no rotation", e.rotation, src.rotation_names))
        if e.position is not None and e.position not in src.point_names:
            raise _fail(m, e, f"{key}.position", _missing(f"the source ({src.kinect_like or src.kind}, "
                        f"{len(src.point_names)} points) has no point", e.position, src.point_names))
        for q, name in ((e.A, "A"), (e.R, "R")) + (((e.D, "D"),) if isinstance(e.D, np.ndarray) else ()):
            q = np.asarray(q, dtype=np.float64)
            if q.shape != (4,) or not np.isfinite(q).all() or abs(np.linalg.norm(q) - 1.0) > 1e-3:
                raise _fail(m, e, f"{key}.{name}", f"{np.round(q, 4).tolist()} is not a unit quaternion (w, x, y, z)")
        if not isinstance(e.D, np.ndarray):
            for d in e.D:
                if d not in src.rotation_names:
                    raise _fail(m, e, f"{key}.D", _missing("the source has no rotation", d, src.rotation_names))
        if e.roll_of is not None:
            if e.roll_of not in ch.joint_names:
                raise _fail(m, e, f"{key}.roll.of", _missing("no such joint", e.roll_of, ch.joint_names))
            j, o = ch.index(e.joint), ch.index(e.roll_of)
            if not (ch.parents[j] == o or ch.parents[o] == j):
                raise _fail(m, e, f"{key}.roll.of", f"{e.roll_of!r} is neither the parent nor a child of {e.joint!r}")
            if not 0.0 <= e.roll_fraction <= 1.0:
                raise _fail(m, e, f"{key}.roll.fraction", f"{e.roll_fraction} is not within 0..1")
    for side, names in m.legs.items():
        for n in names:
            if n is not None and n not in ch.joint_names:
                raise _fail(m, None, f"legs.{side}", _missing("the character has no joint", n, ch.joint_names))
    root = ch.joint_names[ch.root]
    e = m.entry(root)
    if e is None or e.mode != "rotate" or e.rotation is None or e.position is None:
        raise _fail(m, e, f"joints.{root}", "the character's root must be mapped with a rotation and a position")


def _missing(what: str, name: str, known) -> str:
    import difflib
    close = difflib.get_close_matches(name, list(known), n=3)
    return f"{what} {name!r}" + (f" (did you mean {', '.join(close)}?)" if close else "")


# ----- automatic mapping ---------------------------------------------------------------------
def derive_mapping(ch: Character, src: SourceSkeleton, *, source_label: str = "") -> Mapping:
    """Pair character joints with source joints by role (joint_roles), choose modes, then derive A
    and R from the two rest poses (:func:`align_rest_poses`)."""
    croles = roles_of(ch.joint_names)
    if src.kind == "optical":
        sroles = {n: r for n, r in roles_of(src.point_names).items()}
    else:
        sroles = roles_of(src.point_names)
    by_role = {r: n for n, r in sroles.items()}
    same_names = not croles or not sroles
    has_kids = {src.point_names[p] for p in src.point_parents if p >= 0}
    entries: list[JointMap] = []
    for j, name in enumerate(ch.joint_names):
        if ch.end_sites[j]:
            continue
        role = croles.get(name)
        s = name if same_names and name in src.point_names else by_role.get(role) if role else None
        if s is None and role is None and name in src.point_names:
            s = name
        if s is None:
            limb = OPTICAL_ROTATION_LIMB.get(role or "") if src.kind == "optical" and role == "chest" else None
            if limb in src.rotation_names:   # a chest joint: the upper torso turns it, no point there, so
                # the spine below it spreads from the pelvis up to it
                entries.append(JointMap(name, "rotate", limb, None))
            continue
        if src.kind == "optical":
            limb = OPTICAL_ROTATION_LIMB.get(role or "", None)
            rot = limb if limb in src.rotation_names else None
            pos = s
        else:
            rot = s if (s in has_kids and s in src.rotation_names) else None
            pos = s
        mode = "aim" if role in AIM_ROLES and src.kind != "optical" else "rotate"
        entries.append(JointMap(name, mode, rot, pos))
    # a root with a role the source lacks (e.g. no pelvis point): still rotate it from the source root
    root = ch.joint_names[ch.root]
    if not any(e.joint == root for e in entries):
        sroot = int(np.flatnonzero(src.point_parents < 0)[0])
        entries.insert(0, JointMap(root, "rotate", src.rotation_names[0] if src.kind == "optical"
                                   else src.point_names[sroot], src.point_names[sroot]))
    entries = [e for e in entries if e.rotation is not None or e.mode == "aim" or e.position is not None]
    entries = _mark_spreads(ch, entries)
    legs = {}
    for side, (h, k, a, t) in LEG_ROLES.items():
        found = [next((n for n in ch.joint_names if croles.get(n) == r), None) for r in (h, k, a, t)]
        if all(x is not None for x in found[:3]):
            legs[side] = tuple(found)
    m = Mapping(source_label or src.kinect_like or src.kind, ch.name, tuple(entries), None, legs)
    return align_rest_poses(m, ch, src)


def _mark_spreads(ch: Character, entries: list[JointMap]) -> list[JointMap]:
    """A rotate joint driven by the same source rotation as its nearest rotate descendant in the
    chain (e.g. two spine joints both on the upper torso) becomes a spread joint, so the chain bends
    gradually from the joint above instead of turning rigidly."""
    by = {e.joint: e for e in entries}
    out = []
    for e in entries:
        if e.mode == "rotate" and e.rotation is not None and ch.parents[ch.index(e.joint)] >= 0:
            j = ch.index(e.joint)
            kids = [k for k in ch.children(j)]
            below = None
            stack = list(kids)
            while stack:     # first rotate-mapped joint down each child chain
                k = stack.pop(0)
                ek = by.get(ch.joint_names[k])
                if ek is not None and ek.mode == "rotate" and ek.rotation is not None:
                    below = ek
                    break
                stack.extend(ch.children(k))
            if below is not None and below.rotation == e.rotation:
                e = replace(e, mode="spread", rotation=None)
        out.append(e)
    return out


def _rest_world(ch: Character) -> tuple[np.ndarray, np.ndarray]:
    pos, rot = ch.forward_kinematics(as_matrices=True)
    return pos, rot


def heading_alignment(ch: Character, src: SourceSkeleton) -> np.ndarray:
    """A (wxyz): the yaw about Z turning the source's rest facing onto the character's, from the
    left-right line of the hips (else the shoulders); identity when neither has both."""
    croles, sroles = roles_of(ch.joint_names), roles_of(src.point_names)
    cpos, _ = ch.rest_pose()
    for l, r in (("hip_l", "hip_r"), ("shoulder_l", "shoulder_r")):
        cl = [n for n, x in croles.items() if x == l]
        cr = [n for n, x in croles.items() if x == r]
        sl = [n for n, x in sroles.items() if x == l]
        sr = [n for n, x in sroles.items() if x == r]
        if cl and cr and sl and sr:
            vc = cpos[ch.index(cl[0])] - cpos[ch.index(cr[0])]
            vs = src.rest_points[src.point(sl[0])] - src.rest_points[src.point(sr[0])]
            vc[2] = vs[2] = 0.0
            if np.linalg.norm(vc) > 1e-6 and np.linalg.norm(vs) > 1e-6:
                return quat_between(vs, vc)
    return IDENTITY.copy()


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation matrix best turning unit vectors a [N, 3] onto b [N, 3]."""
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def align_rest_poses(m: Mapping, ch: Character, src: SourceSkeleton, *, keep_A: bool = False) -> Mapping:
    """A and R for every rotate/spread entry from the character's and the source's rest poses.

    Per joint, the character's rest bones to its children that have a source point are turned onto
    the source's rest bones (A applied): one bone by the shortest arc (which keeps the twist
    reference), several by the best rotation. A joint with no such bone keeps its nearest mapped
    ancestor's alignment. R = A⁻¹ · align⁻¹ · A · Q_k(rest) · D(rest).
    """
    A = heading_alignment(ch, src)
    cpos, _ = ch.rest_pose()
    by = {e.joint: e for e in m.joints}
    aligns: dict[str, np.ndarray] = {}
    out = []
    for j, name in enumerate(ch.joint_names):
        e = by.get(name)
        if e is None:
            continue
        a = e.A if keep_A else A
        align = None
        if e.mode in ("rotate", "spread") and e.position is not None:
            cvec, svec = [], []
            for k in ch.children(j):
                ek = by.get(ch.joint_names[k])
                if ek is None or ek.position is None:
                    continue
                c = cpos[k] - cpos[j]
                s = quat_rotate(a, src.rest_points[src.point(ek.position)] - src.rest_points[src.point(e.position)])
                if np.linalg.norm(c) > 1e-6 and np.linalg.norm(s) > 1e-6:
                    cvec.append(c / np.linalg.norm(c))
                    svec.append(s / np.linalg.norm(s))
            if len(cvec) == 1:
                align = quat_between(cvec[0], svec[0])
            elif len(cvec) > 1:
                align = matrix_to_quat(_kabsch(np.array(cvec), np.array(svec)))
        if align is None:
            anc = ch.parents[j]
            while anc >= 0 and ch.joint_names[anc] not in aligns:
                anc = ch.parents[anc]
            align = aligns.get(ch.joint_names[anc], IDENTITY) if anc >= 0 else IDENTITY
        aligns[name] = align
        if e.mode == "rotate" and e.rotation is not None:
            qk = src.rest_rotations[src.rotation(e.rotation)]
            qk = quat_multiply(qk, _dependency_rest(e, src))
            r = quat_multiply(quat_multiply(quat_conjugate(a), quat_conjugate(align)), quat_multiply(a, qk))
            out.append(replace(e, A=np.asarray(a, float), R=_canon(r)))
        else:
            out.append(replace(e, A=np.asarray(a, float)))
    return replace(m, joints=tuple(out))


def _dependency_rest(e: JointMap, src: SourceSkeleton) -> np.ndarray:
    if isinstance(e.D, np.ndarray):
        return e.D
    q = IDENTITY.copy()
    for d in e.D:
        q = quat_multiply(q, src.rest_rotations[src.rotation(d)])
    return q


def _canon(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q)
    return q if q[0] >= 0 else -q
