"""Video skeleton sources: one camera's markerless pose, or several calibrated cameras triangulated.

Both run the CPU pose estimator (mediapipe, the ``video`` extra; :mod:`mocapgraph.video`) over
the whole clip, then replay the skeleton like any other skeleton source (``skeleton_pose`` +
latched ``skeleton_info``, Kinect v2 joint names, so the Kinect v2 mappings serve). Building the
node only checks the inputs (the video opens, the calibration has its cameras), so the graph
starts at once whatever the clip's length; the estimation runs after start in a worker thread
(state ``estimating``, its progress in the status), then playback begins.
"""
from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np

from ..bus import Param
from ..formats import SkeletonTrial
from .skeleton_source import SkeletonFilePlayer
from .source_base import INPUT_ERRORS, FilePlayback, SourceError, resolve_data_path

POSE_MODELS = ("auto", "full", "heavy")   # mocapgraph.video.pose_models.CHOICES (not imported: the launcher
                                          # imports this module to check a graph, without the video part)


def _video():
    """The video part, or SourceError (one line) when its extra is not installed."""
    from ..video import capture, frames
    try:
        frames.cv2_module()
        import mediapipe  # noqa: F401
    except (frames.VideoUnavailable, ImportError):
        raise SourceError("the pose estimator is not installed: pip install 'mocapgraph[video]'") from None
    return capture


def _opens(path: Path) -> None:
    """VideoError (one line) unless the video opens."""
    from ..video.frames import VideoFrames
    VideoFrames(path).close()


class _EstimatedPlayer(SkeletonFilePlayer):
    """A skeleton file player whose trial comes from the estimator, computed after the graph starts."""

    def load(self, path: Path) -> None:
        self._capture = _video()
        self._load_path = path
        from ..video.pose_models import INSTALL_HINT, installed, resolve
        model, note = resolve(self.pose_model)
        if note:
            self.log.warning("%s", note)
        if not installed(model):
            raise SourceError(f"the {model} pose model is not installed: {INSTALL_HINT}")
        self._pose_model = model
        self.check_inputs(path)

    def check_inputs(self, path: Path) -> None:
        raise NotImplementedError

    def on_start(self) -> None:
        if self.load_error:
            self.fail(self.load_error)
            return
        self._load_fault = ""
        self._loader = threading.Thread(target=self._estimate, name=f"{self.name}-estimator", daemon=True)
        self.set_state("estimating", f"{self._load_path.name}", 0.0)
        self._loader.start()
        self._wait_timer = self.add_timer(0.1, self._wait_for_estimate)

    def _estimate(self) -> None:
        try:
            SkeletonFilePlayer.load(self, self._load_path)
        except INPUT_ERRORS as exc:
            self._load_fault = str(exc)
        except Exception as exc:  # noqa: BLE001 - whatever the estimator says, in one line
            self._load_fault = f"{self._load_path.name}: {type(exc).__name__}: {exc}"

    def _progress(self, done: int, total: int) -> None:
        self.progress = done / total if total > 0 else float("nan")

    def _wait_for_estimate(self) -> None:
        if self._loader.is_alive():
            return
        self._wait_timer.cancel()
        if self._load_fault:
            self.fail(self._load_fault)
            return
        FilePlayback.on_start(self)


class VideoPoseReader(_EstimatedPlayer):
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
    pose_model = Param("full", "estimator model: full (in mediapipe's wheel; its metric 3D estimate is the "
                               "better one), heavy (installed by scripts/setup.sh) or auto (heavy when installed)",
                       choices=POSE_MODELS)

    def check_inputs(self, path: Path) -> None:
        _opens(path)

    def read_trial(self, path: Path) -> SkeletonTrial:
        trial, det = self._capture.video_trial(path, good=self.good, missing=self.missing, ground=self.ground,
                                               progress=self._progress, pose_model=self._pose_model)
        self.found = int(det.found.sum())
        self.ms_per_frame = det.ms_per_frame
        return trial

    def source_kind(self, trial: SkeletonTrial) -> str:
        return "video_mediapipe"

    def status_data(self) -> dict[str, Any]:
        d = super().status_data()
        d["person_frames"] = getattr(self, "found", 0)
        d["pose_model"] = getattr(self, "_pose_model", "")
        d["estimator_ms"] = round(float(getattr(self, "ms_per_frame", np.nan)), 1)
        return d


class MultiviewPose(_EstimatedPlayer):
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
    sync = Param(False, "find each camera's time offset from the detections and undo it (videos not started "
                        "together)")
    pose_model = Param("auto", "estimator model: heavy (its landmarks keep every bone within 5 %; installed by "
                               "scripts/setup.sh), full (in mediapipe's wheel, ~3x faster) or auto (heavy when "
                               "installed)", choices=POSE_MODELS)

    def check_inputs(self, path: Path) -> None:
        self._videos = [resolve_data_path(str(v)) for v in (self.videos or [])] or self._capture.videos_beside(path)
        self._capture.cameras_for(path, self._videos)
        for v in self._videos:
            _opens(v)

    def read_trial(self, path: Path) -> SkeletonTrial:
        from ..video.multiview import camera_report
        n = len(self._videos)
        video = [-1]

        def progress(k: int, total: int) -> None:     # the videos are estimated one after the other
            video[0] += k == 1
            self._progress(video[0] * total + k, total * n)

        trial, tri, dets, cams = self._capture.multiview_from_files(path, self._videos, progress=progress,
                                                                    sync=self.sync, pose_model=self._pose_model,
                                                                    reject_px=self.reject_px, good_px=self.good_px)
        if self.hold_bones_s > 0:
            trial, _ = self._capture.hold_bone_lengths(trial, self.hold_bones_s)
        self.camera_errors = {d.info.name: round(float(np.nanmedian(tri.error_px[k])), 1) for k, d in enumerate(dets)}
        for line in camera_report(cams, tri):
            self.log.warning("%s", line)
        for note in trial.notes:
            if note.startswith("time offsets"):
                self.log.info("%s", note)
        return trial

    def source_kind(self, trial: SkeletonTrial) -> str:
        return "video_multiview"

    def status_data(self) -> dict[str, Any]:
        d = super().status_data()
        d["reprojection_px"] = getattr(self, "camera_errors", {})
        d["pose_model"] = getattr(self, "_pose_model", "")
        return d
