"""Our topics as Foxglove messages: each frame a ``foxglove.SceneUpdate`` (protobuf), diagnostics as JSON.

`SceneBuilder.feed(envelope, message)` keeps the latched names (layouts, models, skeleton and
character definitions, physics scenes) and turns every per-frame message into a list of
`FoxgloveMessage` ready for the WebSocket bridge or an MCAP file. One entity per stream
(``markers``, ``actor_pose/<actor>``, ...), replaced by its next frame.

What is drawn (world frame ``world``: Z up, metres, the same as ours, so no transform):
markers as spheres, green where seen this frame and red where the position is known but not
seen (NaN positions are not drawable and are left out); joints of actors, skeleton streams and
characters as spheres coloured by quality (good blue, estimated amber; missing left out) with
bones as lines to the parent joint; physics bodies as their shapes (capsules as a cylinder and
two spheres, MuJoCo sizes converted to Foxglove's full extents), tracked bodies orange and
untracked stage objects grey. Diagnostics become one JSON message per node on
``/diagnostics/<node>`` whose fields plot directly (``rate_hz.<topic>``, ``latency_ms.<topic>``);
node states and commands (calibration, bag player) become JSON on their own topics.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..formats.protobuf_records import FixedRecord, key, length_delimited, varint
from ..messages import (ActorPose, CharacterInfo, CharacterPose, Diagnostics, MarkerFrame, MarkerLayout, Message,
                        NodeCommand, NodeStatus, PhysicsScene, PhysicsState, SkeletonInfo, SkeletonModel,
                        SkeletonPose)
from ..messages.codec import Envelope
from ..messages.pose_quality import character_quality

FRAME_ID = "world"
SCENE_SCHEMA = "foxglove.SceneUpdate"
DIAGNOSTICS_SCHEMA = "mocapgraph.DiagnosticsPlot"

_VEC3 = [(1, "d"), (2, "d"), (3, "d")]
_QUAT = [(1, "d"), (2, "d"), (3, "d"), (4, "d")]   # x, y, z, w (Foxglove's order)
_COLOR = [(1, "d"), (2, "d"), (3, "d"), (4, "d")]  # r, g, b, a in 0..1
_POSE = [(1, _VEC3), (2, _QUAT)]
# Field numbers of foxglove.SceneEntity / LinePrimitive (its published .proto).
_SPHERES = FixedRecord([(1, _POSE), (2, _VEC3), (3, _COLOR)], field=9)
_CUBES = FixedRecord([(1, _POSE), (2, _VEC3), (3, _COLOR)], field=8)
_CYLINDERS = FixedRecord([(1, _POSE), (2, _VEC3), (3, "d"), (4, "d"), (5, _COLOR)], field=10)
_LINE_POINTS = FixedRecord(_VEC3, field=5)
_LINE_COLORS = FixedRecord(_COLOR, field=7)
_LINE_LIST = 2
_ENTITY_LINES = 11
_IDENTITY_POSE = length_delimited(2, length_delimited(2, key(4, 1) + np.float64(1.0).tobytes()))

SEEN = (0.2, 0.85, 0.3, 1.0)
UNSEEN = (0.95, 0.2, 0.2, 1.0)
QUALITY_COLORS = np.array([[0.0, 0.0, 0.0, 0.0],     # missing: never drawn
                           [1.0, 0.72, 0.1, 1.0],    # estimated
                           [0.25, 0.6, 1.0, 1.0]])   # good
_SEEN_UNSEEN = np.array([UNSEEN, SEEN])
TRACKED_BODY = (1.0, 0.55, 0.15, 0.85)
STAGE_BODY = (0.6, 0.62, 0.66, 0.9)


@dataclass
class FoxgloveMessage:
    """One message for Foxglove: topic, schema name, encoding ("protobuf" or "json"), payload, stamp ns;
    JSON messages carry their JSON Schema (``schema_data``), scenes use :func:`scene_schema`."""

    topic: str
    schema: str
    encoding: str
    data: bytes
    log_ns: int
    schema_data: bytes = b""


def _stamp(ns: int) -> bytes:
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return key(1, 0) + varint(max(sec, 0)) + key(2, 0) + varint(nsec)


def entity(entity_id: str, stamp_ns: int, parts: bytes, metadata: dict[str, str] | None = None) -> bytes:
    """One ``SceneUpdate.entities`` element: timestamp, frame, id, metadata and primitive fields."""
    body = length_delimited(1, _stamp(stamp_ns)) + length_delimited(2, FRAME_ID.encode()) \
        + length_delimited(3, entity_id.encode())
    for k, v in (metadata or {}).items():
        body += length_delimited(6, length_delimited(1, k.encode()) + length_delimited(2, v.encode()))
    return length_delimited(2, body + parts)


def spheres(centres: np.ndarray, diameters: np.ndarray | float, colors: np.ndarray) -> bytes:
    """Sphere primitives at float[N,3] m, full diameters (m), colours float[N,4] or [4]."""
    n = len(centres)
    if n == 0:
        return b""
    vals = np.empty((n, 14))
    vals[:, 0:3] = centres
    vals[:, 3:7] = (0.0, 0.0, 0.0, 1.0)
    vals[:, 7:10] = diameters if np.ndim(diameters) == 0 else np.asarray(diameters, float)[:, None]
    vals[:, 10:14] = colors
    return _SPHERES.encode(vals)


def _oriented(record: FixedRecord, centres: np.ndarray, quat_wxyz: np.ndarray, sizes: np.ndarray,
              colors: np.ndarray, extra: tuple[float, ...] = ()) -> bytes:
    n = len(centres)
    if n == 0:
        return b""
    vals = np.empty((n, 14 + len(extra)))
    vals[:, 0:3] = centres
    vals[:, 3:6] = quat_wxyz[:, 1:4]
    vals[:, 6] = quat_wxyz[:, 0]
    vals[:, 7:10] = sizes
    vals[:, 10:10 + len(extra)] = extra
    vals[:, 10 + len(extra):] = colors
    return record.encode(vals)


def lines(starts: np.ndarray, ends: np.ndarray, colors: np.ndarray, thickness: float) -> bytes:
    """One LINE_LIST primitive of segments float[K,3] -> float[K,3], per-segment colours float[K,4]."""
    k = len(starts)
    if k == 0:
        return b""
    pts = np.stack([starts, ends], axis=1).reshape(2 * k, 3)
    cols = np.repeat(np.broadcast_to(colors, (k, 4)), 2, axis=0)
    body = key(1, 0) + varint(_LINE_LIST) + _IDENTITY_POSE + key(3, 1) + np.float64(thickness).tobytes() \
        + key(4, 0) + b"\0" + _LINE_POINTS.encode(pts) + _LINE_COLORS.encode(cols)
    return length_delimited(_ENTITY_LINES, body)


def skeleton_parts(joints: np.ndarray, quality: np.ndarray, parent: np.ndarray | None, joint_d: float,
                   bone_w: float) -> tuple[bytes, int]:
    """Joint spheres coloured by quality (0 left out) and bones to drawn parents; (bytes, joints drawn)."""
    q = np.clip(np.asarray(quality, np.int64), 0, 2)
    show = (q > 0) & np.isfinite(joints).all(-1)
    out = spheres(joints[show], joint_d, QUALITY_COLORS[q[show]])
    if parent is not None and len(parent) == len(joints):
        parent = np.asarray(parent, np.int64)
        child = np.flatnonzero((parent >= 0) & show)
        child = child[show[parent[child]]]
        if len(child):
            bq = np.minimum(q[child], q[parent[child]])
            out += lines(joints[parent[child]], joints[child], QUALITY_COLORS[bq], bone_w)
    return out, int(show.sum())


def body_parts(shapes: list[str], sizes: np.ndarray, pos: np.ndarray, quat: np.ndarray,
               tracked: np.ndarray) -> bytes:
    """Physics bodies as Foxglove primitives; MuJoCo sizes (radius, half-length, half-extents)."""
    ok = np.isfinite(pos).all(-1) & np.isfinite(quat).all(-1)
    colors = np.where(tracked[:, None], TRACKED_BODY, STAGE_BODY)
    kind = np.array(shapes + [""] * (len(pos) - len(shapes)))[: len(pos)]
    out = b""
    box = ok & (kind == "box")
    out += _oriented(_CUBES, pos[box], quat[box], 2 * sizes[box], colors[box])
    sph = ok & (kind == "sphere")
    out += spheres(pos[sph], 2 * sizes[sph, 0], colors[sph])
    for name in ("cylinder", "capsule"):
        sel = ok & (kind == name)
        if not sel.any():
            continue
        r, h = sizes[sel, 0], sizes[sel, 1]
        cyl = np.stack([2 * r, 2 * r, 2 * h], axis=1)
        out += _oriented(_CYLINDERS, pos[sel], quat[sel], cyl, colors[sel], extra=(1.0, 1.0))
        if name == "capsule":  # end caps on the local Z axis, as MuJoCo builds a capsule
            axis = Rotation.from_quat(quat[sel], scalar_first=True).apply(np.array([0.0, 0.0, 1.0])) * h[:, None]
            caps = np.concatenate([pos[sel] + axis, pos[sel] - axis])
            out += spheres(caps, np.tile(2 * r, 2), np.tile(colors[sel], (2, 1)))
    other = ok & ~np.isin(kind, ("box", "sphere", "cylinder", "capsule"))
    # Meshes and unknown shapes: a small cube where the body is, so it is at least seen.
    out += _oriented(_CUBES, pos[other], quat[other], np.full((int(other.sum()), 3), 0.05), colors[other])
    return out


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None


def diagnostics_json(msg: Diagnostics) -> dict[str, Any]:
    """A Diagnostics message as a plot-friendly JSON object (NaN -> null)."""
    def per_edge(arr: np.ndarray) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for t, s, v in zip(msg.edge_topics, msg.edge_senders, arr.tolist()):
            name = t if t not in out else f"{t}:{s}"
            out[name.replace(".", "_")] = _finite(float(v))
        return out

    return {"node": msg.node, "pid": msg.pid, "uptime_s": msg.uptime_s, "cpu_s": msg.cpu_s,
            "rate_hz": per_edge(msg.edge_rate_hz), "latency_ms": per_edge(msg.edge_latency_ms),
            "latency_max_ms": per_edge(msg.edge_latency_max_ms), "received": per_edge(msg.edge_received),
            "gaps": per_edge(msg.edge_gaps), "rejected": per_edge(msg.edge_rejected),
            "anomalies": per_edge(msg.edge_anomalies) if msg.edge_anomalies is not None else {},
            "sent": {t.replace(".", "_"): int(n) for t, n in zip(msg.output_topics, msg.output_sent.tolist())},
            **{f"clock_{k}": {c.replace(".", "_"): _finite(float(v)) for c, v in zip(msg.clock_names, arr.tolist())}
               for k, arr in (("offset_ms", msg.clock_offset_ms), ("drift_ppm", msg.clock_drift_ppm),
                              ("jitter_ms", msg.clock_jitter_ms), ("resets", msg.clock_resets))}}


DIAGNOSTICS_JSON_SCHEMA = {
    "title": DIAGNOSTICS_SCHEMA, "type": "object",
    "description": "a mocapgraph node's health, per incoming edge keyed by topic",
    "properties": {"node": {"type": "string"}, "pid": {"type": "integer"}, "uptime_s": {"type": "number"},
                   "cpu_s": {"type": "number"},
                   **{k: {"type": "object", "additionalProperties": {"type": ["number", "null"]}}
                      for k in ("rate_hz", "latency_ms", "latency_max_ms", "received", "gaps", "rejected", "anomalies",
                                "sent", "clock_offset_ms", "clock_drift_ppm", "clock_jitter_ms", "clock_resets")}},
}


_DIAGNOSTICS_SCHEMA_BYTES = json.dumps(DIAGNOSTICS_JSON_SCHEMA).encode()


class SceneBuilder:
    """Turns our messages into Foxglove messages, keeping the latched definitions it has seen.

    Sizes in metres: marker and joint sphere diameters, bone line thickness.
    """

    def __init__(self, marker_d: float = 0.018, joint_d: float = 0.035, bone_w: float = 0.012) -> None:
        self.marker_d = marker_d
        self.joint_d = joint_d
        self.bone_w = bone_w
        self.layouts: dict[str, MarkerLayout] = {}
        self.models: list[SkeletonModel] = []
        self.skeleton_infos: list[SkeletonInfo] = []
        self.characters: dict[str, CharacterInfo] = {}
        self.physics: list[PhysicsScene] = []
        self.drawn: dict[str, int] = {}  # entity id -> primitives (markers, joints) in its last frame

    def feed(self, env: Envelope, msg: Message, topic: str | None = None) -> list[FoxgloveMessage]:
        """Foxglove messages for ``msg`` (none for latched definitions, which are only kept)."""
        topic = topic or env.topic
        stamp = env.capture_ns
        if isinstance(msg, MarkerLayout):
            self.layouts[topic] = msg
        elif isinstance(msg, SkeletonModel):
            self.models = [m for m in self.models if len(m.joint_names) != len(msg.joint_names)] + [msg]
        elif isinstance(msg, SkeletonInfo):
            self.skeleton_infos = [m for m in self.skeleton_infos if m.source != msg.source] + [msg]
        elif isinstance(msg, CharacterInfo):
            self.characters[msg.character] = msg
        elif isinstance(msg, PhysicsScene):
            self.physics = [p for p in self.physics if len(p.body_names) != len(msg.body_names)] + [msg]
        elif isinstance(msg, MarkerFrame):
            return [self._scene(topic, topic, stamp, self._markers(msg), {"frame": str(msg.frame_number)})]
        elif isinstance(msg, ActorPose):
            model = self._by_count(self.models, "joint_names", len(msg.joint_positions))
            parts, n = skeleton_parts(msg.joint_positions, msg.joint_quality,
                                      None if model is None else model.joint_parent, self.joint_d, self.bone_w)
            return [self._scene(topic, f"{topic}/{msg.actor}", stamp, (parts, n), {"frame": str(msg.frame_number)})]
        elif isinstance(msg, SkeletonPose):
            info = self._by_count(self.skeleton_infos, "joint_names", len(msg.joint_positions))
            parts, n = skeleton_parts(msg.joint_positions, msg.tracking_state,
                                      None if info is None else info.joint_parent, self.joint_d, self.bone_w)
            return [self._scene(topic, f"{topic}/{msg.source_id}", stamp, (parts, n),
                                {"frame": str(msg.frame_number)})]
        elif isinstance(msg, CharacterPose):
            info = self.characters.get(msg.character)
            J = len(msg.joint_positions)
            parent = info.joint_parent if info is not None and len(info.joint_names) == J else None
            q = character_quality(msg)
            parts, n = skeleton_parts(msg.joint_positions, q, parent, self.joint_d, self.bone_w)
            return [self._scene(topic, f"{topic}/{msg.character}", stamp, (parts, n), {"frame": str(msg.frame_number)})]
        elif isinstance(msg, PhysicsState):
            scene = self._by_count(self.physics, "body_names", len(msg.positions))
            B = len(msg.positions)
            shapes = list(scene.shapes) if scene is not None else ["sphere"] * B
            sizes = scene.sizes if scene is not None else np.full((B, 3), 0.03)
            tracked = np.isfinite(msg.tracking_error)
            parts = body_parts(shapes, sizes, msg.positions, msg.orientations, tracked)
            return [self._scene(topic, topic, stamp, (parts, B), {"sim_time_s": f"{msg.sim_time_s:.4f}"})]
        elif isinstance(msg, Diagnostics):
            data = json.dumps(diagnostics_json(msg), allow_nan=False).encode()
            return [FoxgloveMessage(f"/{topic}/{msg.node}", DIAGNOSTICS_SCHEMA, "json", data, stamp,
                                    _DIAGNOSTICS_SCHEMA_BYTES)]
        elif isinstance(msg, (NodeStatus, NodeCommand)):
            # state machines (calibration, bag player) for Foxglove's Raw Messages and State panels
            rec = {k: (_finite(v) if isinstance(v, float) else v) for k, v in msg.to_dict().items()}
            for field in ("data_json", "args_json"):
                if field in rec:
                    try:
                        rec[field.removesuffix("_json")] = json.loads(rec[field] or "{}")
                    except ValueError:
                        pass
            data = json.dumps(rec, allow_nan=False, default=str).encode()
            return [FoxgloveMessage(f"/{topic}", f"mocapgraph.{env.type_name}", "json", data, stamp,
                                    json.dumps(type(msg).json_schema()).encode())]
        return []

    @staticmethod
    def _by_count(items: list, field: str, n: int) -> Any:
        for item in reversed(items):
            if len(getattr(item, field)) == n:
                return item
        return None

    def _markers(self, msg: MarkerFrame) -> tuple[bytes, int]:
        p = msg.positions
        ok = np.isfinite(p).all(-1)
        colors = _SEEN_UNSEEN[msg.valid[ok].astype(np.intp)]
        return spheres(p[ok], self.marker_d, colors), len(colors)

    def _scene(self, topic: str, entity_id: str, stamp: int, parts: tuple[bytes, int],
               meta: dict[str, str]) -> FoxgloveMessage:
        data, n = parts
        self.drawn[entity_id] = n
        return FoxgloveMessage(f"/{topic}", SCENE_SCHEMA, "protobuf", entity(entity_id, stamp, data, meta), stamp)


def scene_schema() -> tuple[str, bytes]:
    """Foxglove's own SceneUpdate schema (protobuf FileDescriptorSet) from the official SDK."""
    from foxglove.messages import SceneUpdate

    s = SceneUpdate.get_schema()
    return s.name, bytes(s.data)
