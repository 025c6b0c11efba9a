"""``bag export-foxglove``: the exported MCAP read back with the `mcap` library decodes one
SceneUpdate per source frame with the schema stored in the file; our bag is left byte for byte."""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

import numpy as np
import pytest
from mcap.reader import make_reader

from foxglove_decode import message_class
from mocapgraph.bag.foxglove_scene import QUALITY_COLORS
from mocapgraph.bag.reader import BagReader
from mocapgraph.bag.writer import BagWriter
from mocapgraph.cli import main
from mocapgraph.messages import (CharacterInfo, CharacterPose, Diagnostics, NodeStatus, PhysicsScene,
                                 PhysicsState)


@dataclass
class Result:
    returncode: int
    stdout: str
    stderr: str


@pytest.fixture
def _cli(capsys):
    """``mocapgraph ARGS`` in this process (the same main() as the command), output captured."""
    def run(*args):
        code = main([str(a) for a in args])
        out = capsys.readouterr()
        return Result(code, out.out, out.err)
    return run


def _read(path):
    """topic -> [(log_time, decoded message or JSON)] of an MCAP, decoded with its own schemas."""
    out: dict[str, list] = {}
    classes = {}
    with open(path, "rb") as f:
        for schema, channel, msg in make_reader(f).iter_messages(log_time_order=True):
            if channel.message_encoding == "protobuf":
                cls = classes.get(schema.id) or classes.setdefault(schema.id, message_class(schema.name, schema.data))
                value = cls.FromString(msg.data)
            else:
                assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
                value = json.loads(msg.data)
            out.setdefault(channel.topic, []).append((msg.log_time, schema.name, value))
    return out


def test_markers_and_actor_poses_export_frame_by_frame(capture, tmp_path, _cli):
    bag = tmp_path / "solved.mcap"
    assert _cli("solve", capture.trial, "--model", capture.model, "-o", bag).returncode == 0
    before = hashlib.sha256(capture.rom_bag.read_bytes()).hexdigest()
    r = _cli("bag", "export-foxglove", capture.rom_bag, "-o", tmp_path / "rom_fox.mcap")
    assert r.returncode == 0, r.stderr
    assert hashlib.sha256(capture.rom_bag.read_bytes()).hexdigest() == before  # our bag untouched
    assert "/markers:" in r.stdout

    got = _read(tmp_path / "rom_fox.mcap")
    with BagReader(capture.rom_bag) as src:
        frames = [(e, m) for e, m in src.decoded("markers")]
    scenes = got["/markers"]
    assert len(scenes) == len(frames)
    for (env, m), (log_ns, schema, upd) in zip(frames, scenes):
        assert schema == "foxglove.SceneUpdate"
        (ent,) = upd.entities
        ok = np.isfinite(m.positions).all(-1)
        assert len(ent.spheres) == ok.sum()
        pos = np.array([[s.pose.position.x, s.pose.position.y, s.pose.position.z] for s in ent.spheres])
        np.testing.assert_array_equal(pos, m.positions[ok])
        assert ent.timestamp.seconds * 10**9 + ent.timestamp.nanos == env.capture_ns
    print(f"\nexported {len(scenes)} marker frames, {len(scenes[0][2].entities[0].spheres)} spheres each")

    r = _cli("bag", "export-foxglove", bag, "-o", tmp_path / "solved_fox.mcap")
    assert r.returncode == 0, r.stderr
    got = _read(tmp_path / "solved_fox.mcap")
    with BagReader(bag) as src:
        poses = [m for _, m in src.decoded("actor_pose")]
        (model,) = [m for _, m in src.decoded("skeleton_model")]
    scenes = got["/actor_pose"]
    assert len(scenes) == len(poses)
    bones = int((model.joint_parent >= 0).sum())
    for p, (_, _, upd) in zip(poses, scenes):
        (ent,) = upd.entities
        drawn = (p.joint_quality > 0).sum()
        assert ent.id == "actor_pose/actor" and len(ent.spheres) == drawn
        if drawn == len(p.joint_quality):
            assert len(ent.lines[0].points) == 2 * bones


def test_characters_physics_and_diagnostics_from_constructed_messages(tmp_path, _cli):
    src = tmp_path / "built.mcap"
    T = 5
    with BagWriter(src) as w:
        w.write("character_info", CharacterInfo(character="robot", joint_names=["root", "spine", "head"],
                                                joint_parent=np.array([-1, 0, 1], np.int32),
                                                rest_offsets=np.zeros((3, 3)),
                                                rest_rotations=np.tile([1.0, 0, 0, 0], (3, 1))), seq=1, capture_ns=1)
        w.write("physics_scene", PhysicsScene(body_names=["thigh", "box"], shapes=["capsule", "box"],
                                              sizes=np.array([[0.06, 0.2, 0], [0.2, 0.2, 0.2]])),
                seq=1, capture_ns=1)
        for t in range(T):
            ns = 10**9 + t * 10**7
            jp = np.array([[0, 0, 1.0], [0, 0, 1.3], [0, 0.01 * t, 1.6]])
            w.write("character_pose", CharacterPose(character="robot", frame_number=t, root_position=jp[0],
                                                    local_rotations=np.tile([1.0, 0, 0, 0], (3, 1)),
                                                    joint_positions=jp, joint_quality=np.array([2, 2, 1], np.int8)),
                    seq=t + 1, capture_ns=ns)
            w.write("physics_state", PhysicsState(sim_time_s=t * 0.01, positions=np.array([[0, 0, 0.5], [1, 0, 0.2]]),
                                                  orientations=np.tile([1.0, 0, 0, 0], (2, 1)),
                                                  tracking_error=np.array([0.02, np.nan])), seq=t + 1, capture_ns=ns)
            w.write("calibration_status", NodeStatus(node="cal", state="idle", detail="", progress=0.0),
                    seq=t + 1, capture_ns=ns)
        w.write("diagnostics", Diagnostics(node="solver", pid=1, uptime_s=1.0, cpu_s=0.1, edge_topics=["markers"],
                                           edge_senders=["reader"], edge_rate_hz=np.array([240.0]),
                                           edge_latency_ms=np.array([0.4]), edge_latency_max_ms=np.array([2.0]),
                                           edge_received=np.array([240]), edge_gaps=np.array([0]),
                                           edge_rejected=np.array([0]), edge_anomalies=np.array([1]), output_topics=[], output_sent=np.zeros(0, int)),
                seq=1, capture_ns=2 * 10**9)
    r = _cli("bag", "export-foxglove", src, "-o", tmp_path / "out.mcap")
    assert r.returncode == 0, r.stderr
    got = _read(tmp_path / "out.mcap")
    status = got["/calibration_status"]
    assert len(status) == T and status[0][1] == "mocapgraph.NodeStatus" and status[0][2]["state"] == "idle"
    chars = got["/character_pose"]
    assert len(chars) == T
    assert [round(u.entities[0].spheres[2].pose.position.y, 6) for _, _, u in chars] == [0.01 * t for t in range(T)]
    assert all(len(u.entities[0].lines[0].points) == 4 for _, _, u in chars)
    # the retargeter's quality shows: the held head is drawn as estimated, not good
    head = chars[0][2].entities[0].spheres[2].color
    assert (head.r, head.g, head.b) == tuple(QUALITY_COLORS[1][:3])
    phys = got["/physics_state"]
    assert len(phys) == T
    e = phys[0][2].entities[0]
    assert len(e.cylinders) == 1 and len(e.cubes) == 1 and len(e.spheres) == 2
    ((_, schema, diag),) = got["/diagnostics/solver"]
    assert schema == "mocapgraph.DiagnosticsPlot" and diag["rate_hz"]["markers"] == 240.0
    assert diag["anomalies"]["markers"] == 1


def test_bad_input_is_one_line(tmp_path, capture, _cli):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not a bag at all" * 10)
    r = _cli("bag", "export-foxglove", junk, "-o", tmp_path / "o.mcap")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    r = _cli("bag", "export-foxglove", capture.rom_bag, "-o", tmp_path / "o.mcap", "--topics", "nope")
    assert r.returncode == 2 and "has no topic 'nope'" in r.stderr
    r = _cli("bag", "export-foxglove", capture.rom_bag, "-o", capture.rom_bag, "-f")
    assert r.returncode == 2 and "source bag" in r.stderr


def test_a_truncated_bag_exports_what_it_holds_and_says_so(capture, tmp_path, _cli):
    data = capture.rom_bag.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    r = _cli("bag", "export-foxglove", cut, "-o", tmp_path / "out.mcap")
    # Either the index is gone (one clear line, exit 2) or the read stops at the damage (exit 1,
    # everything before it exported and readable): never a traceback.
    assert "Traceback" not in r.stderr and r.returncode in (1, 2), (r.returncode, r.stdout, r.stderr)
    if r.returncode == 2:
        assert len(r.stderr.strip().splitlines()) == 1 and "recover" in r.stderr
    else:
        assert "stopped early" in r.stdout
        assert len(_read(tmp_path / "out.mcap")["/markers"]) > 0
