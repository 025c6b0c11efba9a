"""Synthetic character node: standard_20 driven by the synthetic performer, as CharacterPose.

A ground-truth character source for the physics tracker's tests, benchmarks and demos
(:func:`mocapgraph.physics.synthetic_targets.synthetic_targets`: the actor's segment rotations
on the character, no markers or calibration in between). Publishes the latched ``character_info``
and one ``character_pose`` per frame at ``rate_hz`` over [start_s, stop_s) of the session, looping.

``faults`` injects bad input the way a real stream breaks, each ``{kind, from_s, to_s, joints}``
with times from the first frame: ``nan`` (the joints, or every joint, NaN and quality 0; the
retargeter itself never sends NaN, so this is the hostile case), ``jump`` (everything
moved ``offset`` metres, default 1 m forward), ``stop`` (no frames at all).
"""
from __future__ import annotations

import time

import numpy as np

from ..bus import Node, Output, Param
from ..messages import CharacterInfo, CharacterPose
from ..physics.synthetic_targets import synthetic_targets

FAULT_KINDS = ("nan", "jump", "stop")


class SyntheticCharacterNode(Node):
    """standard_20 following the synthetic performer (ground truth CharacterPose)."""

    summary = "standard_20 driven by the synthetic performer -> CharacterPose (+ latched CharacterInfo)"
    character_info = Output("character_info", CharacterInfo, "latched skeleton of the character")
    character_pose = Output("character_pose", CharacterPose, "the character every frame")

    character = Param("standard_20", "character name carried in the messages")
    height = Param(1.75, "standing height, m", minimum=0.5, maximum=2.5)
    rate_hz = Param(120.0, "frame rate, Hz", minimum=1.0, maximum=1000.0)
    start_s = Param(17.0, "session time of the first frame, s (17: the walk; 1: the gym)", minimum=0.0)
    stop_s = Param(37.5, "session time after the last frame, s (37.5: end of the performance)", minimum=0.1)
    loop = Param(True, "start again after the last frame")
    offset = Param([0.0, 0.0, 0.0], "world offset of the whole performance, m")
    seed = Param(0, "performer seed")
    faults = Param([], "bad input to inject: [{kind: nan|jump|stop, from_s, to_s, joints: [...], offset}]")

    def __init__(self, name: str, params: dict | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        if self.stop_s <= self.start_s:
            raise ValueError(f"stop_s {self.stop_s} must be after start_s {self.start_s}")
        for f in self.faults:
            if not isinstance(f, dict) or f.get("kind") not in FAULT_KINDS:
                raise ValueError(f"faults: {f!r} needs kind one of {', '.join(FAULT_KINDS)}")
        self.clip = synthetic_targets(self.start_s, self.stop_s, self.rate_hz, seed=self.seed, height=self.height)
        self.off = np.asarray(self.offset, float)
        self.i = 0

    def on_start(self) -> None:
        ch = self.clip.character
        self.character_info.publish(CharacterInfo(character=self.character, joint_names=list(ch.joint_names),
                                                  joint_parent=ch.parents.astype(np.int32),
                                                  rest_offsets=ch.rest_offsets, rest_rotations=ch.rest_rotations))
        self.t0 = time.monotonic()
        self.add_timer(1.0 / self.rate_hz, self._tick)

    def _tick(self) -> None:
        # frames due by now (a late timer catches up, never drifts)
        due = int((time.monotonic() - self.t0) * self.rate_hz) + 1
        while self.i < due:
            self._publish(self.i)
            self.i += 1

    def _publish(self, i: int) -> None:
        n = len(self.clip)
        if i >= n and not self.loop:
            return
        f = i % n
        t = i / self.rate_hz
        pos = self.clip.positions[f] + self.off
        rot = self.clip.local_rotations[f]
        root = self.clip.root[f] + self.off
        quality = np.full(self.clip.character.n_joints, 2, dtype=np.int8)
        for fault in self.faults:
            if not float(fault.get("from_s", 0)) <= t < float(fault.get("to_s", 1e18)):
                continue
            kind = fault["kind"]
            if kind == "stop":
                return
            ch = self.clip.character
            idx = [ch.index(j) for j in fault.get("joints", [])] or list(range(ch.n_joints))
            if kind == "nan":
                pos, rot = pos.copy(), rot.copy()
                pos[idx] = np.nan
                rot[idx] = np.nan
                quality[idx] = 0
                if ch.root in idx:
                    root = np.full(3, np.nan)
            elif kind == "jump":
                d = np.asarray(fault.get("offset", [1.0, 0.0, 0.0]), float)
                pos, root = pos + d, root + d
        stamp = int(round(t * 1e9)) + 1
        self.character_pose.publish(CharacterPose(character=self.character, frame_number=i, root_position=root,
                                                  local_rotations=rot, joint_positions=pos,
                                                  joint_quality=quality), stamp)
