"""Several live cameras' 2D landmarks, grouped by capture time and triangulated into one skeleton.

Each camera is a ``video_camera_reader`` (one process per camera) publishing ``ImageLandmarks``
on ``landmarks_<camera>``; this node groups their frames by capture stamp
(:class:`mocapgraph.video.live.FrameGrouper`: within half a frame period of the slowest camera),
triangulates each group seen by at least two cameras (:func:`mocapgraph.video.multiview.triangulate`)
and publishes the Kinect v2 skeleton stamped with the group's capture time. A camera that lags or
stops is named in the log and counted in the status; the others continue.
"""
from __future__ import annotations

import time
from collections import deque
from typing import Any

import numpy as np

from ..bus import Input, Interface, Output, Param
from ..formats.kinect_csv import KINECT_V2_JOINTS, KINECT_V2_PARENTS
from ..formats.skeleton_trial import topological_order
from ..messages import ImageLandmarks, SkeletonInfo, SkeletonPose
from ..video.multiview import off_cameras
from .source_base import INPUT_ERRORS, SourceNode, resolve_data_path

REPORT_AFTER_GROUPS = 20       # skeletons before a camera's reprojection error is judged against the others'


class MultiviewLive(SourceNode):
    """Triangulates N live cameras (``cameras``: their names in the calibration ``file``; camera X's
    landmarks on topic ``landmarks_X``) into ``skeleton_pose`` + latched ``skeleton_info``.

    Quality as ``multiview_pose``: tracked when >= 3 cameras agree within ``good_px``, inferred
    with two, else not tracked. Bones are held at their lengths over the first ``hold_bones_s``
    seconds of skeletons (0: the raw triangulation); skeleton_info's rest offsets are those lengths.
    """

    summary = "group live cameras' 2D landmarks by capture time and triangulate them into one SkeletonPose"
    skeleton_pose = Output("skeleton_pose", SkeletonPose, "joint positions (m, calibration world), tracking "
                           "state, skeleton_info order")
    skeleton_info = Output("skeleton_info", SkeletonInfo, "latched joint names, parents, rest offsets (the "
                           "bone lengths held)")
    file = Param("", "camera calibration (.qca.txt, .toml, .yaml)", kind="file", required=True)
    cameras = Param([], "camera names (as in the calibration); camera X's landmarks come on landmarks_X")
    wait_s = Param(0.5, "how long a frame group waits for a late camera, s (capture to now)", minimum=0.0)
    stall_s = Param(2.0, "a camera silent this long is stalled: named, not waited for", minimum=0.1)
    reject_px = Param(50.0, "a camera farther than this from a joint's consensus is dropped for it, px", minimum=1.0)
    good_px = Param(30.0, "reprojection error up to which a joint seen by >= 3 cameras is good, px", minimum=1.0)
    hold_bones_s = Param(1.0, "hold every bone at its median length over the first seconds (0: raw)", minimum=0.0)
    source_id = Param("body0", "performer / body id carried in every SkeletonPose")

    @classmethod
    def interface(cls, params: dict[str, Any]) -> Interface:
        iface = super().interface(params)
        for i, cam in enumerate(params.get("cameras", cls.cameras.default)):
            iface.inputs[f"in{i}"] = Input(f"landmarks_{cam}", ImageLandmarks, f"camera {cam}'s 2D landmarks",
                                           name=f"in{i}")
        return iface

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        from ..video.estimator import N_LANDMARKS
        from ..video.live import FrameGrouper
        self.names = [str(c) for c in self.cameras]
        self.grouper = FrameGrouper(self.names, N_LANDMARKS, 1.0 / 30.0, wait_s=self.wait_s, stall_s=self.stall_s)
        self.rates: dict[int, float] = {}
        self.load_error = ""
        self.cams = []
        try:
            from ..video.multiview import match_cameras, read_calibration
            if len(self.names) < 2:
                raise ValueError(f"needs at least two cameras to triangulate, got {len(self.names)}")
            path = resolve_data_path(self.file)
            self.cams = match_cameras(read_calibration(path), self.names, path=path)
        except (*INPUT_ERRORS, ValueError) as exc:
            self.load_error = str(exc)
        self.counts = {"groups": 0, "triangulated": 0, "too_few_cameras": 0, "published": 0}
        self.errors = deque(maxlen=300)             # recent [C] median reprojection errors per group
        self.triangulate_ms = float("nan")
        self.order = topological_order(np.array(KINECT_V2_PARENTS))
        self._calib: list[np.ndarray] = []
        self._t_first: int | None = None
        self.lengths: np.ndarray | None = None
        self.info: SkeletonInfo | None = None

    def on_start(self) -> None:
        if self.load_error:
            self.fail(self.load_error)
            return
        self.set_state("waiting", f"for {len(self.names)} cameras")
        self.add_timer(0.01, self._poll)

    def input_handler(self, port_name: str):
        if not port_name.startswith("in"):
            return super().input_handler(port_name)
        k = int(port_name[2:])
        port = self.input_ports[port_name]

        def take(msg: ImageLandmarks) -> None:
            if msg.camera and msg.camera != self.names[k]:
                self.warn_limited(f"name{k}", "landmarks_%s carries camera %r: taken as %s", self.names[k],
                                  msg.camera, self.names[k])
            if msg.rate_hz > 0 and self.rates.get(k) != msg.rate_hz:
                self.rates[k] = float(msg.rate_hz)
                self.grouper.set_rate(min(self.rates.values()))
            for note in self.grouper.add(k, int(port.envelope.capture_ns), int(msg.frame_number), msg.points,
                                         msg.confidence, time.time_ns()):
                self.log.info("%s", note)

        return take

    def _poll(self) -> None:
        groups, notes = self.grouper.ready(time.time_ns())
        for note in notes:
            self.log.warning("%s", note)
        for g in groups:
            self._triangulate(g)

    def _triangulate(self, g) -> None:
        from ..video.estimator import kinect_joints
        from ..video.multiview import triangulate
        self.counts["groups"] += 1
        if g.present.sum() < 2:
            self.counts["too_few_cameras"] += 1
            return
        c0 = time.perf_counter()
        tri = triangulate(self.cams, g.uv, g.conf, reject_px=self.reject_px, good_px=self.good_px)
        joints, q = kinect_joints(tri.points[None], np.ones((1, tri.points.shape[0])), good=0.5, missing=0.5,
                                  quality=tri.quality[None])
        ms = 1000 * (time.perf_counter() - c0)
        self.triangulate_ms = ms if self.triangulate_ms != self.triangulate_ms else 0.9 * self.triangulate_ms + 0.1 * ms
        seen = np.isfinite(tri.error_px)
        self.errors.append(np.array([np.median(e[s]) if s.any() else np.nan for e, s in zip(tri.error_px, seen)]))
        if not np.isfinite(joints).any():
            return
        self.counts["triangulated"] += 1
        P = joints[0]
        if not self._holding(P, q[0], g.capture_ns):
            return
        if self.lengths is not None:
            P = self._hold(P)
        frame = int(g.frames[g.present][0])
        self.skeleton_pose.publish(SkeletonPose(source_id=self.source_id, frame_number=frame, joint_positions=P,
                                                joint_orientations=np.full((len(KINECT_V2_JOINTS), 4), np.nan),
                                                tracking_state=q[0]), capture_ns=int(g.capture_ns))
        self.counts["published"] += 1
        if self.state != "streaming":
            self.set_state("streaming", f"{len(self.names)} cameras")

    def _holding(self, P: np.ndarray, q: np.ndarray, stamp: int) -> bool:
        """Collect good joints for ``hold_bones_s``; then latch skeleton_info. True once latched."""
        if self.info is not None:
            return True
        self._t_first = self._t_first or stamp
        self._calib.append(np.where((q == 2)[:, None], P, np.nan))
        if stamp - self._t_first < self.hold_bones_s * 1e9:
            self.set_state("calibrating", f"{len(self._calib)} skeletons of {self.hold_bones_s:g} s")
            return False
        from ..kinematics.rest_offsets import observed_rest_offsets
        from ..video.capture import calibrated_lengths
        C = np.array(self._calib)
        parents = np.array(KINECT_V2_PARENTS)
        if self.hold_bones_s > 0:
            self.lengths = calibrated_lengths(C, np.isfinite(C).all(-1), parents)
        self.info = SkeletonInfo(source="video_multiview", joint_names=list(KINECT_V2_JOINTS),
                                 joint_parent=parents.astype(np.int32), rest_offsets=observed_rest_offsets(C, parents),
                                 units_note=f"{len(self.names)} live cameras ({', '.join(self.names)}) triangulated; "
                                            f"calibration world frame, m; bones held over {len(C)} skeletons")
        self.skeleton_info.publish(self.info)
        return True

    def _hold(self, P: np.ndarray) -> np.ndarray:
        from ..video.capture import hold_bones
        return hold_bones(P[None], np.array(KINECT_V2_PARENTS), self.order, self.lengths)[0]

    def status_data(self) -> dict[str, Any]:
        d: dict[str, Any] = dict(self.counts)
        d["cameras"] = self.grouper.status()
        if self.errors:
            E = np.array(self.errors)
            med = np.array([np.median(e[np.isfinite(e)]) if np.isfinite(e).any() else np.nan for e in E.T])
            d["reprojection_px"] = {n: None if np.isnan(m) else round(float(m), 1) for n, m in zip(self.names, med)}
            if len(E) >= REPORT_AFTER_GROUPS:          # a camera far off the others: its calibration, named
                for line in off_cameras(self.names, med):
                    self.warn_limited(line.split(":")[0], "%s", line, every_s=30.0)
        d["triangulate_ms"] = round(float(self.triangulate_ms), 2)
        return d
