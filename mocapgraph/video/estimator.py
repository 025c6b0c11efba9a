"""The CPU pose estimator (mediapipe's pose landmarker) and its 33 landmarks as a Kinect v2 skeleton.

mediapipe 0.10.14 (the ``video`` extra) ships its full pose landmark model and the person
detector inside the wheel (``mediapipe/modules/pose_*``), so nothing is fetched at run time: the
legacy ``mediapipe.solutions.pose`` graph runs it with ``model_complexity=1`` (``full``, the one in
the wheel) or 2 (``heavy``, installed from npm by scripts/setup.sh: :mod:`.pose_models`; refused
when absent, so mediapipe never downloads it). Per frame it gives 33 landmarks: image position
(normalised, made pixels here), a visibility in [0, 1], and a metric 3D estimate centred
between the hips (camera-aligned axes: x right, y down, z away from the camera).

The landmarks become the 25 joints of the Kinect v2 skeleton (names and parents of
:mod:`mocapgraph.formats.kinect_csv`) by fixed linear combinations (:data:`KINECT_FROM_LANDMARKS`),
so every Kinect v2 mapping and the automatic derivation serve a video source. A joint's
confidence is the lowest visibility of the landmarks it is made of; below ``good`` it is
estimated, below ``missing`` it is missing (NaN), never good.
"""
from __future__ import annotations

import contextlib
import os
import sys
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..formats.kinect_csv import KINECT_V2_JOINTS, KINECT_V2_PARENTS
from ..formats.skeleton_trial import SkeletonTrial
from ..messages.quality import QUALITY_ESTIMATED, QUALITY_GOOD, QUALITY_MISSING
from .frames import VideoFrames, VideoInfo, VideoUnavailable
from .pose_models import COMPLEXITY, INSTALL_HINT, POSE_MODELS, installed, resolve

# mediapipe's C++ side logs through glog/absl on stderr: keep only errors
os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

N_LANDMARKS = 33
LANDMARK_NAMES: tuple[str, ...] = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
    "right_ankle", "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)
_L = {n: i for i, n in enumerate(LANDMARK_NAMES)}


def _kinect_weights() -> np.ndarray:
    """[25, 33] weights: Kinect v2 joint = weights @ landmarks."""
    hips = {"left_hip": 0.5, "right_hip": 0.5}
    shoulders = {"left_shoulder": 0.5, "right_shoulder": 0.5}
    ears = {"left_ear": 0.5, "right_ear": 0.5}
    recipe: dict[str, dict[str, float]] = {
        "SpineBase": hips,
        "SpineMid": {k: 0.5 * v for d in (hips, shoulders) for k, v in d.items()},
        "SpineShoulder": shoulders,
        "Neck": {**{k: 0.7 * v for k, v in shoulders.items()}, **{k: 0.3 * v for k, v in ears.items()}},
        "Head": ears,
    }
    for side, s in (("Left", "left"), ("Right", "right")):
        recipe.update({
            f"Shoulder{side}": {f"{s}_shoulder": 1.0}, f"Elbow{side}": {f"{s}_elbow": 1.0},
            f"Wrist{side}": {f"{s}_wrist": 1.0}, f"Hand{side}": {f"{s}_pinky": 0.5, f"{s}_index": 0.5},
            f"HandTip{side}": {f"{s}_index": 1.0}, f"Thumb{side}": {f"{s}_thumb": 1.0},
            f"Hip{side}": {f"{s}_hip": 1.0}, f"Knee{side}": {f"{s}_knee": 1.0},
            f"Ankle{side}": {f"{s}_ankle": 1.0}, f"Foot{side}": {f"{s}_foot_index": 1.0},
        })
    W = np.zeros((len(KINECT_V2_JOINTS), N_LANDMARKS))
    for j, name in enumerate(KINECT_V2_JOINTS):
        for lm, w in recipe[name].items():
            W[j, _L[lm]] = w
    return W


#: [25, 33]: Kinect v2 joint positions = KINECT_FROM_LANDMARKS @ landmark positions
KINECT_FROM_LANDMARKS = _kinect_weights()
FOOT_LANDMARKS = np.array([_L[n] for n in ("left_heel", "right_heel", "left_foot_index", "right_foot_index")])


def kinect_confidence(landmark_conf: np.ndarray) -> np.ndarray:
    """[..., 25] each Kinect joint's confidence: the lowest of its landmarks' ([..., 33])."""
    c = np.asarray(landmark_conf, dtype=np.float64)
    used = KINECT_FROM_LANDMARKS > 0
    return np.min(np.where(used, c[..., None, :], np.inf), axis=-1)


def quality_from_confidence(conf: np.ndarray, good: float, missing: float) -> np.ndarray:
    """int8 quality codes: good at or above ``good``, estimated from ``missing``, else missing."""
    c = np.nan_to_num(np.asarray(conf, dtype=np.float64), nan=0.0)
    return np.where(c >= good, QUALITY_GOOD, np.where(c >= missing, QUALITY_ESTIMATED, QUALITY_MISSING)).astype(np.int8)


@dataclass
class Detections:
    """One camera's estimates over a video: NaN / 0 where no person was found.

    image: [T, 33, 2] pixels (x right, y down); visibility: [T, 33] in [0, 1];
    world: [T, 33, 3] m, camera-aligned, origin between the hips; found: bool [T];
    times_s: [T]; ms_per_frame: the estimator's mean cost.
    """

    info: VideoInfo
    image: np.ndarray
    visibility: np.ndarray
    world: np.ndarray
    found: np.ndarray
    times_s: np.ndarray
    ms_per_frame: float = float("nan")
    notes: list[str] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return int(len(self.found))


@contextlib.contextmanager
def _native_stderr_silenced():
    """File descriptor 2 to /dev/null for a moment: mediapipe's C++ side (TFLite, absl) prints a
    few lines on its graph's start and first frame that are no fault of the input."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


class PoseEstimator:
    """mediapipe's pose landmarker on BGR frames (model from the wheel; CPU)."""

    def __init__(self, *, min_detection: float = 0.5, min_tracking: float = 0.5, smooth: bool = True,
                 static_images: bool = False, model: str = "full") -> None:
        """model: "full" (in mediapipe's wheel), "heavy" (more accurate, ~3x the cost; from npm,
        :mod:`.pose_models`) or "auto" (heavy when installed); a model that is not installed is
        refused, never downloaded."""
        try:
            from mediapipe.python.solutions import pose as mp_pose
        except ImportError:
            raise VideoUnavailable("mediapipe is not installed: pip install 'mocapgraph[video]'") from None
        model, note = resolve(model)
        if note:
            warnings.warn(note, RuntimeWarning, stacklevel=2)
        if model not in POSE_MODELS:
            raise VideoUnavailable(f"unknown pose model {model!r} (expected {' or '.join(POSE_MODELS)})")
        if not installed(model):
            raise VideoUnavailable(f"the {model} pose model is not installed: {INSTALL_HINT}")
        self.model = model
        from .frames import cv2_module
        self._cv2 = cv2_module()
        # mediapipe 0.10.14 calls a protobuf API that protobuf 4.25 marks deprecated, on every frame
        warnings.filterwarnings("ignore", message="SymbolDatabase.GetPrototype", category=UserWarning)
        self._quiet = True              # until the first person: the landmark model starts then
        # the graph opens its calculators in threads after the constructor returns, printing as they
        # go: a blank frame run at once waits for them, inside the window where fd 2 is silenced
        with _native_stderr_silenced():
            self._pose = mp_pose.Pose(static_image_mode=static_images, model_complexity=COMPLEXITY[model], smooth_landmarks=smooth,
                                      enable_segmentation=False, min_detection_confidence=min_detection,
                                      min_tracking_confidence=min_tracking)
            self._pose.process(np.zeros((64, 64, 3), np.uint8))

    def process(self, frame_bgr: np.ndarray):
        """(image [33, 2] px, visibility [33], world [33, 3] m) of one frame, or None: no person."""
        h, w = frame_bgr.shape[:2]
        rgb = self._cv2.cvtColor(frame_bgr, self._cv2.COLOR_BGR2RGB)
        if self._quiet:                    # its start-up notes (anything else on fd 2 then is lost too)
            with _native_stderr_silenced():
                res = self._pose.process(rgb)
            self._quiet = res.pose_landmarks is None
        else:
            res = self._pose.process(rgb)
        if res.pose_landmarks is None:
            return None
        lm = np.array([(p.x, p.y, p.visibility) for p in res.pose_landmarks.landmark], dtype=np.float64)
        wl = np.array([(p.x, p.y, p.z) for p in res.pose_world_landmarks.landmark], dtype=np.float64)
        return lm[:, :2] * (w, h), np.clip(lm[:, 2], 0.0, 1.0), wl

    def close(self) -> None:
        self._pose.close()


def detect_video(source, *, max_frames: int = 0, progress=None, **estimator_kw) -> Detections:
    """Run the estimator over a video file (or ``max_frames`` of a camera). VideoError for an
    unreadable file; frames without a person are NaN, ``found`` False."""
    frames = VideoFrames(source)
    est = PoseEstimator(**estimator_kw)
    img, vis, world, found, times = [], [], [], [], []
    spent = 0.0
    try:
        for i, t, frame in frames:
            t0 = time.perf_counter()
            r = est.process(frame)
            spent += time.perf_counter() - t0
            times.append(t)
            found.append(r is not None)
            if r is None:
                r = (np.full((N_LANDMARKS, 2), np.nan), np.zeros(N_LANDMARKS), np.full((N_LANDMARKS, 3), np.nan))
            img.append(r[0]); vis.append(r[1]); world.append(r[2])
            if progress is not None:
                progress(i + 1, frames.info.frame_count)
            if max_frames and i + 1 >= max_frames:
                break
    finally:
        est.close()
        frames.close()
    n = len(found)
    det = Detections(frames.info, np.array(img).reshape(n, N_LANDMARKS, 2), np.array(vis).reshape(n, N_LANDMARKS),
                     np.array(world).reshape(n, N_LANDMARKS, 3), np.array(found, dtype=bool),
                     np.array(times, dtype=np.float64), 1000.0 * spent / max(n, 1), list(frames.info.notes))
    if n and not det.found.any():
        det.notes.append("no person found in any frame")
    return det


# camera axes (x right, y down, z away) -> world (X toward the camera = the facing person's forward,
# Y = the person's left = camera right, Z up)
CAMERA_TO_WORLD = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def single_view_points(world: np.ndarray, visibility: np.ndarray, *, missing: float = 0.5,
                       ground: str = "feet") -> np.ndarray:
    """Landmarks [T, 33, 3] m in world axes (X toward the camera, Y to the camera's right, Z up)
    from the estimator's camera-aligned, hip-centred ones; ``ground='feet'`` puts each frame's
    lowest foot landmark seen with at least ``missing`` confidence at Z = 0."""
    P = np.asarray(world, dtype=np.float64) @ CAMERA_TO_WORLD.T
    if ground == "feet":
        feet_z = np.where(np.asarray(visibility)[:, FOOT_LANDMARKS] >= missing, P[:, FOOT_LANDMARKS, 2], np.inf)
        low = feet_z.min(axis=1)
        seen = np.isfinite(low)
        low = np.where(seen, low, np.median(low[seen]) if seen.any() else 0.0)
        P[..., 2] -= low[:, None]
    return P


def single_view_trial(det: Detections, *, good: float = 0.8, missing: float = 0.5, ground: str = "feet") -> SkeletonTrial:
    """A one-camera Kinect v2 SkeletonTrial from the estimator's metric landmarks.

    Axes: X toward the camera, Y to the camera's right, Z up, metres. The estimator's 3D is
    centred between the hips (no travel through the room): ``ground='feet'`` puts each frame's
    lowest visible foot landmark at Z = 0, ``'hips'`` keeps the hips at the origin.
    """
    P = single_view_points(det.world, det.visibility, missing=missing, ground=ground)
    return landmarks_trial(P, det.visibility, det.times_s, det.info.fps, good=good, missing=missing,
                           source="video_mediapipe", conversions=[
                               f"{det.info.name}: mediapipe pose landmarks (metric, hip-centred) as Kinect v2 "
                               f"joints; camera axes to X toward the camera, Z up; ground={ground}"],
                           notes=list(det.notes))


def kinect_joints(points: np.ndarray, confidence: np.ndarray, *, good: float, missing: float,
                  quality: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Kinect v2 joints [T, 25, 3] (NaN where missing) and their quality [T, 25] from landmark
    positions [T, 33, 3] and confidences [T, 33] (or explicit landmark ``quality`` codes [T, 33],
    which then cap the joints' own)."""
    joints = np.einsum("jl,tlk->tjk", KINECT_FROM_LANDMARKS, np.nan_to_num(points, nan=0.0))
    q = quality_from_confidence(kinect_confidence(confidence), good, missing)
    if quality is not None:
        q = np.minimum(q, kinect_confidence(quality).astype(np.int8))
    bad = ~np.isfinite(points).all(-1)                                  # [T, 33]
    q[(bad[:, None, :] & (KINECT_FROM_LANDMARKS > 0)[None]).any(-1)] = QUALITY_MISSING
    joints[q == QUALITY_MISSING] = np.nan
    return joints, q


def landmarks_trial(points: np.ndarray, confidence: np.ndarray, times_s: np.ndarray, rate_hz: float, *,
                    good: float, missing: float, source: str, conversions: list[str], notes: list[str],
                    quality: np.ndarray | None = None) -> SkeletonTrial:
    """Kinect v2 SkeletonTrial from landmark positions [T, 33, 3] (m, world) and confidences [T, 33]
    (see :func:`kinect_joints`)."""
    joints, q = kinect_joints(points, confidence, good=good, missing=missing, quality=quality)
    ts = np.round(np.asarray(times_s) * 1e9).astype(np.int64)
    return SkeletonTrial(list(KINECT_V2_JOINTS), np.array(KINECT_V2_PARENTS), joints, q, ts, rate_hz,
                         source=source, conversions=conversions, notes=notes)
