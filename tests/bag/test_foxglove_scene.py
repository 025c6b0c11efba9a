"""Our SceneUpdate bytes decode with Foxglove's own schema to what the official SDK encodes for
the same scene, for every drawn message type."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from foxglove_decode import message_class
from mocapgraph.bag.foxglove_scene import QUALITY_COLORS, SEEN, UNSEEN, SceneBuilder, scene_schema
from mocapgraph.messages import (ActorPose, CharacterInfo, CharacterPose, Diagnostics, MarkerFrame, PhysicsScene,
                                 PhysicsState, SkeletonModel)
from mocapgraph.messages.codec import Envelope

NAME, DATA = scene_schema()
SceneUpdate = message_class(NAME, DATA)


def env(topic: str, t: str, ns: int = 1_500_000_123) -> Envelope:
    return Envelope(topic, t, 1, 1, ns, ns, "test", False)


def decode(m) -> "SceneUpdate":
    assert m.schema == "foxglove.SceneUpdate" and m.encoding == "protobuf"
    return SceneUpdate.FromString(m.data)


def test_markers_match_the_official_sdk_encoding():
    import foxglove.messages as fm

    rng = np.random.default_rng(1)
    p = rng.normal(size=(12, 3))
    valid = rng.random(12) > 0.3
    p[3] = np.nan
    valid[3] = False
    msg = MarkerFrame(frame_number=7, rate_hz=240.0, positions=p, valid=valid, residual=np.zeros(12, np.float32))
    (out,) = SceneBuilder(marker_d=0.02).feed(env("markers", "MarkerFrame"), msg)
    ours = decode(out)
    ok = np.isfinite(p).all(-1)

    def color(c):
        return fm.Color(r=c[0], g=c[1], b=c[2], a=c[3])

    sdk = fm.SceneUpdate(entities=[fm.SceneEntity(
        timestamp=fm.Timestamp(sec=1, nsec=500_000_123), frame_id="world", id="markers",
        metadata=[fm.KeyValuePair(key="frame", value="7")],
        spheres=[fm.SpherePrimitive(pose=fm.Pose(position=fm.Vector3(x=x, y=y, z=z),
                                                 orientation=fm.Quaternion(w=1.0)),
                                    size=fm.Vector3(x=0.02, y=0.02, z=0.02), color=color(SEEN if v else UNSEEN))
                 for (x, y, z), v in zip(p[ok].tolist(), valid[ok])])])
    assert SceneUpdate.FromString(sdk.encode()) == ours
    assert len(ours.entities[0].spheres) == 11


def test_actor_bones_follow_the_model_and_quality():
    J = 4
    model = SkeletonModel(joint_names=list("abcd"), joint_parent=np.array([-1, 0, 1, 1], np.int32))
    joints = np.array([[0, 0, 1], [0, 0, 0.5], [0.3, 0, 0.5], [np.nan] * 3], float)
    q = np.array([2, 1, 2, 0], np.int8)
    pose = ActorPose(actor="ann", frame_number=3, joint_positions=joints, joint_quality=q,
                     limb_orientations=np.zeros((0, 4)), limb_quality=np.zeros(0, np.int8),
                     limb_visible_markers=np.zeros(0, np.int16))
    b = SceneBuilder()
    assert b.feed(env("skeleton_model", "SkeletonModel"), model) == []
    (out,) = b.feed(env("actor_pose", "ActorPose"), pose)
    e = decode(out).entities[0]
    assert e.id == "actor_pose/ann" and len(e.spheres) == 3
    np.testing.assert_allclose([[s.pose.position.x, s.pose.position.y, s.pose.position.z] for s in e.spheres],
                               joints[:3])
    assert [round(s.color.r, 3) for s in e.spheres] == [round(QUALITY_COLORS[k][0], 3) for k in (2, 1, 2)]
    (line,) = e.lines
    assert line.type == 2 and len(line.points) == 4  # two bones a-b, b-c; d is missing
    pts = np.array([[pt.x, pt.y, pt.z] for pt in line.points])
    np.testing.assert_allclose(pts, joints[[0, 1, 1, 2]])
    assert line.colors[0].r == QUALITY_COLORS[1][0]  # a bone is as good as its worse end


def test_character_and_physics_bodies():
    b = SceneBuilder()
    b.feed(env("character_info", "CharacterInfo"),
           CharacterInfo(character="robot", joint_names=["root", "head"], joint_parent=np.array([-1, 0], np.int32),
                         rest_offsets=np.zeros((2, 3))))
    (out,) = b.feed(env("character_pose", "CharacterPose"),
                    CharacterPose(character="robot", frame_number=1, root_position=np.zeros(3),
                                  local_rotations=np.tile([1.0, 0, 0, 0], (2, 1)),
                                  joint_positions=np.array([[0, 0, 1.0], [0, 0, 1.6]])))
    e = decode(out).entities[0]
    assert e.id == "character_pose/robot" and len(e.spheres) == 2 and len(e.lines[0].points) == 2

    q = Rotation.from_euler("x", 90, degrees=True).as_quat(scalar_first=True)
    b.feed(env("physics_scene", "PhysicsScene"),
           PhysicsScene(body_names=["arm", "crate", "ball"], shapes=["capsule", "box", "sphere"],
                        sizes=np.array([[0.05, 0.2, 0], [0.3, 0.2, 0.1], [0.11, 0, 0]])))
    (out,) = b.feed(env("physics_state", "PhysicsState"),
                    PhysicsState(sim_time_s=0.5, positions=np.array([[0, 0, 1.0], [1, 0, 0.1], [2, 0, 0.11]]),
                                 orientations=np.array([q, [1, 0, 0, 0], [1, 0, 0, 0]]),
                                 tracking_error=np.array([0.01, np.nan, np.nan])))
    e = decode(out).entities[0]
    (cyl,) = e.cylinders
    assert (cyl.size.x, cyl.size.y, cyl.size.z) == (0.1, 0.1, 0.4)  # MuJoCo radius/half-length -> extents
    assert (cyl.pose.orientation.w, cyl.pose.orientation.x) == (q[0], q[1])
    (cube,) = e.cubes
    assert (cube.size.x, cube.size.y, cube.size.z) == (0.6, 0.4, 0.2)
    caps = sorted([round(s.pose.position.y, 6) for s in e.spheres if s.size.x == 0.1])
    assert caps == [-0.2, 0.2]  # capsule Z axis turned 90 deg about X points along -Y/+Y
    assert [s.size.x for s in e.spheres if s.size.x != 0.1] == [0.22]
    assert cyl.color.r == 1.0 and cube.color.r != 1.0  # tracked body vs untracked stage object


def test_diagnostics_become_plot_friendly_json():
    import json

    d = Diagnostics(node="solver", pid=1, uptime_s=2.0, cpu_s=0.5, edge_topics=["markers"], edge_senders=["r"],
                    edge_rate_hz=np.array([239.5]), edge_latency_ms=np.array([np.nan]),
                    edge_latency_max_ms=np.array([1.0]), edge_received=np.array([100]), edge_gaps=np.array([0]),
                    edge_rejected=np.array([0]), edge_anomalies=np.array([0]), output_topics=["actor_pose"], output_sent=np.array([99]))
    (out,) = SceneBuilder().feed(env("diagnostics", "Diagnostics"), d)
    assert out.topic == "/diagnostics/solver" and out.encoding == "json"
    rec = json.loads(out.data)
    assert rec["rate_hz"]["markers"] == 239.5 and rec["latency_ms"]["markers"] is None
    assert rec["sent"]["actor_pose"] == 99
