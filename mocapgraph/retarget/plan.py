"""The retarget plan: everything about one source onto one character that does not change per frame.

Built once from the character, the mapping, the source skeleton and the options (:func:`build_plan`);
the batched path (:mod:`batched`), the one-frame numpy path and the compiled kernels (:mod:`live`) all
read their constants from it, so how a frame is computed is decided here once. Character joints are
indices into ``Character.joint_names``; source rotations and points are indices into the source's
``rotation_names`` and ``point_names``. World frame Z up, metres, rotation matrices [.., 3, 3].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..kinematics.quaternion import quat_conjugate, quat_multiply, quat_to_matrix
from .bone_follow import BoneChecks, plan_bone_checks
from .character import Character
from .mapping import JointMap, Mapping, MappingError, check_mapping
from .options import RetargetOptions
from .source import PointRotationPlan, SourceSkeleton, plan_point_rotations

_EYE3 = np.eye(3)


@dataclass(frozen=True)
class RetargetPlan:
    """The constants of one retargeting (see the module docstring for indices and frames); frozen:
    built once, read by every path."""

    parents: np.ndarray          # [J] parent index, the root's 0 (for gathers)
    rest_pos: np.ndarray         # [J, 3] rest joint positions, m (world)
    rest_world: np.ndarray       # [J, 3, 3] rest world orientations
    rest_local_inv: np.ndarray   # [J, 3, 3] inverse rest rotations in the parent frame
    # Eq 4.1 on rotate-mapped joints: Δ = A · Q_k · (D · R⁻¹ · A⁻¹)
    rot_joint: np.ndarray        # [M] character joints
    rot_src: np.ndarray          # [M] their source rotations
    A: np.ndarray                # [M, 3, 3]
    post: np.ndarray             # [M, 3, 3] D · R⁻¹ · A⁻¹
    dep: list[tuple[int, np.ndarray]]   # (rotate entry, source rotations multiplied on Q_k)
    # bone following: rotate entry, its source points (from, to) and its rest bone [.., 3] m
    follow_m: np.ndarray
    follow_a: np.ndarray
    follow_b: np.ndarray
    follow_bone: np.ndarray
    chains: list[dict[str, Any]]  # spread chains (start, end, joints, frac, end point, sources, ratio, offsets)
    aims: list[tuple[int, np.ndarray, int, int, np.ndarray]]   # (joint, rest bone unit, from, to, A)
    aim_joint: np.ndarray
    src_pre: np.ndarray          # [J] nearest driven ancestor-or-self before aims (-1: none)
    src_post: np.ndarray         # [J] and after them
    undriven: np.ndarray         # joints with no driven ancestor (they keep their rest)
    rolls: list[tuple[int, int, float, bool]]   # (roll joint, of joint, fraction, roll hangs from it)
    root: int
    root_src: int                # the source point that moves the root
    root_A: np.ndarray           # [3, 3]
    h_c: float                   # character root (or mid-hip) height above its floor at rest, m
    h_s: float                   # source root height above its floor standing, m
    ratio: float                 # root translation scale (leg-length ratio unless given)
    root_s: np.ndarray | None    # rest root - rest mid-hip in the root frame, m (None: not the mid-hip rule)
    anc: np.ndarray              # [J, J] 1 where column k is an ancestor bone of joint j
    anc_full: np.ndarray         # [J, J] bool: ancestors, the root and the joint itself
    legs: dict[str, np.ndarray] | None   # the two legs for planting (None: no planting)
    eye_j: np.ndarray            # [J, 3, 3] identities
    offset: np.ndarray           # [3] world shift of the character, m
    point_plan: PointRotationPlan | None   # rotations from points (positions-only sources)
    checks: BoneChecks           # the bone-follow quality checks
    # what the plan was built from (read by the one-frame paths, which fold it further)
    character: Character
    mapping: Mapping
    source: SourceSkeleton
    options: RetargetOptions


def build_plan(character: Character, mapping: Mapping, source: SourceSkeleton,
               options: RetargetOptions) -> RetargetPlan:
    """The plan of ``mapping`` from ``source`` onto ``character`` under ``options``; raises
    MappingError naming the file and joint for a mapping that cannot drive the character."""
    check_mapping(mapping, character, source)
    ch, m, src, opt = character, mapping, source, options
    J = ch.n_joints
    cpos, crot = ch.forward_kinematics(as_matrices=True)
    by = {e.joint: e for e in m.joints}
    jidx = {n: i for i, n in enumerate(ch.joint_names)}
    rot = [e for e in m.joints if e.mode == "rotate" and e.rotation is not None]
    rot_joint, rot_src, A, post, dep = _rotate_joints(rot, src, jidx)
    driven = np.zeros(J, bool)
    driven[rot_joint] = True
    follow = _bone_follows(ch, src, rot, by, jidx, cpos) if opt.follow_bones else []
    chains = _spread_chains(ch, m, src, by, jidx, cpos, driven) if opt.spread else []
    aims = _aims(ch, m, src, by, jidx, cpos) if opt.aim else []
    aim_joint = np.array([a[0] for a in aims], dtype=np.int64)
    src_pre = _nearest(ch.parents, driven)   # inheritance: nearest driven ancestor-or-self, before and after aims
    if len(aim_joint):
        driven[aim_joint] = True
    src_post = _nearest(ch.parents, driven)
    rolls = [(jidx[e.joint], jidx[e.roll_of], float(e.roll_fraction), ch.parents[jidx[e.joint]] == jidx[e.roll_of])
             for e in m.joints if e.roll_of is not None] if opt.roll else []
    root = _root_motion(ch, m, src, by, opt, cpos, crot)
    anc, anc_full = _ancestors(ch.parents, ch.root)
    return RetargetPlan(
        parents=np.maximum(ch.parents, 0), rest_pos=cpos, rest_world=crot,
        rest_local_inv=np.swapaxes(quat_to_matrix(ch.rest_rotations), -1, -2),
        rot_joint=rot_joint, rot_src=rot_src, A=A, post=post, dep=dep,
        follow_m=np.array([f[0] for f in follow], dtype=np.int64),
        follow_a=np.array([f[1] for f in follow], dtype=np.int64),
        follow_b=np.array([f[2] for f in follow], dtype=np.int64),
        follow_bone=np.array([f[3] for f in follow]).reshape(-1, 3),
        chains=chains, aims=aims, aim_joint=aim_joint, src_pre=src_pre, src_post=src_post,
        undriven=np.flatnonzero(src_post < 0), rolls=rolls, **root,
        anc=anc, anc_full=anc_full,
        legs=_legs(ch, m, src, by, jidx, cpos, rest_floor(cpos)) if opt.foot_planting and m.legs else None,
        eye_j=np.broadcast_to(_EYE3, (J, 3, 3)), offset=np.asarray(opt.offset, dtype=np.float64),
        point_plan=plan_point_rotations(src) if src.derived_rotations else None,
        checks=plan_bone_checks(ch, m, src, opt.follow_tolerance_deg),
        character=ch, mapping=m, source=src, options=opt)


def rest_floor(rest_positions: np.ndarray) -> float:
    """Floor height of a rest pose, m: 0 when the pose plausibly stands on z = 0 (lowest joint
    between -5 cm and 20 cm, e.g. an ankle), else the lowest joint (a BVH rest pose hanging from a
    root at the origin: its toes are the floor)."""
    low = float(np.nanmin(rest_positions[:, 2]))
    return 0.0 if -0.05 <= low <= 0.20 else low


def _rotate_joints(rot: list[JointMap], src: SourceSkeleton, jidx: dict[str, int]):
    """Eq 4.1's constants of the rotate-mapped joints: (joints, source rotations, A, D·R⁻¹·A⁻¹, dependencies)."""
    post, dep = [], []
    for i, e in enumerate(rot):
        d = e.D if isinstance(e.D, np.ndarray) else np.array([1.0, 0, 0, 0])
        if not isinstance(e.D, np.ndarray) and len(e.D):
            dep.append((i, np.array([src.rotation(x) for x in e.D])))
        post.append(quat_multiply(quat_multiply(d, quat_conjugate(e.R)), quat_conjugate(e.A)))
    return (np.array([jidx[e.joint] for e in rot], dtype=np.int64),
            np.array([src.rotation(e.rotation) for e in rot], dtype=np.int64),
            quat_to_matrix(np.array([e.A for e in rot]).reshape(-1, 4)),
            quat_to_matrix(np.array(post).reshape(-1, 4)), dep)


def _bone_follows(ch: Character, src: SourceSkeleton, rot: list[JointMap], by: dict, jidx: dict,
                  cpos: np.ndarray) -> list[tuple[int, int, int, np.ndarray]]:
    """Rotate joints with exactly one child that has a source point: (entry, from point, to point, rest bone)."""
    follow = []
    for i, e in enumerate(rot):
        j = jidx[e.joint]
        kids = [k for k in ch.children(j) if by.get(ch.joint_names[k]) is not None
                and by[ch.joint_names[k]].position is not None]
        if e.position is None or len(kids) != 1:
            continue
        a, b = src.point(e.position), src.point(by[ch.joint_names[kids[0]]].position)
        cb = cpos[kids[0]] - cpos[j]
        if np.linalg.norm(src.rest_points[b] - src.rest_points[a]) < 1e-6 or np.linalg.norm(cb) < 1e-6:
            continue   # a zero-length source bone has no direction to follow
        follow.append((i, a, b, cb))
    return follow


def _along(ch: Character, joint: int, kids: list[int]) -> int:
    """The child of ``joint`` whose rest bone continues ``joint``'s own bone best (-1: no child)."""
    up = ch.rest_offsets[joint] / max(np.linalg.norm(ch.rest_offsets[joint]), 1e-12)
    return max(kids, key=lambda k: float(ch.rest_offsets[k] @ up) / max(np.linalg.norm(ch.rest_offsets[k]), 1e-12),
               default=-1)


def _spread_chains(ch: Character, m: Mapping, src: SourceSkeleton, by: dict, jidx: dict, cpos: np.ndarray,
                   driven: np.ndarray) -> list[dict[str, Any]]:
    """The spread chains (Kiip 3.5.3), each from a rotate-mapped joint above it to one below it;
    marks their joints driven."""
    chains, spread = [], [jidx[e.joint] for e in m.joints if e.mode == "spread"]
    sset, handled = set(spread), set()
    for s in spread:
        if s in handled:
            continue
        start = ch.parents[s]
        while start >= 0 and start in sset:
            start = ch.parents[start]
        if start < 0 or not driven[start]:
            raise MappingError(f"{m.where(by[ch.joint_names[s]])}: joints.{ch.joint_names[s]}: a spread joint "
                               "needs a rotate-mapped joint above it in the chain")
        chain, end = _walk_chain(ch, by, s, sset, driven)
        if end < 0:
            raise MappingError(f"{m.where(by[ch.joint_names[s]])}: joints.{ch.joint_names[s]}: a spread joint "
                               "needs a rotate-mapped joint below it in the chain")
        handled.update(chain)
        chains.append(_chain(ch, src, by, cpos, start, chain, end))
        driven[chain] = True
    return chains


def _walk_chain(ch: Character, by: dict, s: int, sset: set, driven: np.ndarray) -> tuple[list[int], int]:
    """From spread joint ``s`` down through spread (and unmapped) joints: (chain, its rotate-mapped end or -1)."""
    chain, j = [], s
    while True:
        chain.append(j)
        kids = list(ch.children(j))
        nxt = [k for k in kids if k in sset]
        rk = [k for k in kids if driven[k]]
        if nxt:      # stay on the spread chain (a side branch, e.g. a clavicle, is not its end)
            j = nxt[0]
            continue
        if not rk and len(kids) == 1 and by.get(ch.joint_names[kids[0]]) is None:
            j = kids[0]  # an unmapped joint inside the chain takes its share too
            continue
        # the chain's end: the rotate-mapped child continuing its direction
        return chain, (_along(ch, j, rk) if rk else -1)


def _chain(ch: Character, src: SourceSkeleton, by: dict, cpos: np.ndarray, start: int, chain: list[int],
           end: int) -> dict[str, Any]:
    """One spread chain's constants: its share of the turn per joint, the end point that fixes its
    reach and the source points (pivot, end) with their length ratio."""
    seg = [chain[0]] + chain[1:] + [end]
    cum = np.cumsum(np.linalg.norm(ch.rest_offsets[seg], axis=1))  # bones start->chain[0], ..., ->end
    # end point: the end joint if it has a source point, else its child continuing the chain with one
    endpt, endsrc = end, by.get(ch.joint_names[end])
    if endsrc is None or endsrc.position is None:
        kid = _along(ch, end, list(ch.children(end)))
        ek = by.get(ch.joint_names[kid]) if kid >= 0 else None
        endpt, endsrc = (kid, ek) if ek is not None and ek.position is not None else (-1, None)
    piv_e = by.get(ch.joint_names[chain[0]])
    piv_src = piv_e.position if piv_e is not None and piv_e.position else by[ch.joint_names[start]].position
    ratio = np.nan
    if endsrc is not None and piv_src is not None:
        a = src.rest_points[src.point(endsrc.position)] - src.rest_points[src.point(piv_src)]
        ratio = np.linalg.norm(cpos[endpt] - cpos[chain[0]]) / max(np.linalg.norm(a), 1e-9)
    # joints whose bones lie between the pivot and the end point (chain + end if needed)
    path = chain + ([end] if endpt != end else [])
    # a joint's delta turns its rest world bone vector (toward the next joint, end point last) into the current one
    offsets = np.array([cpos[b] - cpos[a] for a, b in zip(path, path[1:] + [endpt])]) if endpt >= 0 else None
    return dict(start=start, end=end, ends=np.array([start, end]), joints=np.array(chain), frac=cum[:-1] / cum[-1],
                endpt=endpt, path=np.array(path), pivot_src=src.point(piv_src) if piv_src else -1,
                end_src=src.point(endsrc.position) if endsrc is not None else -1,
                A=quat_to_matrix(by[ch.joint_names[start]].A), ratio=ratio, offsets=offsets)


def _aims(ch: Character, m: Mapping, src: SourceSkeleton, by: dict, jidx: dict, cpos: np.ndarray):
    """Aim joints (clavicles, Kiip 3.5.4): (joint, rest bone to its child as a unit vector, from point, to point, A)."""
    aims = []
    for e in (e for e in m.joints if e.mode == "aim"):
        j = jidx[e.joint]
        kid = next((k for k in ch.children(j) if by.get(ch.joint_names[k]) is not None
                    and by[ch.joint_names[k]].position is not None), -1)
        frm = e.position or (by.get(ch.joint_names[ch.parents[j]]).position
                             if by.get(ch.joint_names[ch.parents[j]]) else None)
        if kid < 0 or frm is None:
            raise MappingError(f"{m.where(e)}: joints.{e.joint}: an aim joint needs a source point at (or above) "
                               "it and a child with a source point")
        b = cpos[kid] - cpos[j]
        aims.append((j, b / np.linalg.norm(b), src.point(frm), src.point(by[ch.joint_names[kid]].position),
                     quat_to_matrix(e.A)))
    return aims


def _nearest(parents: np.ndarray, driven: np.ndarray) -> np.ndarray:
    """[J] the nearest driven ancestor-or-self of each joint (-1: none)."""
    out = np.full(len(parents), -1, dtype=np.int64)
    for j in range(len(parents)):
        k = j
        while k >= 0 and not driven[k]:
            k = parents[k]
        out[j] = k
    return out


def _ancestors(parents: np.ndarray, root: int) -> tuple[np.ndarray, np.ndarray]:
    """(anc [J, J]: 1 where k's bone lies above j, positions being root + anc @ bones; the same with
    the root and the joint itself, as bool: whose quality a joint's is bounded by)."""
    J = len(parents)
    anc = np.zeros((J, J))
    for j in range(J):
        k = j
        while k >= 0 and parents[k] >= 0:
            anc[j, k] = 1.0
            k = parents[k]
    full = anc.astype(bool)
    full[:, root] = True
    np.fill_diagonal(full, True)
    return anc, full


def _root_motion(ch: Character, m: Mapping, src: SourceSkeleton, by: dict, opt: RetargetOptions,
                 cpos: np.ndarray, crot: np.ndarray) -> dict[str, Any]:
    """How the root moves: its source point and A, the floor-matched heights and the scale ratio
    (the fields root, root_src, root_A, h_c, h_s, ratio, root_s of the plan)."""
    root = ch.root
    re = by[ch.joint_names[root]]
    root_src = src.point(re.position)
    c_floor, s_floor = rest_floor(cpos), rest_floor(src.rest_points)
    h_c = float(cpos[root, 2] - c_floor)
    h_s = float(src.rest_points[root_src, 2] - s_floor)
    ratio = _leg_ratio(ch, m, src, by, h_c, h_s) if opt.root_scale else 1.0
    if opt.scale is not None:
        ratio = float(opt.scale)
    elif m.scale is not None:
        ratio = float(m.scale)
    if s_floor != 0.0:
        h_s += _standing_lift(ch, m, src, by, cpos, c_floor, s_floor, ratio)
    root_s, mid_h = _midhip_rule(ch, m, src, by, cpos, crot, root_src)
    return dict(root=root, root_src=root_src, root_A=quat_to_matrix(re.A),
                h_c=h_c if root_s is None else float(mid_h - c_floor), h_s=h_s, ratio=ratio, root_s=root_s)


def _leg_ratio(ch: Character, m: Mapping, src: SourceSkeleton, by: dict, h_c: float, h_s: float) -> float:
    """Character leg length over the source's (mean of the mapped legs), else the root heights' ratio."""
    ratios = []
    for names in m.legs.values():
        es = [by.get(n) for n in names[:3]]
        if any(e is None or e.position is None for e in es):
            continue
        cl = sum(np.linalg.norm(ch.rest_offsets[ch.index(n)]) for n in names[1:3])
        sp = src.rest_points[[src.point(e.position) for e in es]]
        sl = np.linalg.norm(sp[1] - sp[0]) + np.linalg.norm(sp[2] - sp[1])
        if sl > 1e-6:
            ratios.append(cl / sl)
    if ratios:
        return float(np.mean(ratios))
    return float(h_c / h_s) if h_s > 1e-6 else 1.0


def _midhip_rule(ch: Character, m: Mapping, src: SourceSkeleton, by: dict, cpos: np.ndarray, crot: np.ndarray,
                 root_src: int) -> tuple[np.ndarray | None, float]:
    """When the source root point is, at rest, the mid-point of the source points of the
    character's two hips (within 1 mm) and the character's root is not its own mid-hip, the root
    formula places the character's mid-hip there: returns (s = rest root - rest mid-hip in the root's
    rest frame, m: the root is then mid-hip + W_root · s; the rest mid-hip height, m, which h_c then
    measures). (None, nan) otherwise (nothing changes)."""
    if "l" not in m.legs or "r" not in m.legs:
        return None, np.nan
    es = [by.get(m.legs[side][0]) for side in ("l", "r")]
    if any(e is None or e.position is None for e in es):
        return None, np.nan
    mid_src = src.rest_points[[src.point(e.position) for e in es]].mean(0)
    if not np.linalg.norm(src.rest_points[root_src] - mid_src) <= 1e-3:
        return None, np.nan
    mid = cpos[[ch.index(m.legs[side][0]) for side in ("l", "r")]].mean(0)
    s = crot[ch.root].T @ (cpos[ch.root] - mid)
    if not np.abs(s).max() > 1e-9:   # the root already is the mid-hip (the actor on its own skeleton)
        return None, np.nan
    return s, float(mid[2])


def _standing_lift(ch: Character, m: Mapping, src: SourceSkeleton, by: dict, cpos: np.ndarray, c_floor: float,
                   s_floor: float, ratio: float) -> float:
    """How much higher the source root stands than its rest pose says, m, for a source whose rest
    pose hangs from the origin (a BVH): its lowest rest joint is no floor when the rest is no standing
    pose (CMU: the feet level, the ankles 2.5 cm above the toe joints, where a standing foot has them
    9 cm above the floor, which left the character's feet 15 cm up and never in contact). The
    source's ankles are taken to stand at least as high as the character's scaled by the leg
    ratio (its feet no flatter than the character's); the rest's vertical root-to-ankle extent
    stays. 0 when a leg is not mapped to source points, and for a source onto itself."""
    lift = []
    for names in m.legs.values():
        e = by.get(names[2])
        if e is None or e.position is None:
            return 0.0
        c_ankle = cpos[ch.index(names[2]), 2] - c_floor
        s_ankle = src.rest_points[src.point(e.position), 2] - s_floor
        lift.append(max(0.0, c_ankle / max(ratio, 1e-9) - s_ankle))
    return float(np.mean(lift)) if lift else 0.0


def _legs(ch: Character, m: Mapping, src: SourceSkeleton, by: dict, jidx: dict, cpos: np.ndarray,
          c_floor: float) -> dict[str, np.ndarray] | None:
    """The two legs for foot planting: hip, knee, ankle, toe joints [2], the joints each thigh and
    shin turn, bone lengths l1, l2 (m), the rest ankle and toe heights above the floor (m) and the
    source points of the ankles [2] (``src_ankle``, -1: none; a plant moves with them); None
    without two mapped legs."""
    sides = [s for s in ("l", "r") if s in m.legs][:2]
    if len(sides) != 2:
        return None
    J = ch.n_joints
    hip, knee, ankle = (np.array([jidx[m.legs[s][i]] for s in sides]) for i in range(3))
    toe = np.array([jidx[m.legs[s][3]] if m.legs[s][3] else -1 for s in sides])
    src_e = [by.get(m.legs[s][2]) for s in sides]
    src_ankle = np.array([src.point(e.position) if e is not None and e.position is not None else -1 for e in src_e],
                         dtype=np.int64)
    chains = [ch.chain(j) for j in range(J)]
    sub = np.array([[hip[i] in c and ankle[i] not in c for c in chains] for i in range(2)])   # turned by the thigh/shin
    below_knee = np.array([[knee[i] in c for c in chains] for i in range(2)])
    return dict(below_knee=below_knee, hip=hip, knee=knee, ankle=ankle, toe=toe, sub=sub, src_ankle=src_ankle,
                l1=np.linalg.norm(cpos[knee] - cpos[hip], axis=1),
                l2=np.linalg.norm(cpos[ankle] - cpos[knee], axis=1),
                rest_h=cpos[ankle, 2] - c_floor,
                toe_h=np.where(toe >= 0, cpos[np.maximum(toe, 0), 2] - c_floor, np.nan))
