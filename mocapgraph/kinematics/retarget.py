"""The retargeter: a performer's motion (source rotations and points) onto a character, batched over frames.

Per frame, in the world frame (Z up, metres, wxyz): every rotate-mapped joint's world rotation from
its rest by Claro's Eq 4.1 (A·Q_k·D·R⁻¹·A⁻¹; :mod:`retarget_mapping`), spread joints sharing the
rotation between the joints above and below them with the chain end put on the scaled source end
point, aimed joints (clavicles) turned toward the source bone, unmapped joints turning with their
mapped ancestor, roll joints taking a fraction of the twist about the limb axis; world orientations
then give the local rotations (Kiip Eq 8: C_L = P_W⁻¹ · C_W, with the rest orientation between)
and the joint positions; the root moves by the source root scaled by the leg-length ratio with the
floor matched (a source root at the mid-point of the hips puts the character's mid-hip there); foot planting finally holds feet in contact and above the floor (:mod:`foot_planting`).

One code path for live and batch: :meth:`Retargeter.process` takes [F, ...] arrays and carries its
state (last good source values, plants) from one call to the next, so a live node calls it with
one frame and ``mocapgraph retarget`` with a whole trial. A source value that goes missing is
held (its joints flagged estimated, 1); one never seen leaves the rest pose (flagged missing, 0).
Rotations out are never NaN.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .bone_follow import plan_bone_checks, unfollowed
from .retarget_kernels import flag_unfollowed
from .character import Character
from .foot_planting import PlantState, plant_targets, two_bone_ik
from .quaternion import (matrix_between, matrix_to_quat, norm, quat_conjugate, quat_multiply, quat_power,
                         quat_rotate, quat_to_matrix, swing_twist, twist_angle)
from .retarget_live import LiveKernel
from .retarget_mapping import Mapping, MappingError, check_mapping
from .retarget_source import OpticalFrames, SourceSkeleton, plan_point_rotations, rotations_from_points

QUALITY_MISSING, QUALITY_ESTIMATED, QUALITY_GOOD = 0, 1, 2
_EYE3 = np.eye(3)


@dataclass
class RetargetOptions:
    """Each method on or off, and the foot-planting thresholds."""

    spread: bool = True            # spine/neck spread with end-point matching (Kiip 3.5.3)
    aim: bool = True               # clavicles aimed at the scaled shoulder (3.5.4)
    roll: bool = True              # roll joints share the twist (3.5.5)
    foot_planting: bool = False    # contact, planting and floor (3.5.6)
    root_scale: bool = True        # root translation times the leg-length ratio
    follow_bones: bool = True      # a rotate joint with one mapped child points its bone along the source bone
    scale: float | None = None     # fixed root ratio (None: the mapping's, else the leg ratio)
    floor_z: float = 0.0
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)   # world shift of the character, m (beside the performer)
    contact_height_m: float = 0.03
    contact_speed_mps: float = 0.3
    release_s: float = 0.15
    # a joint whose bone turned from the source bone by more than this beyond the rest-shape
    # difference is flagged estimated on that frame (bone_follow); None: never
    follow_tolerance_deg: float | None = 10.0


@dataclass
class RetargetResult:
    """[F, ...] arrays: local rotations wxyz (relative to rest), root and joint positions (m, world),
    joint quality (0 missing, 1 estimated, 2 good), foot contact per leg side (l, r)."""

    local_rotations: np.ndarray
    root_positions: np.ndarray
    joint_positions: np.ndarray
    joint_quality: np.ndarray
    contact: np.ndarray


@dataclass
class _State:
    rot: np.ndarray
    rot_seen: np.ndarray
    pts: np.ndarray
    pts_seen: np.ndarray
    plant: PlantState = field(default_factory=PlantState.fresh)


def rest_floor(rest_positions: np.ndarray) -> float:
    """Floor height of a rest pose, m: 0 when the pose plausibly stands on z = 0 (lowest joint
    between -5 cm and 20 cm, e.g. an ankle), else the lowest joint (a BVH rest pose hanging from a
    root at the origin: its toes are the floor)."""
    low = float(np.nanmin(rest_positions[:, 2]))
    return 0.0 if -0.05 <= low <= 0.20 else low


def _eye(n: int) -> np.ndarray:
    return np.broadcast_to(np.eye(3), (n, 3, 3)).copy()


def _ffill(x: np.ndarray, ok: np.ndarray, last: np.ndarray, seen: np.ndarray):
    """Hold the last good value per column: (filled [F, N, ...], quality [F, N], new last, new seen)."""
    F = x.shape[0]
    if F == 1:   # the live case, without the index machinery
        extra = (slice(None),) + (None,) * (x.ndim - 2)
        filled = np.where(ok[(0,) + extra], x[0], last)[None]
        q = np.where(ok, QUALITY_GOOD, np.where(seen[None], QUALITY_ESTIMATED, QUALITY_MISSING)).astype(np.int8)
        return filled, q, filled[0].copy(), seen | ok[0]
    idx = np.where(ok, np.arange(F)[:, None], -1)
    idx = np.maximum.accumulate(idx, axis=0)
    cols = np.arange(x.shape[1])[None, :]
    got = x[np.maximum(idx, 0), cols]
    filled = np.where((idx >= 0)[..., None], got, last[None])
    q = np.where(ok, QUALITY_GOOD, np.where((idx >= 0) | seen[None], QUALITY_ESTIMATED, QUALITY_MISSING))
    return filled, q.astype(np.int8), filled[-1].copy(), seen | (idx[-1] >= 0)


class Retargeter:
    """Compiled mapping of one source onto one character; :meth:`process` runs it on frames."""

    def __init__(self, character: Character, mapping: Mapping, source: SourceSkeleton,
                 options: RetargetOptions | None = None, *, live: bool = True, compiled: bool = True) -> None:
        """``live=False`` leaves out the one-frame path (every call takes the batched one);
        ``compiled=False`` keeps the one-frame path in numpy (the compiled kernels' reference)."""
        check_mapping(mapping, character, source)
        self.character, self.mapping, self.source = character, mapping, source
        self.options = options or RetargetOptions()
        ch, m, src, opt = character, mapping, source, self.options
        J = ch.n_joints
        self._par = np.maximum(ch.parents, 0)
        cpos, crot = ch.forward_kinematics(as_matrices=True)
        self._rest_pos, self._rest_world = cpos, crot                     # [J, 3], [J, 3, 3]
        self._rest_local_inv = np.swapaxes(quat_to_matrix(ch.rest_rotations), -1, -2)
        by = {e.joint: e for e in m.joints}
        self._by = by
        jidx = {n: i for i, n in enumerate(ch.joint_names)}
        # --- rotate joints (Eq 4.1)
        rot = [e for e in m.joints if e.mode == "rotate" and e.rotation is not None]
        self._rot_joint = np.array([jidx[e.joint] for e in rot], dtype=np.int64)
        self._rot_src = np.array([src.rotation(e.rotation) for e in rot], dtype=np.int64)
        A = quat_to_matrix(np.array([e.A for e in rot]).reshape(-1, 4))
        post = []
        self._dep: list[tuple[int, np.ndarray]] = []
        for i, e in enumerate(rot):
            d = e.D if isinstance(e.D, np.ndarray) else np.array([1.0, 0, 0, 0])
            if not isinstance(e.D, np.ndarray) and len(e.D):
                self._dep.append((i, np.array([src.rotation(x) for x in e.D])))
            # D · R⁻¹ · A⁻¹
            post.append(quat_multiply(quat_multiply(d, quat_conjugate(e.R)), quat_conjugate(e.A)))
        self._A = A
        self._post = quat_to_matrix(np.array(post).reshape(-1, 4))
        driven = np.zeros(J, bool)
        driven[self._rot_joint] = True
        # --- bone following: rotate joints with exactly one child that has a source point
        follow = []
        if opt.follow_bones:
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
        self._follow_m = np.array([f[0] for f in follow], dtype=np.int64)
        self._follow_a = np.array([f[1] for f in follow], dtype=np.int64)
        self._follow_b = np.array([f[2] for f in follow], dtype=np.int64)
        self._follow_bone = np.array([f[3] for f in follow]).reshape(-1, 3)
        # --- spread chains
        self._chains = []
        spread_on = opt.spread
        spread = [jidx[e.joint] for e in m.joints if e.mode == "spread"] if spread_on else []
        sset = set(spread)
        handled = set()
        for s in spread:
            if s in handled:
                continue
            start = ch.parents[s]
            while start >= 0 and start in sset:
                start = ch.parents[start]
            if start < 0 or not driven[start]:
                raise MappingError(f"{m.where(by[ch.joint_names[s]])}: joints.{ch.joint_names[s]}: a spread joint "
                                   "needs a rotate-mapped joint above it in the chain")
            # walk down from start through spread joints to the first rotate-mapped joint
            chain, j = [], s
            end = -1
            while True:
                chain.append(j)
                kids = [k for k in ch.children(j)]
                nxt = [k for k in kids if k in sset]
                rk = [k for k in kids if driven[k]]
                if nxt:      # stay on the spread chain (a side branch, e.g. a clavicle, is not its end)
                    j = nxt[0]
                    continue
                if not rk and len(kids) == 1 and by.get(ch.joint_names[kids[0]]) is None:
                    j = kids[0]  # an unmapped joint inside the chain takes its share too
                    continue
                if rk:       # the chain's end: the rotate-mapped child continuing its direction
                    up = ch.rest_offsets[j] / max(np.linalg.norm(ch.rest_offsets[j]), 1e-12)
                    end = max(rk, key=lambda k: float(ch.rest_offsets[k] @ up) / max(np.linalg.norm(ch.rest_offsets[k]), 1e-12))
                break
            if end < 0:
                raise MappingError(f"{m.where(by[ch.joint_names[s]])}: joints.{ch.joint_names[s]}: a spread joint "
                                   "needs a rotate-mapped joint below it in the chain")
            handled.update(chain)
            seg = [chain[0]] + chain[1:] + [end]
            lengths = np.linalg.norm(ch.rest_offsets[seg], axis=1)  # bones start->chain[0], ..., ->end
            cum = np.cumsum(lengths)
            frac = cum[:-1] / cum[-1]
            # end point: the end joint if it has a source point, else its child with one
            endpt, endsrc = end, by.get(ch.joint_names[end])
            if endsrc is None or endsrc.position is None:
                # the end joint's child continuing the chain, if the source has a point there
                kids = list(ch.children(end))
                up = ch.rest_offsets[end] / max(np.linalg.norm(ch.rest_offsets[end]), 1e-12)
                kid = max(kids, key=lambda k: float(ch.rest_offsets[k] @ up) / max(np.linalg.norm(ch.rest_offsets[k]), 1e-12),
                          default=-1)
                ek = by.get(ch.joint_names[kid]) if kid >= 0 else None
                endpt, endsrc = (kid, ek) if ek is not None and ek.position is not None else (-1, None)
            piv_e = by.get(ch.joint_names[chain[0]])
            piv_src = piv_e.position if piv_e is not None and piv_e.position else by[ch.joint_names[start]].position
            ratio = np.nan
            if endsrc is not None and piv_src is not None:
                a = src.rest_points[src.point(endsrc.position)] - src.rest_points[src.point(piv_src)]
                ratio = np.linalg.norm(cpos[endpt] - cpos[chain[0]]) / max(np.linalg.norm(a), 1e-9)
            self._chains.append(dict(
                start=start, end=end, ends=np.array([start, end]), joints=np.array(chain), frac=frac, endpt=endpt,
                # joints whose bones lie between the pivot and the end point (chain + end if needed)
                path=np.array(chain + ([end] if endpt != end else [])),
                pivot_src=src.point(piv_src) if piv_src else -1,
                end_src=src.point(endsrc.position) if endsrc is not None else -1,
                A=quat_to_matrix(by[ch.joint_names[start]].A), ratio=ratio))
            self._chains[-1]["offsets"] = self._path_offsets(self._chains[-1]) if endpt >= 0 else None
            driven[chain] = True
        # --- aim joints
        aims = [e for e in m.joints if e.mode == "aim"] if opt.aim else []
        self._aims = []
        for e in aims:
            j = jidx[e.joint]
            kid = next((k for k in ch.children(j) if by.get(ch.joint_names[k]) is not None
                        and by[ch.joint_names[k]].position is not None), -1)
            frm = e.position or (by.get(ch.joint_names[ch.parents[j]]).position
                                 if by.get(ch.joint_names[ch.parents[j]]) else None)
            if kid < 0 or frm is None:
                raise MappingError(f"{m.where(e)}: joints.{e.joint}: an aim joint needs a source point at (or above) "
                                   "it and a child with a source point")
            b = cpos[kid] - cpos[j]
            self._aims.append((j, b / np.linalg.norm(b), src.point(frm), src.point(by[ch.joint_names[kid]].position),
                               quat_to_matrix(e.A)))
        self._aim_joint = np.array([a[0] for a in self._aims], dtype=np.int64)
        # inheritance: nearest driven ancestor-or-self (before and after aims)
        self._src_pre = self._nearest(driven)
        if len(self._aim_joint):
            driven[self._aim_joint] = True
        self._src_post = self._nearest(driven)
        self._undriven = np.flatnonzero(self._src_post < 0)   # precomputed: the live path runs per frame
        self._driven = driven
        # --- roll joints
        self._rolls = []
        if opt.roll:
            for e in m.joints:
                if e.roll_of is None:
                    continue
                r, o = jidx[e.joint], jidx[e.roll_of]
                self._rolls.append((r, o, float(e.roll_fraction), ch.parents[r] == o))
        # --- root translation
        root = ch.root
        re = by[ch.joint_names[root]]
        self._root = root
        self._root_src = src.point(re.position)
        self._root_A = quat_to_matrix(re.A)
        c_floor, s_floor = rest_floor(cpos), rest_floor(src.rest_points)
        self._h_c = cpos[root, 2] - c_floor
        self._h_s = src.rest_points[self._root_src, 2] - s_floor
        self.ratio = self._leg_ratio() if opt.root_scale else 1.0
        if opt.scale is not None:
            self.ratio = float(opt.scale)
        elif m.scale is not None:
            self.ratio = float(m.scale)
        if s_floor != 0.0:
            self._standing_heights(cpos, c_floor, s_floor)
        self._root_s = self._midhip_rule(cpos, c_floor)
        # --- positions: ancestor matrix (P = root + Anc @ bone vectors)
        anc = np.zeros((J, J))
        for j in range(J):
            k = j
            while k >= 0 and ch.parents[k] >= 0:
                anc[j, k] = 1.0
                k = ch.parents[k]
        self._anc = anc
        full = anc.astype(bool)
        full[:, root] = True
        np.fill_diagonal(full, True)
        self._anc_full = full
        # --- legs for planting
        self._legs = None
        if opt.foot_planting and m.legs:
            sides = [s for s in ("l", "r") if s in m.legs][:2]
            if len(sides) == 2:
                hip, knee, ankle = (np.array([jidx[m.legs[s][i]] for s in sides]) for i in range(3))
                toe = np.array([jidx[m.legs[s][3]] if m.legs[s][3] else -1 for s in sides])
                sub = np.zeros((2, J), bool)   # joints whose world rotation the thigh/shin turns
                desc_ankle = np.zeros((2, J), bool)
                for i in range(2):
                    for j in range(J):
                        ch_ = ch.chain(j)
                        if hip[i] in ch_ and ankle[i] not in ch_:
                            sub[i, j] = True
                        if ankle[i] in ch_ and j != ankle[i]:
                            desc_ankle[i, j] = True
                below_knee = np.array([[knee[i] in ch.chain(k) for k in range(J)] for i in range(2)])
                self._legs = dict(below_knee=below_knee, hip=hip, knee=knee, ankle=ankle, toe=toe, sub=sub,
                                  l1=np.linalg.norm(cpos[knee] - cpos[hip], axis=1),
                                  l2=np.linalg.norm(cpos[ankle] - cpos[knee], axis=1),
                                  rest_h=cpos[ankle, 2] - c_floor,
                                  toe_h=np.where(toe >= 0, cpos[np.maximum(toe, 0), 2] - c_floor, np.nan))
        self._eye_j = np.broadcast_to(_EYE3, (J, 3, 3))
        self._offset = np.asarray(opt.offset, dtype=np.float64)
        # --- positions-only sources
        self._plan = plan_point_rotations(src) if src.derived_rotations else None
        self._checks = plan_bone_checks(ch, m, src, opt.follow_tolerance_deg)
        self.reset()
        self._live = None
        self._optical: OpticalFrames | None = None   # process_actor's point layout when not compiled
        # the one-frame path's folded gathers multiply every (held, so finite) point by its weights
        self._live = LiveKernel(self, compiled) if live and np.isfinite(src.rest_points).all() else None

    # ----------------------------------------------------------------------------------------------
    def _nearest(self, driven: np.ndarray) -> np.ndarray:
        ch = self.character
        out = np.full(ch.n_joints, -1, dtype=np.int64)
        for j in range(ch.n_joints):
            k = j
            while k >= 0 and not driven[k]:
                k = ch.parents[k]
            out[j] = k
        return out

    def _leg_ratio(self) -> float:
        ch, m, src = self.character, self.mapping, self.source
        ratios = []
        for side, names in m.legs.items():
            es = [self._by.get(n) for n in names[:3]]
            if any(e is None or e.position is None for e in es):
                continue
            cl = sum(np.linalg.norm(ch.rest_offsets[ch.index(n)]) for n in names[1:3])
            sp = src.rest_points[[src.point(e.position) for e in es]]
            sl = np.linalg.norm(sp[1] - sp[0]) + np.linalg.norm(sp[2] - sp[1])
            if sl > 1e-6:
                ratios.append(cl / sl)
        if ratios:
            return float(np.mean(ratios))
        return float(self._h_c / self._h_s) if self._h_s > 1e-6 else 1.0

    def _midhip_rule(self, cpos: np.ndarray, c_floor: float) -> np.ndarray | None:
        """When the source root point is, at rest, the mid-point of the source points of the
        character's two hips (within 1 mm) and the character's root is not its own mid-hip, the root
        formula places the character's mid-hip there: returns s = rest root - rest mid-hip in the root's
        rest frame (m; the root is then mid-hip + W_root · s) and makes h_c the rest mid-hip height.
        None (nothing changes) otherwise."""
        m, src, ch = self.mapping, self.source, self.character
        if "l" not in m.legs or "r" not in m.legs:
            return None
        es = [self._by.get(m.legs[side][0]) for side in ("l", "r")]
        if any(e is None or e.position is None for e in es):
            return None
        mid_src = src.rest_points[[src.point(e.position) for e in es]].mean(0)
        if not np.linalg.norm(src.rest_points[self._root_src] - mid_src) <= 1e-3:
            return None
        mid = cpos[[ch.index(m.legs[side][0]) for side in ("l", "r")]].mean(0)
        s = self._rest_world[self._root].T @ (cpos[self._root] - mid)
        if not np.abs(s).max() > 1e-9:   # the root already is the mid-hip (the actor on its own skeleton)
            return None
        self._h_c = float(mid[2] - c_floor)
        return s

    def _standing_heights(self, cpos: np.ndarray, c_floor: float, s_floor: float) -> None:
        """The source root's height above the floor when standing, for a source whose rest pose hangs
        from the origin (a BVH): its lowest rest joint is no floor when the rest is no standing pose
        (CMU: the feet level, the ankles 2.5 cm above the toe joints, where a standing foot has them
        9 cm above the floor, which left the character's feet 15 cm up and never in contact). The
        source's ankles are taken to stand at least as high as the character's scaled by the leg
        ratio (its feet no flatter than the character's); the rest's vertical root-to-ankle extent
        stays. Unchanged when a leg is not mapped to source points, and for a source onto itself."""
        m, src = self.mapping, self.source
        lift = []
        for names in m.legs.values():
            e = self._by.get(names[2])
            if e is None or e.position is None:
                return
            c_ankle = cpos[self.character.index(names[2]), 2] - c_floor
            s_ankle = src.rest_points[src.point(e.position), 2] - s_floor
            lift.append(max(0.0, c_ankle / max(self.ratio, 1e-9) - s_ankle))
        if lift:
            self._h_s += float(np.mean(lift))

    def reset(self) -> None:
        """Forget held source values and plants (the next frame starts afresh)."""
        src = self.source
        self._state = _State(src.rest_rotations.copy(), np.zeros(len(src.rotation_names), bool),
                             src.rest_points.copy(), np.zeros(len(src.point_names), bool))

    def set_rest_from_current(self) -> Mapping:
        """``capture_rest_pose``: the last source frame is the character's rest pose: R = Q_k·D now.
        Returns the new mapping (write it with ``write_mapping`` to keep it)."""
        from dataclasses import replace
        st = self._state
        if not st.rot_seen.any() and not self.source.derived_rotations:
            raise MappingError("capture_rest_pose: no source frame received yet")
        new = []
        for e in self.mapping.joints:
            if e.mode == "rotate" and e.rotation is not None:
                q = st.rot[self.source.rotation(e.rotation)]
                if isinstance(e.D, np.ndarray):
                    q = quat_multiply(q, e.D)
                else:
                    for d in e.D:
                        q = quat_multiply(q, st.rot[self.source.rotation(d)])
                q = q / np.linalg.norm(q)
                new.append(replace(e, R=q if q[0] >= 0 else -q))
            else:
                new.append(e)
        m = replace(self.mapping, joints=tuple(new))
        self.__init__(self.character, m, self.source, self.options, live=self._live is not None,
                      compiled=self._live is not None and self._live.compiled is not None)
        return m

    # ----------------------------------------------------------------------------------------------
    def process_one(self, points: np.ndarray, point_ok: np.ndarray | None, rotations: np.ndarray | None,
                    rotation_ok: np.ndarray | None, time_s: float) -> RetargetResult:
        """One live frame (the node's call): points [P, 3], rotations [R, 4] or None, masks [P], [R]
        or None, time in s; :meth:`process` of that frame (F = 1), without its batch wrapping."""
        if self._live is not None:
            return self._live_frame(points, point_ok, rotations, rotation_ok, float(time_s))
        return self.process(points[None], None if point_ok is None else point_ok[None],
                            None if rotations is None else rotations[None],
                            None if rotation_ok is None else rotation_ok[None], float(time_s))

    def _actor_kernel(self):
        """The compiled live path when it takes actor frames (an optical source), else None."""
        live = self._live
        if live is not None and live.compiled is not None and live.compiled.hips is not None:
            return live.compiled
        return None

    def actor_buffers(self) -> RetargetResult | None:
        """A one-frame result for :meth:`process_actor` to write into (its ``out``), or None when the
        live path is not compiled (then each frame's result is new)."""
        compiled = self._actor_kernel()
        return None if compiled is None else compiled.buffers()

    def process_actor(self, joint_positions: np.ndarray, joint_quality: np.ndarray, limb_rotations: np.ndarray,
                      limb_quality: np.ndarray, time_s: float, out: RetargetResult | None = None) -> RetargetResult:
        """One live frame of a solved actor (an optical source; ActorPose's arrays: joints [J, 3] m,
        their quality [J], limb rotations [R, 4] wxyz, their quality [R]): :meth:`process_one` of the
        joints with the pelvis point (OpticalFrames) and the limbs of quality >= 1; one compiled call
        when the live path is compiled (the node's hot path: no point layout or mask in Python).
        ``out`` (from :meth:`actor_buffers`): the compiled path writes this frame into it and returns
        it (overwritten by the next call); otherwise, and without it, the result is new."""
        compiled = self._actor_kernel()
        if compiled is not None:
            return compiled.run_actor(joint_positions, joint_quality, limb_rotations, limb_quality, float(time_s), out)
        if self.source.kind != "optical":
            raise ValueError(f"an actor frame wants an optical source, this one is {self.source.kind}")
        if self._optical is None:
            self._optical = OpticalFrames(self.source.point_names[:-1])
        pts, ok = self._optical.frame(joint_positions, joint_quality)
        return self.process_one(pts[0], ok[0], limb_rotations, np.asarray(limb_quality) >= 1, time_s)

    def _live_frame(self, pts, pok, rot, rok, t) -> RetargetResult:
        """The one-frame path, then the bone-follow check on the held points the frame used."""
        res = self._live.run(pts, pok, rot, rok, t)
        c = self._checks
        if c.joint.size:    # retarget_kernels.flag_unfollowed: one compiled call
            flag_unfollowed(res.joint_positions[0], self._state.pts, c.joint, c.child, c.a, c.b, c.A, c.cos_limit,
                            res.joint_quality[0])
        return res

    def process(self, points: np.ndarray, point_ok: np.ndarray | None = None,
                rotations: np.ndarray | None = None, rotation_ok: np.ndarray | None = None,
                times_s: np.ndarray | None = None) -> RetargetResult:
        """Retarget frames: points [F, P, 3] (m, NaN missing), rotations [F, R, 4] (wxyz, NaN missing;
        None for a positions-only source), ``times_s`` [F] (s; one frame: a float will do) for foot-planting speeds."""
        st = self._state
        pts = np.asarray(points, dtype=np.float64)
        F = pts.shape[0]
        if F == 1 and self._live is not None:   # the live case: same math, constants folded (retarget_live)
            return self._live_frame(pts[0], None if point_ok is None else np.asarray(point_ok, bool)[0],
                                    None if rotations is None else np.asarray(rotations, dtype=np.float64)[0],
                                    None if rotation_ok is None else np.asarray(rotation_ok, bool)[0], times_s)
        if self._live is not None:
            self._live.release_state()
        pok = np.isfinite(pts).all(-1) if point_ok is None else (np.asarray(point_ok, bool) & np.isfinite(pts).all(-1))
        if rotations is None:
            if self._plan is None:
                raise ValueError("this source has rotations: pass them")
            rotations = rotations_from_points(self._plan, np.where(pok[..., None], pts, np.nan))
            rok = np.isfinite(rotations).all(-1)
        else:
            rotations = np.asarray(rotations, dtype=np.float64)
            n = norm(rotations)
            rok = np.isfinite(n) & (np.abs(n - 1.0) < 1e-3)
            if rotation_ok is not None:
                rok &= np.asarray(rotation_ok, bool)
        rot, rq, st.rot, st.rot_seen = _ffill(rotations, rok, st.rot, st.rot_seen)
        pts, pq, st.pts, st.pts_seen = _ffill(pts, pok, st.pts, st.pts_seen)
        J = self.character.n_joints
        # 1. rotate joints: Δ = A · Q_k · D · R⁻¹ · A⁻¹
        qk = rot[:, self._rot_src]
        for i, deps in self._dep:
            for d in deps:
                qk[:, i] = quat_multiply(qk[:, i], rot[:, d])
        delta = np.broadcast_to(self._eye_j, (F, J, 3, 3)).copy()
        d_rot = self._A @ quat_to_matrix(qk) @ self._post
        if len(self._follow_m):
            sub = d_rot[:, self._follow_m]
            have = (sub @ self._follow_bone[..., None])[..., 0]
            A = self._A[self._follow_m]
            want = (A @ (pts[:, self._follow_b] - pts[:, self._follow_a])[..., None])[..., 0]
            ok = norm(want) > 1e-9
            turn = matrix_between(have, np.where(ok[..., None], want, have))
            d_rot[:, self._follow_m] = turn @ sub
        delta[:, self._rot_joint] = d_rot
        # 2. spread chains
        for c in self._chains:
            qse = matrix_to_quat(delta[:, c["ends"]])            # start and end in one call
            qs, qe = qse[:, 0], qse[:, 1]
            rel = quat_multiply(quat_conjugate(qs), qe)
            qi = quat_multiply(qs[:, None], quat_power(rel[:, None], c["frac"][None, :]))
            delta[:, c["joints"]] = quat_to_matrix(qi)
            if c["end_src"] >= 0 and c["pivot_src"] >= 0 and np.isfinite(c["ratio"]):
                target = c["ratio"] * (c["A"] @ (pts[:, c["end_src"]] - pts[:, c["pivot_src"]])[..., None])[..., 0]
                path = c["path"]
                kids_off = c["offsets"]
                for _ in range(1 if c["endpt"] == c["end"] else 4):
                    vec = np.einsum("fkij,kj->fi", delta[:, path], kids_off)
                    corr = matrix_between(vec, target)
                    delta[:, c["joints"]] = corr[:, None] @ delta[:, c["joints"]]
        # 3. inherit, 4. aims
        if self._aims:
            delta_all = delta[:, self._src_pre]
            for j, b, frm, to, A in self._aims:
                dp = delta_all[:, self.character.parents[j]]
                carried = (dp @ b[:, None])[..., 0]
                want = (A @ (pts[:, to] - pts[:, frm])[..., None])[..., 0]
                delta[:, j] = matrix_between(carried, want) @ dp
        delta_all = delta[:, np.maximum(self._src_post, 0)]
        if self._undriven.size:
            delta_all[:, self._undriven] = _EYE3
        world = delta_all @ self._rest_world                     # [F, J, 3, 3]
        # 5. roll joints
        for r, o, f, upper in self._rolls:
            world = self._apply_roll(world, r, o, f, upper)
        # 6. root and positions
        root = self._root_position(pts[:, self._root_src])
        if self._root_s is not None:   # the formula gave the mid-hip: the root sits off it, turning with the root
            root = root + world[:, self._root] @ self._root_s
        pos = self._positions(world, root)
        contact = np.zeros((F, 2), bool)
        if self._legs is not None:
            t = np.arange(F, dtype=float) if times_s is None else np.asarray(times_s, float).reshape(-1)
            world, pos, contact = self._plant(world, pos, root, t)
        # 7. local rotations: rest⁻¹ · W[parent]⁻¹ · W
        parent_w = world[:, self._par]
        parent_w[:, self._root] = _EYE3
        local = self._rest_local_inv @ np.swapaxes(parent_w, -1, -2) @ world
        quality = self._quality(rq, pq)
        if not self._checks.empty:
            quality = np.where(unfollowed(self._checks, pos, pts), np.minimum(quality, QUALITY_ESTIMATED), quality)
        return RetargetResult(matrix_to_quat(local), root, pos, quality.astype(np.int8), contact)

    def _quality(self, rq: np.ndarray, pq: np.ndarray) -> np.ndarray:
        """Joint quality [F, J] from the source rotations' and points' [F, R], [F, P]: a joint is as good
        as the worst of what drives it and of every joint above it."""
        F, J = rq.shape[0], self.character.n_joints
        jq = np.full((F, J), QUALITY_GOOD, np.int8)
        jq[:, self._rot_joint] = rq[:, self._rot_src]
        if len(self._follow_m):   # a bone aimed at held points is estimated too
            fj = self._rot_joint[self._follow_m]
            jq[:, fj] = np.minimum(jq[:, fj], np.minimum(pq[:, self._follow_a], pq[:, self._follow_b]))
        for c in self._chains:
            jq[:, c["joints"]] = np.minimum(jq[:, [c["start"]]], jq[:, [c["end"]]])
            if c["end_src"] >= 0 and c["pivot_src"] >= 0:
                jq[:, c["joints"]] = np.minimum(jq[:, c["joints"]],
                                                np.minimum(pq[:, [c["end_src"]]], pq[:, [c["pivot_src"]]]))
        for j, _b, frm, to, _A in self._aims:
            jq[:, j] = np.minimum(pq[:, to], pq[:, frm])
        jq = jq[:, np.maximum(self._src_post, 0)]
        jq[:, self._root] = np.minimum(jq[:, self._root], pq[:, self._root_src])
        return np.where(self._anc_full[None], jq[:, None, :], 9).min(-1).astype(np.int8)

    # ----------------------------------------------------------------------------------------------
    def _path_offsets(self, c) -> np.ndarray:
        """Rest world bone vector leaving each joint of a chain path toward the next (end point last)."""
        path = list(c["path"]) + [c["endpt"]]
        # a joint's delta turns its rest world bone vector into the current one
        return np.array([self._rest_pos[b] - self._rest_pos[a] for a, b in zip(path[:-1], path[1:])])

    def _root_position(self, src_root: np.ndarray) -> np.ndarray:
        """Root: horizontal source root times the ratio (A applied), height matched at the floor."""
        p = (self._root_A @ src_root[..., None])[..., 0] * self.ratio
        p[:, 2] = self._h_c + self.ratio * (src_root[:, 2] - self._h_s) + self.options.floor_z
        return p + self._offset

    def _positions(self, world: np.ndarray, root: np.ndarray) -> np.ndarray:
        ch = self.character
        bones = (world[:, self._par] @ ch.rest_offsets[:, :, None])[..., 0]
        return root[:, None, :] + np.einsum("jk,fkd->fjd", self._anc, bones)

    def _apply_roll(self, world, r, o, f, upper):
        ch = self.character
        rest_q = ch.rest_rotations
        wq = matrix_to_quat(world)
        if upper:   # r hangs from o: o keeps (1 - f) of its twist about the o->r bone, r takes f
            par = ch.parents[o]
            pw = wq[:, par] if par >= 0 else np.array([1.0, 0, 0, 0])
            local_o = quat_multiply(quat_conjugate(quat_multiply(pw, rest_q[o])), wq[:, o])
            axis = ch.rest_offsets[r] / np.linalg.norm(ch.rest_offsets[r])
            _, tw = swing_twist(local_o, axis)
            world[:, o] = quat_to_matrix(quat_multiply(wq[:, o], quat_power(quat_conjugate(tw), f)))
        else:       # o hangs from r: r takes f of o's twist about the r->o bone
            local_o = quat_multiply(quat_conjugate(quat_multiply(wq[:, r], rest_q[o])), wq[:, o])
            axis_o = quat_rotate(quat_conjugate(rest_q[o]), ch.rest_offsets[o] / np.linalg.norm(ch.rest_offsets[o]))
            _, tw = swing_twist(local_o, axis_o)
            ang = twist_angle(tw, axis_o) * f
            ax = ch.rest_offsets[o] / np.linalg.norm(ch.rest_offsets[o])      # in r's frame
            turn = np.concatenate([np.cos(ang / 2)[:, None], np.sin(ang / 2)[:, None] * ax], axis=1)
            world[:, r] = quat_to_matrix(quat_multiply(wq[:, r], turn))
        return world

    def _plant(self, world, pos, root, t):
        L, opt = self._legs, self.options
        ankle = pos[:, L["ankle"]]
        toe_lift = None
        if (L["toe"] >= 0).all():
            toe_lift = (opt.floor_z + L["toe_h"]) - pos[:, L["toe"], 2]
        # thresholds are for a performer-sized character: a bigger one moves (and jitters) faster
        k = max(self.ratio, 1e-3)
        target, contact = plant_targets(ankle, L["rest_h"], t, self._state.plant, floor_z=opt.floor_z,
                                        height_m=opt.contact_height_m * k, speed_mps=opt.contact_speed_mps * k,
                                        release_s=opt.release_s, toe_lift=toe_lift)
        if np.abs(target - ankle).max(initial=0.0) < 1e-12 or not np.isfinite(target).any():
            return world, pos, contact          # nothing to correct (free feet above the floor)
        hip, knee = pos[:, L["hip"]], pos[:, L["knee"]]
        pole = (world[:, L["hip"]] @ np.array([1.0, 0.0, 0.0]))  # the thigh's forward axis
        s1, s2, _ = two_bone_ik(hip, knee, ankle, target, L["l1"][None], L["l2"][None], pole)
        # a foot already where it should be keeps its leg (IK would bend a straight one by its reach margin),
        # so a frame's result does not depend on the other frames of its batch
        need = (np.abs(target - ankle).max(-1) >= 1e-12)[..., None, None]
        s1, s2 = np.where(need, s1, _EYE3), np.where(need, s2, _EYE3)
        for i in range(2):
            above_knee = L["sub"][i].copy()
            thigh = above_knee & ~L["below_knee"][i]
            shin = above_knee & L["below_knee"][i]
            world[:, thigh] = s1[:, i, None] @ world[:, thigh]
            world[:, shin] = (s2[:, i] @ s1[:, i])[:, None] @ world[:, shin]
        return world, self._positions(world, root), contact
