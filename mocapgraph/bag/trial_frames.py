"""A recorded trial as the retargeter's source frames: BVH, Kinect CSV, C3D/TRC solved by a model, or a bag.

One library place for "file -> frames to retarget", called by ``mocapgraph retarget`` (and by
anything else that retargets a recording). Markers (C3D, TRC, a bag's MarkerFrame topic) are solved
by the frame solver with a calibrated model first. Points in metres, world frame (Z up);
rotations wxyz; times in seconds from the first frame. Every failure is a :class:`TrialError`
(one line, naming the file).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..formats import FormatError
from ..formats.sources import SKELETON_KINDS, read_skeleton_file, skeleton_rest_offsets
from .errors import BagError


class TrialError(ValueError):
    """A trial that cannot be read as source frames; the message is one line naming the file."""


@dataclass
class SourceFrames:
    """A trial as the retargeter reads it: points [F, P, 3] m, ok [F, P], rotations [F, R, 4] or None."""

    source: object
    points: np.ndarray
    point_ok: np.ndarray
    rotations: np.ndarray | None
    rotation_ok: np.ndarray | None
    times_s: np.ndarray
    frame_numbers: np.ndarray
    rate_hz: float
    label: str


@dataclass
class ModelView:
    """What an actor source needs of a model, from a model file or a bag's SkeletonModel."""

    joint_names: tuple
    joint_parent: np.ndarray
    joint_limbs: np.ndarray
    limb_names: tuple
    joint_base: np.ndarray
    layout: str


def skeleton_frames(names, parents, rest_offsets, positions, orientations, state, times, rate, label) -> SourceFrames:
    """A skeleton stream's arrays (positions [F, J, 3] m, orientations [F, J, 4] or None, tracking
    state [F, J] or None) as source frames."""
    from ..formats.retarget_setup import source_from_skeleton_info
    has_q = orientations is not None and bool(np.isfinite(orientations).any())
    src = source_from_skeleton_info(names, parents, rest_offsets, has_orientations=has_q)
    ok = np.isfinite(positions).all(-1) & (state >= 1 if state is not None else True)
    return SourceFrames(src, positions, ok, orientations if has_q else None, None, times,
                        np.arange(len(times)), rate, label)


def actor_frames(m: ModelView, joints, jq, limbs, lq, times, rate, label) -> SourceFrames:
    """A solved actor's arrays (joints [F, J, 3] m and quality [F, J], limb rotations [F, R, 4] and
    quality [F, R]) as source frames: the joints plus the pelvis point (both hips good)."""
    from ..formats.retarget_setup import source_from_model
    from ..retarget.source import optical_points
    src = source_from_model(m.joint_names, m.joint_parent, m.joint_limbs, m.limb_names, m.joint_base, m.layout)
    pts = optical_points(joints, m.joint_names)
    hips = [i for i, n in enumerate(m.joint_names) if n.startswith("hip")]
    pok = np.concatenate([jq >= 1, (jq[:, hips] >= 1).all(1, keepdims=True)], axis=1)
    return SourceFrames(src, pts, pok, limbs, lq >= 1, times, np.arange(len(times)), rate, label)


def read_trial_frames(path: str | Path, model: str | None = None, topic: str | None = None) -> SourceFrames:
    """Any supported trial as source frames (``model``: a model file for markers; ``topic``: a bag's
    topic, None for its only one); TrialError (one line) otherwise."""
    p = Path(path)
    if not p.exists():
        raise TrialError(f"{path}: no such file")
    kind = p.suffix.lower()
    try:
        if kind in SKELETON_KINDS:
            # BVH: its rest pose; Kinect: bone lengths of tracked samples (only lengths matter, see retarget_setup)
            tr = read_skeleton_file(p, ground="feet")
            offs = skeleton_rest_offsets(tr, tracked_only=True)
            t = tr.timestamps_ns * 1e-9 if kind != ".bvh" else np.arange(tr.n_frames) / tr.rate_hz
            state = tr.tracking_state if kind != ".bvh" else None
            return skeleton_frames(tr.names, tr.parents, offs, tr.positions, tr.orientations, state, t,
                                   tr.rate_hz, p.name)
        if kind in (".c3d", ".trc"):
            return solved_marker_frames(p, model, topic)
        if kind == ".mcap":
            return bag_frames(p, model, topic)
    except (FormatError, BagError) as exc:
        raise TrialError(str(exc)) from None
    except OSError as exc:
        raise TrialError(f"{path}: cannot read ({exc.strerror or exc})") from None
    raise TrialError(f"{p.name}: unknown trial type {p.suffix or '(none)'!r} (expected .bvh, .csv or .txt (Kinect), "
                     ".c3d, .trc or .mcap)")


def solved_marker_frames(p: Path, model_path: str | None, topic: str | None) -> SourceFrames:
    """Markers (C3D, TRC or a bag's MarkerFrame topic) solved by the frame solver with a model file."""
    from ..adapters.marker_columns import model_order, place_markers
    from ..kinematics.model import ModelFileError, load_model
    from ..kinematics.solving.solver import FrameSolver
    from .sources import read_marker_input
    if not model_path:
        raise TrialError(f"{p.name}: markers need an actor model: --model model.json (mocapgraph calibrate)")
    try:
        model = load_model(model_path)
        inp = read_marker_input(p, topic)
        where, _ = place_markers(model, inp, allow_missing=False)
    except ModelFileError as exc:
        raise TrialError(str(exc)) from None
    times = (inp.frame_numbers - inp.frame_numbers[0]) / inp.rate_hz
    res = FrameSolver(model, rate_hz=inp.rate_hz).solve(model_order(inp, where), times)
    m = ModelView(model.joint_names, model.joint_parent, model.joint_limbs, model.limb_names, model.joint_base,
                  model.layout)
    return actor_frames(m, res.joints, res.joint_quality, res.limb_rotation, res.limb_quality, times, inp.rate_hz, p.name)


def bag_frames(p: Path, model_path: str | None, topic: str | None) -> SourceFrames:
    """A bag's SkeletonPose (with SkeletonInfo), ActorPose (with SkeletonModel) or MarkerFrame topic."""
    from .reader import BagReader
    with BagReader(p) as r:
        by_type: dict[str, list[str]] = {}
        for t, i in r.topic_infos().items():
            by_type.setdefault(i.type_name, []).append(t)
        if "SkeletonPose" not in by_type and "ActorPose" not in by_type:
            if "MarkerFrame" in by_type:
                return solved_marker_frames(p, model_path, topic)
            raise TrialError(f"{p.name}: no SkeletonPose, ActorPose or MarkerFrame topic to retarget")
        kind = "SkeletonPose" if "SkeletonPose" in by_type else "ActorPose"
        tp = topic or by_type[kind][0]
        comp = "SkeletonInfo" if kind == "SkeletonPose" else "SkeletonModel"
        if comp not in by_type:
            raise TrialError(f"{p.name}: topic {tp!r} [{kind}] needs its latched {comp}, which the bag lacks")
        info = None
        for _, m in r.decoded(by_type[comp][0]):
            info = m
        frames = [(env.capture_ns, m) for env, m in r.decoded(tp)]
    if not frames:
        raise TrialError(f"{p.name}: topic {tp!r} holds no frames")
    ns = np.array([f[0] for f in frames], dtype=np.int64)
    t = (ns - ns[0]) * 1e-9
    rate = float(1.0 / np.median(np.diff(t))) if len(t) > 1 else 30.0
    msgs = [f[1] for f in frames]
    if kind == "SkeletonPose":
        J = len(info.joint_names)
        good = [m for m in msgs if m.joint_positions.shape[0] == J]
        if len(good) < len(msgs):
            print(f"note: {len(msgs) - len(good)} frames of {tp} do not have the {J} joints of skeleton_info: skipped")
        return skeleton_frames(info.joint_names, info.joint_parent, info.rest_offsets,
                               np.stack([m.joint_positions for m in good]), np.stack([m.joint_orientations for m in good]),
                               np.stack([m.tracking_state for m in good]), t[:len(good)], rate, p.name)
    m = info
    view = ModelView(m.joint_names, m.joint_parent, m.joint_limbs, m.limb_names, m.base_joints, m.layout_name)
    return actor_frames(view, np.stack([x.joint_positions for x in msgs]), np.stack([x.joint_quality for x in msgs]),
                        np.stack([x.limb_orientations for x in msgs]), np.stack([x.limb_quality for x in msgs]),
                        t, rate, p.name)
