"""Synthetic actor node: a scripted human performer as live markers, with exact ground truth.

The embedded default source (no download, no hardware). Frames come from
:class:`mocapgraph.kinematics.synthetic.actor.SyntheticActor` (base pose hold, range-of-motion
gym, walk / reach / turn / kick performance). The whole session is computed before the graph
starts when it fits in ``precompute_mb`` (the default one-pass session does at any usual rate);
longer sessions are computed ahead in chunks on a worker thread. Either way the timer that
publishes frames only looks rows up. The session ends in the base pose where it began, so
``loop`` restarts seamlessly; frame numbers and stamps keep counting. ``start_s`` begins the
first pass later in the session (e.g. at the performance) with the session's own frame numbers.
"""
from __future__ import annotations

import math
import queue
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..bus import Output, Param
from ..adapters.model_messages import model_to_message
from ..kinematics.synthetic.actor import CaptureOptions, SyntheticActor, SyntheticCapture
from ..kinematics.synthetic.motion import MotionScript
from ..kinematics.synthetic.truth import exact_model
from ..messages import QUALITY_GOOD, ActorPose, SkeletonModel
from .marker_source import LayoutMap, MarkerSourceNode
from .source_base import INPUT_ERRORS, SourceError

CHUNK_S = 0.25  # seconds of frames computed per worker step


@dataclass
class _Chunk:
    """Frames [start, start + n) of one pass, ready to publish row by row."""

    start: int
    markers: np.ndarray       # [n, M, 3]
    valid: np.ndarray         # [n, M]
    joints: np.ndarray        # [n, J, 3]
    limb_quat: np.ndarray     # [n, L, 4]
    visible: np.ndarray       # int16 [n, L]


def ground_truth_model(cap: SyntheticCapture, layout_name: str) -> SkeletonModel:
    """The exact skeleton of a synthetic session as a SkeletonModel message (no calibration)."""
    return model_to_message(exact_model(cap, layout_name), cap.skeleton.marker_limb)


class SyntheticActorNode(MarkerSourceNode):
    """A scripted human wearing a marker layout: ``markers`` + latched ``marker_layout``, and the
    exact ``ground_truth`` (ActorPose: joint centres, limb orientations wxyz relative to the base
    pose, quality all GOOD) with its latched ``ground_truth_model`` (SkeletonModel: base markers,
    joint offsets, base joints, bone lengths). Deterministic for a given seed and parameters;
    noise, wobble, dropouts, limb shadowing and swaps touch the markers, never the ground truth.
    """

    summary = "scripted human performer with exact ground truth (noise, wobble, occlusion, swaps)"
    ground_truth = Output("ground_truth", ActorPose, "exact joint centres (m, world) and limb orientations "
                          "(wxyz, relative to the base pose); quality all GOOD")
    ground_truth_model = Output("ground_truth_model", SkeletonModel, "latched exact skeleton: base markers, "
                                "marker-to-joint offsets, base joints, bone lengths")
    layout = Param("kiip_full_body", "marker layout worn by the actor: a name under "
                                     "graph_configs/marker_layouts or a .yaml path")
    rate_hz = Param(120.0, "capture rate, Hz", minimum=1.0, maximum=2000.0)
    rate_scale = Param(1.0, "speed: 1 = real time, 2 = twice as fast, 0 = as fast as possible", minimum=0.0)
    seed = Param(0, "random seed (marker placement, noise, occlusion and swap events)")
    duration_s = Param(0.0, "session length, s; 0 = one pass (1 s base pose, 16 s gym, 20.5 s performance); "
                            "longer sessions repeat the performance", minimum=0.0)
    loop = Param(True, "start the session again when it ends (seamless: it ends in the base pose)")
    start_s = Param(0.0, "where the first pass begins, s into the session (17 = the performance with the default "
                         "script); frame numbers are the session's (start_s x rate_hz first); loops restart at 0 s",
                    minimum=0.0)
    noise_mm = Param(0.0, "Gaussian marker noise, standard deviation per axis, mm", minimum=0.0)
    wobble_mm = Param(0.0, "soft-tissue wobble, RMS per axis in the limb frame, mm", minimum=0.0)
    dropout_rate_hz = Param(0.0, "random single-marker dropouts per marker per second", minimum=0.0)
    shadow_rate_hz = Param(0.0, "limb-shadowing occlusions (a limb's markers hidden) per second", minimum=0.0)
    swap_rate_hz = Param(0.0, "label swaps between nearby markers per second", minimum=0.0)
    actor = Param("synthetic", "actor name carried in the ground truth")
    script = Param({}, "motion script timing, overriding any of: base_s (base-pose hold), gym_block_s (each of "
                       "4 gym blocks), walk_s, reach_s, turn_s, kick_s (performance clips), s; walk_speed (m/s), "
                       "stride_s, gym_scale (x the gym's ranges)")
    # Computing the whole session at start leaves no worker thread competing for the GIL with the
    # publishing timer (that costs about 1 ms of jitter at 240 Hz).
    precompute_mb = Param(64.0, "sessions up to this size (markers + ground truth, MB) are computed before "
                                "the graph starts; longer ones on a worker thread while playing", minimum=0.0)

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.load_error = ""
        self.frames_sent = 0
        self.late_frames = 0
        self._queue: queue.Queue[_Chunk] = queue.Queue(maxsize=4)
        self._quit = threading.Event()
        self._worker: threading.Thread | None = None
        self._chunk: _Chunk | None = None
        self._row = 0
        self.worker_error = ""
        try:
            known = set(MotionScript.__dataclass_fields__)
            bad = sorted(set(self.script) - known)
            if bad:
                raise SourceError(f"script has no setting {bad[0]!r} (known: {', '.join(sorted(known))})")
            script = MotionScript(**{k: float(v) for k, v in self.script.items()})
            opts = CaptureOptions(noise_mm=self.noise_mm, wobble_mm=self.wobble_mm,
                                  dropout_rate_hz=self.dropout_rate_hz, shadow_rate_hz=self.shadow_rate_hz,
                                  swap_rate_hz=self.swap_rate_hz)
            self.actor_model = SyntheticActor(self.layout, rate=self.rate_hz, seed=self.seed, options=opts,
                                              duration_s=self.duration_s or None, script=script)
        except (*INPUT_ERRORS, ValueError, TypeError, OSError) as exc:
            self.load_error = f"synthetic actor: {exc}"
            return
        sk = self.actor_model.skeleton
        self.n_frames = self.actor_model.n_frames
        self.start_frame = int(round(self.start_s * self.rate_hz))
        if self.start_frame >= self.n_frames:
            self.load_error = (f"synthetic actor: start_s {self.start_s:g} s is not inside the session "
                               f"({self.n_frames / self.rate_hz:g} s)")
            return
        self._row = self.start_frame   # the first pass's first row (of the whole session, or of the first chunk)
        self._onehot = np.zeros((sk.n_markers, sk.n_limbs), np.int16)
        self._onehot[np.arange(sk.n_markers), np.asarray(sk.marker_limb)] = 1
        self.chunk_frames = max(8, int(round(CHUNK_S * self.rate_hz)))
        per_frame = sk.n_markers * 25 + sk.n_joints * 24 + sk.n_limbs * 34
        self._whole: _Chunk | None = None
        self._whole_sent = False
        if self.n_frames * per_frame <= self.precompute_mb * 1e6:
            parts = [self._pack(c) for c in self.actor_model.chunks(1024)]
            self._whole = _Chunk(0, *(np.concatenate([getattr(p, f) for p in parts])
                                      for f in ("markers", "valid", "joints", "limb_quat", "visible")))
            self._first = self.actor_model.capture(0, min(1, self.n_frames))
        else:
            self._first = self.actor_model.capture(self.start_frame,
                                                   min(self.start_frame + self.chunk_frames, self.n_frames))
            self._queue.put(self._pack(self._first))
            self._row = 0

    # ----- producing frames (worker thread) ------------------------------------------------
    def _pack(self, cap: SyntheticCapture) -> _Chunk:
        visible = (cap.valid.astype(np.int16) @ self._onehot).astype(np.int16)
        return _Chunk(int(cap.frames[0]) if cap.n_frames else 0, cap.markers, cap.valid,
                      cap.joint_centres, cap.limb_quat, visible)

    def _produce(self) -> None:
        try:
            self._produce_chunks()
        except Exception as exc:  # reported by the node thread, which owns the sockets
            self.worker_error = f"synthetic actor: frame generation failed: {exc!r}"

    def _produce_chunks(self) -> None:
        start = self.start_frame + self._first.n_frames
        while not self._quit.is_set():
            if start >= self.n_frames:
                if not self.loop:
                    return
                start = 0
            stop = min(start + self.chunk_frames, self.n_frames)
            chunk = self._pack(self.actor_model.capture(start, stop))
            while not self._quit.is_set():
                try:
                    self._queue.put(chunk, timeout=0.1)
                    break
                except queue.Full:
                    continue
            start = stop

    # ----- publishing (node thread) ----------------------------------------------------------
    def on_start(self) -> None:
        if self.load_error:
            self.fail(self.load_error)
            return
        sk = self.actor_model.skeleton
        lmap = LayoutMap.build(self.layout, list(sk.marker_labels), "synthetic actor")
        opts = self.actor_model.options
        note = ("generated in metres, world frame (Z up, X forward); "
                f"noise {opts.noise_mm:g} mm, wobble {opts.wobble_mm:g} mm, dropouts {opts.dropout_rate_hz:g}/s, "
                f"shadows {opts.shadow_rate_hz:g}/s, swaps {opts.swap_rate_hz:g}/s, seed {self.seed}")
        self.publish_layout(lmap, note, f"synthetic actor ({sk.name})")
        self.ground_truth_model.publish(ground_truth_model(self._first, sk.name))
        if self._whole is None:
            # A worker thread holding the GIL must not delay the timer by Python's default 5 ms.
            sys.setswitchinterval(0.0005)
            self._worker = threading.Thread(target=self._produce, name=f"{self.name}-frames", daemon=True)
            self._worker.start()
        self.mono0, self.wall0 = time.monotonic(), time.time_ns()
        period = 0.0 if self.rate_scale == 0 else 1.0 / (self.rate_hz * self.rate_scale)
        begin = f", from {self.start_frame / self.rate_hz:g} s" if self.start_frame else ""
        self.set_state("streaming", f"{sk.name}, {self.rate_hz:g} Hz, session {self.n_frames / self.rate_hz:g} s{begin}")
        self.add_timer(period, self._tick, first_delay_s=0.0)

    def _next_chunk(self) -> _Chunk | None:
        if self._whole is not None:
            if self._whole_sent and not self.loop:
                return None
            self._whole_sent = True
            return self._whole
        try:
            return self._queue.get_nowait()
        except queue.Empty:
            pass
        if self._worker is None or not self._worker.is_alive():
            return None  # the session is over (loop off) or generation failed
        if self.rate_scale:
            self.late_frames += 1  # real time and the worker is behind: this frame goes out late
        while True:
            try:
                return self._queue.get(timeout=0.05)
            except queue.Empty:
                if self._worker is None or not self._worker.is_alive():
                    return None if self._queue.empty() else self._queue.get_nowait()

    def _tick(self) -> None:
        if self.rate_scale == 0:
            due = self.frames_sent + 64
        else:  # frames whose time has come (more than one only after a stall)
            # (0.1 ms of slack for the timer's rounding: a frame is never sent earlier than that)
            due = math.floor((time.monotonic() - self.mono0 + 1e-4) * self.rate_hz * self.rate_scale) + 1
        while self.frames_sent < due:
            c = self._chunk
            if c is None or self._row >= c.markers.shape[0]:
                # (the first chunk begins at the row __init__ set: start_s into the session)
                first = c is None and not self.frames_sent
                c = self._chunk = self._next_chunk()
                self._row = self._row if first else 0
                if c is None:
                    if self.worker_error:
                        self.fail(self.worker_error)
                        return
                    self.set_state("finished", f"{self.frames_sent} frames sent")
                    self.request_stop()
                    return
            i = self._row
            k = self.start_frame + self.frames_sent
            cap_ns = self.wall0 + round(self.frames_sent * 1e9 / self.rate_hz)
            self.publish_frame(k, self.rate_hz, c.markers[i], cap_ns, valid=c.valid[i])
            self.ground_truth.publish(ActorPose(
                actor=self.actor, frame_number=k, joint_positions=c.joints[i],
                joint_quality=np.full(c.joints.shape[1], QUALITY_GOOD, np.int8),
                limb_orientations=c.limb_quat[i], limb_quality=np.full(c.limb_quat.shape[1], QUALITY_GOOD, np.int8),
                limb_visible_markers=c.visible[i]), capture_ns=cap_ns)
            self._row += 1
            self.frames_sent += 1

    def status_data(self) -> dict[str, Any]:
        return {"frames_sent": self.frames_sent, "late_frames": self.late_frames,
                "session_frames": getattr(self, "n_frames", 0)}

    def on_stop(self) -> None:
        self._quit.set()
        if self._worker is not None:
            self._worker.join(1.0)
