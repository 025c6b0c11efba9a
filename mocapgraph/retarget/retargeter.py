"""The retargeter: a performer's motion (source rotations and points) onto a character, the calls the node and CLI make.

What it does per frame (world frame, Z up, metres, wxyz): every rotate-mapped joint's world rotation
from its rest by Claro's Eq 4.1 (A·Q_k·D·R⁻¹·A⁻¹; :mod:`mapping`), spread chains, aimed clavicles,
unmapped joints turning with their mapped ancestor, roll joints, the root scaled by the leg-length
ratio with the floor matched, foot planting, local rotations (Kiip Eq 8). Where it is decided:
:mod:`plan` builds the constants once; :mod:`batched` is the arithmetic on [F, ...] arrays (the
reference); :mod:`live` and :mod:`kernels` the same for one frame, compiled, with
:mod:`live_numpy` its numpy reference.

One entry for live and batch: :meth:`Retargeter.process` takes [F, ...] arrays and carries its
state (last good source values, plants) from one call to the next, so a live node calls it with
one frame and ``mocapgraph retarget`` with a whole trial. A source value that goes missing is
held (its joints flagged estimated, 1); one never seen leaves the rest pose (flagged missing, 0).
Rotations out are never NaN.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..kinematics.quaternion import norm, quat_multiply
from .batched import hold_last_good, retarget_frames
from .character import Character
from .foot_planting import PlantState
from .kernels import flag_unfollowed
from .live import CompiledFrame
from .mapping import Mapping, MappingError
from .options import RetargetOptions, RetargetResult
from .plan import RetargetPlan, build_plan
from .source import OpticalFrames, SourceSkeleton, rotations_from_points

__all__ = ["RetargetOptions", "RetargetResult", "Retargeter"]


@dataclass
class RetargetState:
    """What carries from one call to the next: the last good source values (and whether each was
    ever seen) and the plants."""

    rot: np.ndarray
    rot_seen: np.ndarray
    pts: np.ndarray
    pts_seen: np.ndarray
    plant: PlantState = field(default_factory=PlantState.fresh)


class Retargeter:
    """One source onto one character: its plan, the state carried between calls, and the calls:
    :meth:`process` on [F, ...] frames, :meth:`process_one` and :meth:`process_actor` on one live frame."""

    def __init__(self, character: Character, mapping: Mapping, source: SourceSkeleton,
                 options: RetargetOptions | None = None, *, live: bool = True,
                 frame_path: type = CompiledFrame) -> None:
        """``live=False`` leaves out the one-frame path (every call takes the batched one), as do
        roll joints (no one-frame path rolls); ``frame_path`` builds the one-frame path from the plan
        (:class:`live.CompiledFrame`; the tests pass :class:`live_numpy.NumpyFrame`, its reference)."""
        self.character, self.mapping, self.source = character, mapping, source
        self.options = options or RetargetOptions()
        self.plan: RetargetPlan = build_plan(character, mapping, source, self.options)
        self.reset()
        self._optical: OpticalFrames | None = None   # process_actor's point layout off the compiled path
        # the one-frame path's folded gathers multiply every (held, so finite) point by its weights
        one_frame = live and not self.plan.rolls and np.isfinite(source.rest_points).all()
        self.frame_path = frame_path(self.plan) if one_frame else None
        self._frame_path_type = frame_path

    @property
    def ratio(self) -> float:
        """The root translation's scale (the leg-length ratio unless the options or mapping give one)."""
        return self.plan.ratio

    def reset(self) -> None:
        """Forget held source values and plants (the next frame starts afresh)."""
        src = self.source
        self.state = RetargetState(src.rest_rotations.copy(), np.zeros(len(src.rotation_names), bool),
                             src.rest_points.copy(), np.zeros(len(src.point_names), bool))

    def set_rest_from_current(self) -> Mapping:
        """``capture_rest_pose``: the last source frame is the character's rest pose: R = Q_k·D now.
        Returns the new mapping (write it with ``write_mapping`` to keep it)."""
        from dataclasses import replace
        st = self.state
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
        self.__init__(self.character, m, self.source, self.options, live=self.frame_path is not None,
                      frame_path=self._frame_path_type)
        return m

    # ----------------------------------------------------------------------------------------------
    def process_one(self, points: np.ndarray, point_ok: np.ndarray | None, rotations: np.ndarray | None,
                    rotation_ok: np.ndarray | None, time_s: float) -> RetargetResult:
        """One live frame (the node's call): points [P, 3], rotations [R, 4] or None, masks [P], [R]
        or None, time in s; :meth:`process` of that frame (F = 1), without its batch wrapping."""
        if self.frame_path is not None:
            return self._live_frame(points, point_ok, rotations, rotation_ok, float(time_s))
        return self.process(points[None], None if point_ok is None else point_ok[None],
                            None if rotations is None else rotations[None],
                            None if rotation_ok is None else rotation_ok[None], float(time_s))

    def _actor_kernel(self) -> CompiledFrame | None:
        """The compiled live path when it takes actor frames (an optical source), else None."""
        live = self.frame_path
        return live if isinstance(live, CompiledFrame) and live.hips is not None else None

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
            return compiled.run_actor(self.state, joint_positions, joint_quality, limb_rotations, limb_quality,
                                      float(time_s), out)
        if self.source.kind != "optical":
            raise ValueError(f"an actor frame wants an optical source, this one is {self.source.kind}")
        if self._optical is None:
            self._optical = OpticalFrames(self.source.point_names[:-1])
        pts, ok = self._optical.frame(joint_positions, joint_quality)
        return self.process_one(pts[0], ok[0], limb_rotations, np.asarray(limb_quality) >= 1, time_s)

    def _live_frame(self, pts, pok, rot, rok, t) -> RetargetResult:
        """The one-frame path, then the bone-follow check on the held points the frame used."""
        res = self.frame_path.run(self.state, pts, pok, rot, rok, t)
        c = self.plan.checks
        if c.joint.size:    # kernels.flag_unfollowed: one compiled call
            flag_unfollowed(res.joint_positions[0], self.state.pts, c.joint, c.child, c.a, c.b, c.A, c.cos_limit,
                            res.joint_quality[0])
        return res

    def process(self, points: np.ndarray, point_ok: np.ndarray | None = None,
                rotations: np.ndarray | None = None, rotation_ok: np.ndarray | None = None,
                times_s: np.ndarray | None = None) -> RetargetResult:
        """Retarget frames: points [F, P, 3] (m, NaN missing), rotations [F, R, 4] (wxyz, NaN missing;
        None for a positions-only source), ``times_s`` [F] (s; one frame: a float will do) for foot-planting speeds."""
        st = self.state
        pts = np.asarray(points, dtype=np.float64)
        F = pts.shape[0]
        if F == 1 and self.frame_path is not None:   # the live case: same math, constants folded (live)
            return self._live_frame(pts[0], None if point_ok is None else np.asarray(point_ok, bool)[0],
                                    None if rotations is None else np.asarray(rotations, dtype=np.float64)[0],
                                    None if rotation_ok is None else np.asarray(rotation_ok, bool)[0], times_s)
        if self.frame_path is not None:
            self.frame_path.release_state()
        pok = np.isfinite(pts).all(-1) if point_ok is None else (np.asarray(point_ok, bool) & np.isfinite(pts).all(-1))
        if rotations is None:
            if self.plan.point_plan is None:
                raise ValueError("this source has rotations: pass them")
            rotations = rotations_from_points(self.plan.point_plan, np.where(pok[..., None], pts, np.nan))
            rok = np.isfinite(rotations).all(-1)
        else:
            rotations = np.asarray(rotations, dtype=np.float64)
            n = norm(rotations)
            rok = np.isfinite(n) & (np.abs(n - 1.0) < 1e-3)
            if rotation_ok is not None:
                rok &= np.asarray(rotation_ok, bool)
        rot, rq, st.rot, st.rot_seen = hold_last_good(rotations, rok, st.rot, st.rot_seen)
        pts, pq, st.pts, st.pts_seen = hold_last_good(pts, pok, st.pts, st.pts_seen)
        return retarget_frames(self.plan, self.character, self.options, st.plant, rot, rq, pts, pq, times_s)
