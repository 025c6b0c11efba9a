"""Helpers shared by the retargeting tests: BVH sources and bone-direction angles."""
from __future__ import annotations

import copy
import functools
from pathlib import Path

import numpy as np

from mocapgraph.formats.bvh_file import bvh_to_skeleton, read_bvh
from mocapgraph.kinematics.rest_offsets import offsets_from_rest
from mocapgraph.retarget.source import SourceSkeleton, skeleton_source


def bvh_source(path: Path):
    """(BvhMotion, SkeletonTrial, SourceSkeleton) of a BVH file, as the bvh_player node sends it."""
    motion = read_bvh(path)
    trial = bvh_to_skeleton(motion)
    offs = offsets_from_rest(motion.rest_positions(), trial.parents)
    return motion, trial, skeleton_source(trial.names, trial.parents, offs, has_orientations=True, kind_hint="bvh")


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors [..., 3], degrees."""
    cos = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def mapped_bones(ch, mapping, src: SourceSkeleton, min_len: float = 1e-6):
    """(character joint, child, source point, source child point) for every bone whose two ends
    both have a source point, the source bone being longer than ``min_len`` at rest."""
    by = {e.joint: e for e in mapping.joints}
    out = []
    for j, n in enumerate(ch.joint_names):
        e = by.get(n)
        if e is None or e.position is None:
            continue
        for k in ch.children(j):
            ek = by.get(ch.joint_names[k])
            if ek is None or ek.position is None:
                continue
            a, b = src.point(e.position), src.point(ek.position)
            if np.linalg.norm(src.rest_points[b] - src.rest_points[a]) > min_len:
                out.append((j, int(k), a, b))
    return out


def live_minus_batch(ch, mapping, src, opts, pts, pok, rot, times=None, n: int = 200) -> float:
    """Largest difference between the one-frame path (with roll joints: the batched path on one
    frame), frame by frame, and the batched path over
    the first ``n`` frames (local rotations, root, joint positions; quality and contact must agree)."""
    from mocapgraph.retarget.retargeter import Retargeter
    pts, rot = pts[:n], None if rot is None else rot[:n]
    pok = None if pok is None else pok[:n]
    t = np.arange(len(pts)) / 120.0 if times is None else times[:n]
    batch = Retargeter(ch, mapping, src, opts, live=False).process(pts, pok, rot, None, t)
    live = Retargeter(ch, mapping, src, opts)
    assert (live.frame_path is None) == bool(live.plan.rolls)   # roll joints: the batched path, one frame a call
    worst = 0.0
    for f in range(len(pts)):
        r = live.process(pts[f:f + 1], None if pok is None else pok[f:f + 1], None if rot is None else rot[f:f + 1],
                         None, t[f:f + 1])
        for k in ("local_rotations", "root_positions", "joint_positions"):
            worst = max(worst, float(np.abs(getattr(r, k)[0] - getattr(batch, k)[f]).max()))
        assert (r.joint_quality[0] == batch.joint_quality[f]).all() and (r.contact[0] == batch.contact[f]).all()
    return worst


@functools.lru_cache(maxsize=1)
def _solved_synthetic_actor():
    from mocapgraph.kinematics.calibration.calibrate import calibrate
    from mocapgraph.kinematics.solving.solver import FrameSolver
    from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor

    cap = SyntheticActor("kiip_full_body", options=CaptureOptions(noise_mm=1.0), seed=4).capture()
    model = calibrate(cap.skeleton, cap.markers[: cap.phases["gym"][1]], rate_hz=cap.rate, source="synthetic")
    res = FrameSolver(model, rate_hz=cap.rate).solve(cap.markers[cap.phase_slice("performance")])
    return cap, model, res


def solved_synthetic_actor():
    """(capture, model, solver result) of the synthetic actor (seed 4, 1 mm marker noise), calibrated
    on its base pose and gym and solved over its performance: built once per session for the
    retargeting modules that start from it (seconds each), handed out as a copy of its own."""
    return copy.deepcopy(_solved_synthetic_actor())
