"""Video files to skeleton trials: one camera's metric estimate, or N calibrated cameras triangulated.

The glue of the pure parts (:mod:`.frames`, :mod:`.estimator`, :mod:`.multiview`) that the
nodes and the batch commands share. Every unusable input is a one-line FormatError
(VideoError, CalibrationError): a video that does not decode, a calibration without a camera
for a video, a frame rate unusable for alignment, a clip with no person in it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..formats.skeleton_trial import SkeletonTrial
from .estimator import Detections, detect_video, landmarks_trial, single_view_trial
from .frames import VideoError
from .multiview import CalibrationError, Camera, Triangulation, match_cameras, read_calibration, triangulate_frames

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v")


def require_person(det: Detections) -> Detections:
    """The detections, or VideoError when no frame shows a person."""
    if det.n_frames and not det.found.any():
        raise VideoError(None if det.info.name.startswith("camera:") else Path(det.info.name),
                         f"no person found in any of its {det.n_frames} frames")
    return det


def video_trial(path: str | Path, *, good: float = 0.8, missing: float = 0.5, ground: str = "feet",
                progress=None, pose_model: str = "full") -> tuple[SkeletonTrial, Detections]:
    """One camera's Kinect v2 trial (see :func:`single_view_trial`) and its detections
    (``pose_model``: :mod:`.pose_models`; the full model's metric 3D estimate keeps the thighs and
    shanks within 10 % of the triangulated ones on the demo, the heavy one's within 19 %)."""
    det = require_person(detect_video(path, progress=progress, model=pose_model))
    return single_view_trial(det, good=good, missing=missing, ground=ground), det


def videos_beside(calibration: str | Path) -> list[Path]:
    """The video files in the calibration's folder, sorted by name."""
    folder = Path(calibration).parent
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES)


def cameras_for(calibration: str | Path, videos: list[Path]) -> list[Camera]:
    """The calibration's camera of each video (matched by file stem), CalibrationError otherwise."""
    if len(videos) < 2:
        raise CalibrationError(Path(calibration), f"needs at least two videos to triangulate, got {len(videos)}")
    return match_cameras(read_calibration(calibration), [v.stem for v in videos], path=calibration)


def _pick(d: Detections, idx: np.ndarray, times_s: np.ndarray) -> Detections:
    return Detections(d.info, d.image[idx], d.visibility[idx], d.world[idx], d.found[idx], times_s,
                      d.ms_per_frame, d.notes)


def aligned(dets: list[Detections], names: list[str], *, max_rate: float = 240.0) -> tuple[list[Detections], list[str]]:
    """The cameras' detections on common frames (the videos are taken to start together).

    Same rate: cut to the shortest clip. Rates that differ: aligned by time stamp on the slowest
    camera's frames (each other camera's nearest frame, within half of its own frame period), over
    the time every clip covers; a note says so. VideoError naming the cameras when a rate is not
    usable (0 or over ``max_rate``, so no time stamps to align by)."""
    rates = np.array([d.info.fps for d in dets])
    listing = ", ".join(f"{n} {r:g} fps" for n, r in zip(names, rates))
    if not ((rates > 0) & (rates <= max_rate)).all():
        raise VideoError("videos", f"frame rates unusable for alignment ({listing})")
    n = min(d.n_frames for d in dets)
    if np.ptp(rates) <= 0.01 * rates.max():
        notes = []
        if any(d.n_frames != n for d in dets):
            notes.append("frame counts differ (" + ", ".join(f"{nm} {d.n_frames}" for nm, d in zip(names, dets))
                         + f"): the first {n} of each used")
        return [_pick(d, np.arange(n), d.times_s[:n]) for d in dets], notes
    ref = int(np.argmin(rates))
    span = min((d.n_frames - 1) / r for d, r in zip(dets, rates))   # seconds every clip covers
    t = np.arange(int(np.floor(span * rates[ref] + 1e-9)) + 1) / rates[ref]
    out = [_pick(d, np.minimum(np.rint(t * r).astype(np.int64), d.n_frames - 1), t) for d, r in zip(dets, rates)]
    return out, [f"frame rates differ ({listing}): aligned by time stamp on {names[ref]}'s {len(t)} frames"]


def multiview_trial(dets: list[Detections], cameras: list[Camera], **tri_kw) -> tuple[SkeletonTrial, Triangulation]:
    """N cameras' detections on common frames (:func:`aligned`) triangulated into a Kinect v2 trial
    (world of the calibration, m) and the triangulation (errors, cameras used, quality)."""
    uv = np.stack([d.image for d in dets])
    conf = np.stack([d.visibility for d in dets])
    tri = triangulate_frames(cameras, uv, conf, **tri_kw)
    T = uv.shape[1]
    notes = [n for d in dets for n in d.notes]
    rate = 1.0 / np.median(np.diff(dets[0].times_s)) if T > 1 else dets[0].info.fps
    trial = landmarks_trial(tri.points, np.ones(tri.quality.shape), dets[0].times_s[:T], rate,
                            good=0.5, missing=0.5, quality=tri.quality, source="video_multiview",
                            conversions=[f"{len(cameras)} cameras ({', '.join(c.name for c in cameras)}) "
                                         "triangulated; calibration world frame, mm to m"], notes=notes)
    return trial, tri


def synchronised(dets: list[Detections], cameras: list[Camera]) -> tuple[list[Detections], list[str]]:
    """The detections (on common frames) with each camera resampled at its time offset found by
    :func:`mocapgraph.video.sync.estimate_offsets` over the body's joints (shoulders to ankles),
    and a note of the offsets and the median reprojection error before and after."""
    from .estimator import LANDMARK_NAMES
    from .sync import estimate_offsets, shifted
    body = np.array([i for i, n in enumerate(LANDMARK_NAMES)
                     if n.split("_")[-1] in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")])
    off, before, after = estimate_offsets(cameras, np.stack([d.image for d in dets]),
                                          np.stack([d.visibility for d in dets]), body)
    out = [d if s == 0 else Detections(d.info, shifted(d.image, s), np.nan_to_num(shifted(d.visibility, s)),
                                       shifted(d.world, s), d.found, d.times_s, d.ms_per_frame, d.notes)
           for d, s in zip(dets, off)]
    rate = dets[0].info.fps
    listing = ", ".join(f"{c.name} {s:+g} frames ({1000 * s / rate:+.0f} ms)" for c, s in zip(cameras[1:], off[1:]))
    return out, [f"time offsets from the detections, against {cameras[0].name}: {listing}; median reprojection "
                 f"error {before:.1f} -> {after:.1f} px"]


def multiview_from_files(calibration: str | Path, videos: list[Path] | None = None, progress=None, sync: bool = False,
                         pose_model: str = "auto",
                         **tri_kw) -> tuple[SkeletonTrial, Triangulation, list[Detections], list[Camera]]:
    """Read the calibration, match every video to its camera (before any estimation), detect (the
    heavy model when installed: :mod:`.pose_models`), align (and with ``sync``, find and undo the
    cameras' time offsets: :func:`synchronised`), triangulate."""
    videos = [Path(v) for v in videos] if videos else videos_beside(calibration)
    cams = cameras_for(calibration, videos)
    dets = [require_person(detect_video(v, progress=progress, model=pose_model)) for v in videos]
    dets, notes = aligned(dets, [v.stem for v in videos])
    if sync:
        dets, more = synchronised(dets, cams)
        notes += more
    trial, tri = multiview_trial(dets, cams, **tri_kw)
    trial.notes.extend(notes)
    return trial, tri, dets, cams


def calibrated_lengths(P: np.ndarray, good: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """[J] each bone's median length over the frames of P [T, J, 3] whose two ends are good
    (bool [T, J]); NaN for roots and bones never seen."""
    par = np.asarray(parents)
    child = np.flatnonzero(par >= 0)
    lengths = np.full(len(par), np.nan)
    seg = np.linalg.norm(P[:, child] - P[:, par[child]], axis=-1)       # [T, C]
    both = good[:, child] & good[:, par[child]]
    seen = both.any(axis=0)
    lengths[child[seen]] = np.nanmedian(np.where(both, seg, np.nan)[:, seen], axis=0)
    return lengths


def hold_bones(P: np.ndarray, parents: np.ndarray, order, lengths: np.ndarray) -> np.ndarray:
    """P [T, J, 3] with every bone of known length put back at it: each child along its observed
    direction from its (already placed) parent, parents first (``order``: topological); a joint whose
    parent is missing keeps its position."""
    out = P.copy()
    for j in order:          # once per joint for the whole clip (vectorised over frames)
        p = parents[j]
        if p < 0 or not np.isfinite(lengths[j]):
            continue
        d = P[:, j] - P[:, p]
        n = np.linalg.norm(d, axis=-1, keepdims=True)
        ok = np.isfinite(out[:, p]).all(-1) & np.isfinite(n[:, 0]) & (n[:, 0] > 1e-9)
        out[ok, j] = out[ok, p] + d[ok] / n[ok] * lengths[j]
    return out


def hold_bone_lengths(trial: SkeletonTrial, calibrate_s: float) -> tuple[SkeletonTrial, np.ndarray]:
    """The trial with every bone held at its length calibrated over the first ``calibrate_s``
    seconds (median over the frames whose two ends are tracked, :func:`calibrated_lengths`), as
    the marker calibration holds its segments (:func:`hold_bones`). Returns the new trial and the
    lengths [J] (NaN for roots and bones never seen in the calibration)."""
    calib = trial.times_s <= calibrate_s
    good = (trial.tracking_state == 2) & calib[:, None]
    lengths = calibrated_lengths(trial.positions, good, trial.parents)
    out = hold_bones(trial.positions, trial.parents, trial.topological_order, lengths)
    held = SkeletonTrial(trial.names, trial.parents, out, trial.tracking_state, trial.timestamps_ns, trial.rate_hz,
                         source=trial.source, notes=list(trial.notes), extra=dict(trial.extra),
                         conversions=list(trial.conversions) + [f"bone lengths held at their median over the "
                                                                f"first {calibrate_s:g} s"])
    return held, lengths
