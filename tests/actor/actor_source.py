"""A synthetic-actor marker source for the actor graph tests (imported by the node processes).

Publishes like every marker reader: ``markers`` (layout order, NaN + valid False when missing)
and the latched ``marker_layout``, plus ``ground_truth`` (ActorPose of the exact joint centres).
Capture stamps follow the session time (``t0 + frame / rate``) whatever ``speed`` is, so a run at
4x real time is seen by the calibration and solver exactly as a real-time one. Frames come from
:class:`SyntheticActor` (deterministic for a seed), in chunks of one second.
"""
from __future__ import annotations

import time

import numpy as np

from mocapgraph.bus import Node, Output, Param
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from mocapgraph.kinematics.synthetic.motion import MotionScript
from mocapgraph.messages import ActorPose, MarkerFrame, MarkerLayout


class ActorSource(Node):
    markers = Output("markers", MarkerFrame)
    marker_layout = Output("marker_layout", MarkerLayout)
    ground_truth = Output("ground_truth", ActorPose)

    layout = Param("kiip_full_body", "layout name or path")
    stream_layout = Param("", "name to announce in MarkerLayout ('' = the layout's own name)")
    rate_hz = Param(120.0, "capture rate, Hz")
    speed = Param(4.0, "wall-clock speed-up")
    duration_s = Param(30.0, "session length, s")
    noise_mm = Param(1.0, "marker noise, mm")
    gym_block_s = Param(1.0, "length of each of the 4 gym blocks, s")
    gym_scale = Param(1.0, "gym range scale")
    seed = Param(0, "seed")
    nan_every = Param(0, "every Nth frame (N > 0) all markers NaN/invalid")
    hide = Param([], "labels never visible")

    def on_start(self) -> None:
        self.actor = SyntheticActor(self.layout, rate=self.rate_hz, duration_s=self.duration_s, seed=self.seed,
                                    script=MotionScript(gym_block_s=self.gym_block_s, gym_scale=self.gym_scale),
                                    options=CaptureOptions(noise_mm=self.noise_mm))
        sk = self.actor.skeleton
        self.hidden = np.array([sk.marker_labels.index(h) for h in self.hide], dtype=np.int64)
        self.marker_layout.publish(MarkerLayout(
            name=self.stream_layout or sk.name, labels=list(sk.marker_labels), limb_names=list(sk.limb_names),
            marker_limb=sk.marker_limb, units_note="synthetic, m, world", source="synthetic actor (tests)"))
        self.k = 0
        self.chunk = None
        self.mono0, self.wall0 = time.monotonic(), time.time_ns()
        self.add_timer(1.0 / (self.rate_hz * self.speed), self.tick, first_delay_s=0.0)

    def tick(self) -> None:
        due = int((time.monotonic() - self.mono0) * self.rate_hz * self.speed) + 1
        while self.k < min(due, self.actor.n_frames):
            self.emit(self.k)
            self.k += 1
        if self.k >= self.actor.n_frames:
            self.request_stop()

    def emit(self, k: int) -> None:
        step = int(self.rate_hz)
        if self.chunk is None or not (self.chunk.frames[0] <= k < self.chunk.frames[0] + self.chunk.n_frames):
            a = (k // step) * step
            self.chunk = self.actor.capture(a, min(self.actor.n_frames, a + step))
        i = k - int(self.chunk.frames[0])
        pos = self.chunk.markers[i].copy()
        pos[self.hidden] = np.nan
        if self.nan_every and k % self.nan_every == self.nan_every - 1:
            pos[:] = np.nan
        stamp = self.wall0 + int(round(k * 1e9 / self.rate_hz))
        self.markers.publish(MarkerFrame(frame_number=k, rate_hz=self.rate_hz, positions=pos,
                                         valid=np.isfinite(pos).all(1),
                                         residual=np.full(len(pos), np.nan, np.float32)), capture_ns=stamp)
        J, L = self.chunk.joint_centres.shape[1], self.chunk.limb_quat.shape[1]
        self.ground_truth.publish(ActorPose(
            actor="truth", frame_number=k, joint_positions=self.chunk.joint_centres[i],
            joint_quality=np.full(J, 2, np.int8), limb_orientations=self.chunk.limb_quat[i],
            limb_quality=np.full(L, 2, np.int8), limb_visible_markers=np.zeros(L, np.int16)), capture_ns=stamp)
