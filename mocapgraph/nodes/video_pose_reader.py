"""Video skeleton sources: one camera's markerless pose, or several calibrated cameras triangulated.

Both run the CPU pose estimator (mediapipe, the ``video`` extra; :mod:`mocapgraph.video`) over
the whole clip at load, then replay the skeleton like any other skeleton source (``skeleton_pose``
+ latched ``skeleton_info``, Kinect v2 joint names, so the Kinect v2 mappings serve).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..bus import Param
from ..formats import SkeletonTrial
from .skeleton_source import SkeletonFilePlayer
from .source_base import SourceError, resolve_data_path


def _video():
    """The video part, or SourceError (one line) when its extra is not installed."""
    from ..video import capture, frames
    try:
        frames.cv2_module()
        import mediapipe  # noqa: F401
    except (frames.VideoUnavailable, ImportError):
        raise SourceError("the pose estimator is not installed: pip install 'mocapgraph[video]'") from None
    return capture


class VideoPoseReader(SkeletonFilePlayer):
    """Plays a video's markerless pose as ``skeleton_pose`` + latched ``skeleton_info``.

    One camera: mediapipe's metric 3D estimate (centred between the hips, so no travel through
    the room) as the 25 Kinect v2 joints; X toward the camera, Z up; ``ground: feet`` puts each
    frame's lowest foot on Z = 0. Per joint: tracked when the estimator's confidence is at least
    ``good``, inferred from ``missing``, else not tracked (NaN). A video with no person is refused.
    """

    summary = "estimate a skeleton from a video file (one camera, mediapipe on the CPU) as SkeletonPose"
    good = Param(0.8, "estimator confidence from which a joint is tracked (good)", minimum=0.0, maximum=1.0)
    missing = Param(0.5, "confidence under which a joint is not tracked (NaN); between: inferred",
                    minimum=0.0, maximum=1.0)
    ground = Param("feet", "'feet': each frame's lowest foot at Z = 0; 'hips': the hips at the origin",
                   choices=("feet", "hips"))

    def read_trial(self, path: Path) -> SkeletonTrial:
        trial, det = _video().video_trial(path, good=self.good, missing=self.missing, ground=self.ground)
        self.found = int(det.found.sum())
        self.ms_per_frame = det.ms_per_frame
        return trial

    def source_kind(self, trial: SkeletonTrial) -> str:
        return "video_mediapipe"

    def status_data(self) -> dict[str, Any]:
        d = super().status_data()
        d["person_frames"] = getattr(self, "found", 0)
        d["estimator_ms"] = round(float(getattr(self, "ms_per_frame", np.nan)), 1)
        return d


class MultiviewPose(SkeletonFilePlayer):
    """Triangulates several synchronised, calibrated videos into one skeleton (``skeleton_pose``).

    ``file`` is the calibration (QTM ``.qca.txt`` or OpenCV-style TOML/YAML); ``videos`` the clips,
    each matched to its camera by file stem (empty: every video beside the calibration). World:
    the calibration's, metres. Per joint: tracked when at least three cameras agree within
    ``good_px``, inferred with two, else not tracked; a camera whose ray disagrees by more than
    ``reject_px`` is dropped for that joint. Per-camera median reprojection errors are in the
    status, and a camera far off the others (a wrong calibration) is logged. Bones are held at
    their lengths over the first ``hold_bones_s`` seconds (as the marker calibration holds its
    segments; 0 keeps the raw triangulation).
    """

    summary = "triangulate several calibrated videos' markerless poses (mediapipe) into one SkeletonPose"
    videos = Param([], "video files (one per calibrated camera, matched by file stem); empty: every video "
                       "in the calibration's folder")
    reject_px = Param(50.0, "a camera farther than this from a joint's consensus is dropped for it, px", minimum=1.0)
    good_px = Param(30.0, "reprojection error up to which a joint seen by >= 3 cameras is good, px", minimum=1.0)
    hold_bones_s = Param(1.0, "hold every bone at its median length over the first seconds (0: raw triangulation)",
                         minimum=0.0)

    def read_trial(self, path: Path) -> SkeletonTrial:
        capture = _video()
        videos = [resolve_data_path(str(v)) for v in (self.videos or [])]
        trial, tri, dets, cams = capture.multiview_from_files(path, videos or None, reject_px=self.reject_px,
                                                        good_px=self.good_px)
        names = [d.info.name for d in dets]
        self.camera_errors = {n: round(float(np.nanmedian(tri.error_px[k])), 1) for k, n in enumerate(names)}
        from ..video.multiview import camera_report
        if self.hold_bones_s > 0:
            trial, _ = capture.hold_bone_lengths(trial, self.hold_bones_s)
        for line in camera_report(cams, tri):
            self.log.warning("%s", line)
        return trial

    def source_kind(self, trial: SkeletonTrial) -> str:
        return "video_multiview"

    def status_data(self) -> dict[str, Any]:
        d = super().status_data()
        d["reprojection_px"] = getattr(self, "camera_errors", {})
        return d
