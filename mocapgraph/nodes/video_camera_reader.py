"""Live markerless skeleton source: a camera (or a video streamed as if live) through the pose estimator.

A worker thread reads frames and runs the estimator; the node's loop publishes each result as it
comes (``skeleton_pose`` stamped with the frame's capture time). Frames that arrive while the
estimator is busy are skipped (counted): the stream stays live rather than falling behind. The
latched ``skeleton_info`` is sent after ``calibrate_s`` seconds of frames, its rest offsets the
bone lengths observed over them (the short calibration of a stream without a rest pose).

Every estimated frame's 2D landmarks also go out on ``landmarks`` (``ImageLandmarks``, stamped
with the capture time) for ``multiview_live``, which triangulates several cameras. A file streamed
as if live is a camera whose frame ``k`` is captured at ``epoch + t_k / rate_scale`` (every
``every``-th frame of the file): ``start_at`` gives the epoch that the cameras of one rig share.
"""
from __future__ import annotations

import math
import queue
import threading
import time
from typing import Any

import numpy as np

from ..bus import Output, Param
from ..formats.kinect_csv import KINECT_V2_JOINTS, KINECT_V2_PARENTS
from ..kinematics.rest_offsets import observed_rest_offsets
from ..messages import ImageLandmarks, SkeletonInfo, SkeletonPose
from .source_base import INPUT_ERRORS, SourceNode, resolve_data_path
from .video_pose_reader import _video


class VideoCameraReader(SourceNode):
    """A camera's (``camera: 0``) or a video's (``camera: path``, paced at its own rate) markerless
    skeleton, live: Kinect v2 joints, tracked / inferred / not tracked by the estimator's
    confidence, as ``video_pose_reader`` makes them. The status says how far the estimator keeps
    up: frames read, estimated, skipped, and the estimated rate against the camera's."""

    summary = "live markerless skeleton from a camera (or a video streamed as if live), mediapipe on the CPU"
    skeleton_pose = Output("skeleton_pose", SkeletonPose, "joint positions (m, world), tracking state, "
                           "skeleton_info order")
    skeleton_info = Output("skeleton_info", SkeletonInfo, "latched joint names, parents, rest offsets "
                           "(observed over the first calibrate_s)")
    landmarks = Output("landmarks", ImageLandmarks, "every estimated frame's 2D landmarks (px, capture-stamped), "
                       "for multiview_live")
    camera = Param("0", "camera device index (0, camera:0) or a video file streamed at its own rate")
    camera_name = Param("", "the camera's name in the calibration (empty: the file's stem, or cameraN)")
    rate_scale = Param(1.0, "a file streamed as if live: its speed (0.25: four times slower)", minimum=0.01)
    every = Param(1, "a file streamed as if live: take every k-th frame (a camera at the file's rate / k)",
                  minimum=1)
    start_at = Param(0.0, "a file streamed as if live: wall-clock time (unix s) of its first frame, shared by "
                          "the cameras of a rig; -S: the next multiple of S s at least 2 s after start; 0: at once")
    width = Param(640, "requested camera width, px (a file keeps its own)", minimum=0)
    height = Param(480, "requested camera height, px", minimum=0)
    good = Param(0.8, "estimator confidence from which a joint is tracked (good)", minimum=0.0, maximum=1.0)
    missing = Param(0.5, "confidence under which a joint is not tracked (NaN)", minimum=0.0, maximum=1.0)
    ground = Param("feet", "'feet': each frame's lowest foot at Z = 0; 'hips': the hips at the origin",
                   choices=("feet", "hips"))
    calibrate_s = Param(1.0, "seconds of frames whose bone lengths make skeleton_info's rest offsets", minimum=0.0)
    source_id = Param("body0", "performer / body id carried in every SkeletonPose")
    pose_model = Param("full", "estimator model: full (in mediapipe's wheel; the live default for speed) or heavy "
                               "(more accurate, ~3x the cost; installed by scripts/setup.sh)",
                       choices=("full", "heavy"))

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self._results: queue.Queue = queue.Queue(maxsize=8)
        self._quit = threading.Event()
        self._worker: threading.Thread | None = None
        self._calib: list[np.ndarray] = []
        self._t_first: float | None = None
        self._started_wall = 0.0
        self.cam_name = ""
        self.info: SkeletonInfo | None = None
        self.counts = {"read": 0, "estimated": 0, "skipped": 0, "no_person": 0, "published": 0}
        self.source_fps = 0.0
        self.estimator_ms = float("nan")

    def on_start(self) -> None:
        self._started_wall = time.time()           # first: the cameras of a rig start within milliseconds
        try:
            from ..video.frames import camera_index
            src = self.camera
            self._source = camera_index(src) if camera_index(src) is not None else resolve_data_path(str(src))
        except INPUT_ERRORS as exc:
            self.fail(str(exc))
            return
        self._worker = threading.Thread(target=self._produce, name=f"{self.name}-estimator", daemon=True)
        self._worker.start()
        self.set_state("starting", f"opening {self.camera}")
        self.add_timer(0.005, self._drain, first_delay_s=0.0)

    # ----- worker thread: frames -> estimator -> queue ----------------------------------------------
    def _epoch(self) -> float:
        """Wall-clock time (s) of a streamed file's first frame (see ``start_at``)."""
        if self.start_at > 0:
            return self.start_at
        if self.start_at < 0:
            step = -self.start_at
            return math.ceil((self._started_wall + 2.0) / step) * step
        return time.time()

    def _produce(self) -> None:
        from ..video.estimator import PoseEstimator
        from ..video.frames import VideoFrames
        try:
            _video()                                # the extra installed (imported here: on_start stays quick)
            frames = VideoFrames(self._source, width=self.width, height=self.height)
            est = PoseEstimator(model=self.pose_model)
        except Exception as exc:  # noqa: BLE001 - a VideoError, or the estimator failing: one line via the loop
            self._results.put(exc)
            return
        live_file = frames.camera is None
        info = frames.info
        self.source_fps = info.fps * self.rate_scale / self.every if live_file else info.fps
        self.cam_name = self.camera_name or (self._source.stem if live_file else f"camera{frames.camera}")
        epoch = None                                # a file's clock starts once the estimator is warm
        try:
            for i, t, frame in frames:
                if self._quit.is_set():
                    break
                if live_file and i % self.every:
                    continue
                self.counts["read"] += 1
                stamp = time.time_ns()
                if live_file:                        # a file streamed as if live: wait for its time, skip
                    if epoch is None:                # the frames the estimator was too slow for
                        est.process(frame)           # the first estimate warms the models up (slow)
                        epoch = self._epoch()
                    due = epoch + t / self.rate_scale
                    lag = time.time() - due
                    if lag > 1.0 / self.source_fps:
                        self.counts["skipped"] += 1
                        continue
                    if lag < 0:
                        time.sleep(-lag)
                    stamp = int(round(due * 1e9))
                self._estimate(est, i, stamp, frame)
            self._results.put(None)                # the end of a file
        except Exception as exc:  # noqa: BLE001
            self._results.put(exc)
        finally:
            est.close()
            frames.close()

    def _estimate(self, est, index: int, stamp: int, frame: np.ndarray) -> None:
        from ..video.estimator import N_LANDMARKS, single_view_points
        c0 = time.perf_counter()
        r = est.process(frame)
        ms = 1000 * (time.perf_counter() - c0)
        self.estimator_ms = ms if self.estimator_ms != self.estimator_ms else 0.9 * self.estimator_ms + 0.1 * ms
        self.counts["estimated"] += 1
        size = (frame.shape[1], frame.shape[0])
        if r is None:
            self.counts["no_person"] += 1
            self._put((index, stamp, None, np.full((N_LANDMARKS, 2), np.nan), np.zeros(N_LANDMARKS), size))
            return
        P = single_view_points(r[2][None], r[1][None], missing=self.missing, ground=self.ground)
        self._put((index, stamp, P, r[0], r[1], size))

    def _put(self, item) -> None:
        try:
            self._results.put_nowait(item)
        except queue.Full:                         # the loop fell behind: the oldest result goes
            try:
                self._results.get_nowait()
                self.counts["skipped"] += 1
            except queue.Empty:
                pass
            self._results.put_nowait(item)

    # ----- node loop: publish ------------------------------------------------------------------------
    def _drain(self) -> None:
        from ..video.estimator import kinect_joints
        while True:
            try:
                item = self._results.get_nowait()
            except queue.Empty:
                return
            if item is None:
                if self.info is None and self._calib:      # a stream shorter than calibrate_s
                    self._latch_info()
                self.set_state("finished", f"{self.counts['estimated']} frames estimated", 1.0)
                self.request_stop()
                return
            if isinstance(item, Exception):
                self.fail(str(item) if isinstance(item, INPUT_ERRORS) else f"{self.camera}: {type(item).__name__}: {item}")
                return
            index, stamp, P, uv, vis, size = item
            self.landmarks.publish(ImageLandmarks(camera=self.cam_name, frame_number=int(index), width=size[0],
                                                  height=size[1], rate_hz=float(self.source_fps), points=uv,
                                                  confidence=vis.astype(np.float32)), capture_ns=stamp)
            if P is None:
                continue
            joints, q = kinect_joints(P, vis[None], good=self.good, missing=self.missing)
            if self.info is None and not self._calibrating(joints[0], q[0]):
                continue
            self.skeleton_pose.publish(SkeletonPose(source_id=self.source_id, frame_number=int(index),
                                                    joint_positions=joints[0],
                                                    joint_orientations=np.full((len(KINECT_V2_JOINTS), 4), np.nan),
                                                    tracking_state=q[0]), capture_ns=stamp)
            self.counts["published"] += 1

    def _calibrating(self, joints: np.ndarray, q: np.ndarray) -> bool:
        """Collect tracked joints for ``calibrate_s``; then latch skeleton_info. True once latched."""
        now = time.monotonic()
        self._t_first = self._t_first or now
        self._calib.append(np.where((q == 2)[:, None], joints, np.nan))
        if now - self._t_first < self.calibrate_s:
            self.set_state("calibrating", f"{len(self._calib)} frames of {self.calibrate_s:g} s")
            return False
        self._latch_info()
        self.set_state("streaming", f"{self.camera}")
        return True

    def _latch_info(self) -> None:
        rest = observed_rest_offsets(np.array(self._calib), np.array(KINECT_V2_PARENTS))
        self.info = SkeletonInfo(source="video_mediapipe", joint_names=list(KINECT_V2_JOINTS),
                                 joint_parent=np.array(KINECT_V2_PARENTS, dtype=np.int32), rest_offsets=rest,
                                 units_note=f"live {self.camera}: mediapipe pose landmarks as Kinect v2 joints; "
                                            f"X toward the camera, Z up; ground={self.ground}; rest offsets "
                                            f"observed over {len(self._calib)} frames")
        self.skeleton_info.publish(self.info)

    def status_data(self) -> dict[str, Any]:
        d: dict[str, Any] = dict(self.counts)
        d["source_fps"] = round(float(self.source_fps), 2)
        d["estimator_ms"] = round(float(self.estimator_ms), 1)
        if self.estimator_ms == self.estimator_ms and self.source_fps:
            d["keeps_up"] = round(min(1.0, 1000.0 / self.estimator_ms / self.source_fps), 2)
        return d

    def on_stop(self) -> None:
        self._quit.set()
        if self._worker is not None:
            self._worker.join(2.0)
