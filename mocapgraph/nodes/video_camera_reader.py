"""Live markerless skeleton source: a camera (or a video streamed as if live) through the pose estimator.

A worker thread reads frames and runs the estimator; the node's loop publishes each result as it
comes (``skeleton_pose`` stamped with the frame's capture time). Frames that arrive while the
estimator is busy are skipped (counted): the stream stays live rather than falling behind. The
latched ``skeleton_info`` is sent after ``calibrate_s`` seconds of frames, its rest offsets the
bone lengths observed over them (the short calibration of a stream without a rest pose).
"""
from __future__ import annotations

import queue
import threading
import time
from typing import Any

import numpy as np

from ..bus import Output, Param
from ..formats.kinect_csv import KINECT_V2_JOINTS, KINECT_V2_PARENTS
from ..kinematics.rest_offsets import observed_rest_offsets
from ..messages import SkeletonInfo, SkeletonPose
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
    camera = Param("0", "camera device index (0, camera:0) or a video file streamed at its own rate")
    width = Param(640, "requested camera width, px (a file keeps its own)", minimum=0)
    height = Param(480, "requested camera height, px", minimum=0)
    good = Param(0.8, "estimator confidence from which a joint is tracked (good)", minimum=0.0, maximum=1.0)
    missing = Param(0.5, "confidence under which a joint is not tracked (NaN)", minimum=0.0, maximum=1.0)
    ground = Param("feet", "'feet': each frame's lowest foot at Z = 0; 'hips': the hips at the origin",
                   choices=("feet", "hips"))
    calibrate_s = Param(1.0, "seconds of frames whose bone lengths make skeleton_info's rest offsets", minimum=0.0)
    source_id = Param("body0", "performer / body id carried in every SkeletonPose")

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self._results: queue.Queue = queue.Queue(maxsize=8)
        self._quit = threading.Event()
        self._worker: threading.Thread | None = None
        self._calib: list[np.ndarray] = []
        self._t_first: float | None = None
        self.info: SkeletonInfo | None = None
        self.counts = {"read": 0, "estimated": 0, "skipped": 0, "no_person": 0, "published": 0}
        self.source_fps = 0.0
        self.estimator_ms = float("nan")

    def on_start(self) -> None:
        try:
            capture = _video()
            from ..video.frames import camera_index
            src = self.camera
            self._source = camera_index(src) if camera_index(src) is not None else resolve_data_path(str(src))
        except INPUT_ERRORS as exc:
            self.fail(str(exc))
            return
        self._capture = capture
        self._worker = threading.Thread(target=self._produce, name=f"{self.name}-estimator", daemon=True)
        self._worker.start()
        self.set_state("starting", f"opening {self.camera}")
        self.add_timer(0.005, self._drain, first_delay_s=0.0)

    # ----- worker thread: frames -> estimator -> queue ----------------------------------------------
    def _produce(self) -> None:
        from ..video.estimator import PoseEstimator, single_view_points
        from ..video.frames import VideoFrames
        try:
            frames = VideoFrames(self._source, width=self.width, height=self.height)
            est = PoseEstimator()
        except Exception as exc:  # noqa: BLE001 - a VideoError, or the estimator failing: one line via the loop
            self._results.put(exc)
            return
        live_file = frames.camera is None
        self.source_fps = frames.info.fps
        t0 = None                                   # a file's clock starts once the first frame is done
        try:
            for i, t, frame in frames:
                if self._quit.is_set():
                    break
                self.counts["read"] += 1
                if live_file and t0 is not None:     # a file streamed as if live: wait for its time,
                    lag = time.monotonic() - t0 - t  # skip the frames the estimator was too slow for
                    if lag > 1.0 / frames.info.fps:
                        self.counts["skipped"] += 1
                        continue
                    if lag < 0:
                        time.sleep(-lag)
                stamp = time.time_ns()
                c0 = time.perf_counter()
                r = est.process(frame)
                ms = 1000 * (time.perf_counter() - c0)
                self.estimator_ms = ms if self.estimator_ms != self.estimator_ms else 0.9 * self.estimator_ms + 0.1 * ms
                self.counts["estimated"] += 1
                if t0 is None:                       # the first estimate warms the models up (slow)
                    t0 = time.monotonic() - t
                if r is None:
                    self.counts["no_person"] += 1
                    continue
                P = single_view_points(r[2][None], r[1][None], missing=self.missing, ground=self.ground)
                self._put((i, stamp, P, r[1][None]))
            self._results.put(None)                # the end of a file
        except Exception as exc:  # noqa: BLE001
            self._results.put(exc)
        finally:
            est.close()
            frames.close()

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
            index, stamp, P, vis = item
            joints, q = kinect_joints(P, vis, good=self.good, missing=self.missing)
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
