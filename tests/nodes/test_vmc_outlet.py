"""VMC protocol out: every bundle parses with python-osc; the sent bones, turned back into our axes
(Unity's left-handed Y-up frame undone with scipy's own quaternions), rebuild the character's joints
of ``character_pose`` within 1e-5 m, for the three shipped characters and from a real vmc_outlet
process; the rest pose sends identities; bones a character lacks and non-finite bones are left out;
at 60 Hz for 30 s no bundle is lost on loopback."""
from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avatar_support import locals_from_bones, parse, unity_world
from graph_helpers import read_jsonl, wait_until
from mocapgraph.formats.character_file import load_character
from mocapgraph.formats.vmc import VMCBundle, humanoid_bones
from mocapgraph.retarget.character import Character


def random_pose(ch: Character, rng) -> tuple[np.ndarray, np.ndarray]:
    """Every joint turned up to ~50 degrees, the root moved: (local rotations [J, 4] wxyz, root [3])."""
    rot = Rotation.from_rotvec(rng.normal(scale=0.5, size=(ch.n_joints, 3))).as_quat()[:, [3, 0, 1, 2]]
    return rot, ch.rest_offsets[ch.root] + rng.normal(scale=0.5, size=3) + [0, 0, 1.0]


def _character(name: str) -> Character:
    """A shipped character, or "turned": standard_20 with random rest orientations (as a glTF rig
    has), which a normalized VMC humanoid must not see: its rest pose still sends identities."""
    if name != "turned":
        return load_character(name)
    ch = load_character("standard_20")
    rest = Rotation.random(ch.n_joints, random_state=3).as_quat()[:, [3, 0, 1, 2]]
    return Character("turned", ch.joint_names, ch.parents, ch.rest_offsets, rest)


@pytest.mark.parametrize("name", ["standard_20", "mixamo", "cmu", "turned"])
def test_sent_bones_rebuild_the_characters_joints(name):
    ch = _character(name)
    vb = VMCBundle(ch)
    rng = np.random.default_rng(7)
    J = ch.n_joints
    # rest pose: identities, no displacement, tracking good
    rest = parse(vb.encode(np.tile([1.0, 0, 0, 0], (J, 1)), ch.rest_offsets[ch.root], np.full(J, 2), 0.0))
    assert rest["ok"] == [1, 3, 0, 1] and rest["t"] == 0.0
    np.testing.assert_allclose(rest["root"][0], 0, atol=1e-7)
    for _b, (_p, q) in rest["bones"].items():
        np.testing.assert_allclose(np.abs(q), [0, 0, 0, 1], atol=1e-7)
    worst = 0.0
    for _ in range(20):
        local, root = random_pose(ch, rng)
        truth, _ = ch.forward_kinematics(local, root)          # what character_pose carries
        parsed = parse(vb.encode(local, root, np.full(J, 2), 1.25))
        bones = humanoid_bones(ch)
        assert set(parsed["bones"]) == set(bones) and len(bones) >= 15
        world = unity_world(parsed, ch, bones)
        for b, j in bones.items():
            worst = max(worst, float(np.abs(world[b][0] - truth[ch.index(j)]).max()))
        # the sent rotations alone, on the character's rest skeleton (our own FK), rebuild every joint
        # where each joint that moves a child is a humanoid bone (standard_20, mixamo; cmu's
        # LHipJoint/lhand are not): the bar
        if name != "cmu":
            pos, _ = ch.forward_kinematics(locals_from_bones(world, ch, bones), root)
            np.testing.assert_allclose(pos, truth, atol=1e-5)
    assert worst < 1e-5, worst
    print(f"\n{name}: {len(vb.bone_names)} bones, worst joint {worst * 1e6:.2f} um over 20 random poses")


def test_bones_the_character_lacks_and_broken_bones_are_left_out():
    ch = load_character("cmu")
    vb = VMCBundle(ch)
    assert "LeftEye" not in vb.bone_names and "LeftIndexProximal" not in vb.bone_names
    J = ch.n_joints
    local = np.tile([1.0, 0, 0, 0], (J, 1))
    local[ch.index("LeftElbow")] = np.nan          # hostile input: the elbow and what hangs below it
    q = np.full(J, 2)
    q[ch.index("RightKnee")] = 1
    parsed = parse(vb.encode(local, ch.rest_offsets[0], q, 0.0))
    assert {"LeftLowerArm", "LeftHand"}.isdisjoint(parsed["bones"]) and "LeftUpperArm" in parsed["bones"]
    assert parsed["ok"][3] == 0        # an estimated knee: tracking is not "good"


class RawReceiver:
    """A UDP socket on a free loopback port keeping every datagram whole (parsed by the test)."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.datagrams: list[tuple[float, bytes]] = []
        self._run = True
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while self._run:
            try:
                self.datagrams.append((time.monotonic(), self.sock.recv(65536)))
            except socket.timeout:
                continue

    def close(self) -> None:
        self._run = False
        self.thread.join(2)
        self.sock.close()


def _graph(port: int, log, start_s: float, stop_s: float) -> str:
    return f"""
nodes:
  - name: dancer
    type: synthetic_character
    params: {{rate_hz: 60.0, start_s: {start_s}, stop_s: {stop_s}, loop: false}}
  - name: vmc
    type: vmc_outlet
    params: {{port: {port}}}
  - name: log
    type: topic_logger
    params: {{path: "{log}", topics: [character_pose, character_info]}}
"""


def test_a_vmc_outlet_process_sends_what_character_pose_says(launch_graph, tmp_path):
    rx = RawReceiver()
    log = tmp_path / "poses.jsonl"
    try:
        g = launch_graph(_graph(rx.port, log, 17.0, 20.0))   # 3 s of the walk
        g.wait_ready()
        wait_until(lambda: len(rx.datagrams) >= 150, 30, "VMC bundles", g)
        g.stop()
    finally:
        rx.close()
    info = read_jsonl(log, "character_info")[-1]["msg"]
    ch = Character(info["character"], tuple(info["joint_names"]), info["joint_parent"], info["rest_offsets"],
                   info["rest_rotations"], allow_zero_bones=True)
    poses = [r["msg"] for r in read_jsonl(log, "character_pose")]
    truth = np.array([p["joint_positions"] for p in poses])
    bones = humanoid_bones(ch)
    worst, hips = 0.0, ch.index(bones["Hips"])
    for _, data in rx.datagrams:
        parsed = parse(data)
        world = unity_world(parsed, ch, bones)
        # the pose this bundle carries: the logged one whose hips are where the bundle puts them
        k = int(np.argmin(np.abs(truth[:, hips] - world["Hips"][0]).max(axis=1)))
        pos, _ = ch.forward_kinematics(locals_from_bones(world, ch, bones), world["Hips"][0])
        worst = max(worst, float(np.abs(pos - truth[k]).max()))
    print(f"\nVMC from a node: {len(rx.datagrams)} bundles, worst joint {worst * 1e6:.2f} um")
    assert worst < 1e-5


@pytest.mark.timing
def test_60_hz_for_30_s_loses_nothing_on_loopback(launch_graph, tmp_path):
    rx = RawReceiver()
    log = tmp_path / "poses.jsonl"
    try:
        g = launch_graph(_graph(rx.port, log, 17.0, 47.0))   # 1800 poses at 60 Hz
        g.wait_ready()
        wait_until(lambda: len(read_jsonl(log, "character_pose")) >= 1800, 60, "1800 poses", g)
        time.sleep(0.5)
        g.stop()
    finally:
        rx.close()
    poses = len(read_jsonl(log, "character_pose"))
    times = np.array([t for t, _ in rx.datagrams])
    for _, data in rx.datagrams:
        parse(data)
    rate = (len(times) - 1) / (times[-1] - times[0])
    print(f"\nVMC 60 Hz x 30 s: {len(times)} bundles received of {poses} poses, {rate:.2f} Hz")
    assert poses == 1800 and len(times) == poses
    assert 59.0 < rate < 61.0


def test_a_vrm_avatar_live_from_a_bvh_with_no_mapping_file(launch_graph, tmp_path, shared_data):
    """bvh_player (CMU 131_01) -> retargeter onto a VRM the test wrote (VRoid-style names, no mapping
    file) -> vmc_outlet naming the bones from the same file's humanoid map: Unity's forward kinematics
    over the bundles puts every sent bone where the logged character_pose has its joint."""
    from avatar_support import write_vrm
    from mocapgraph.formats.gltf_character import load_gltf_character
    avatar = tmp_path / "avatar.vrm"
    write_vrm(avatar, "1.0")
    gc = load_gltf_character(avatar)
    rx = RawReceiver()
    log = tmp_path / "poses.jsonl"
    try:
        g = launch_graph(f"""
nodes:
  - name: reader
    type: bvh_player
    params: {{file: "{shared_data / 'bvh/cmu/131_01.bvh'}", loop: false}}
  - name: retargeter
    type: retargeter
    params: {{source: skeleton, character: "{avatar}"}}
  - name: vmc
    type: vmc_outlet
    params: {{port: {rx.port}, avatar: "{avatar}"}}
  - name: log
    type: topic_logger
    params: {{path: "{log}", topics: [character_pose, character_info]}}
""")
        g.wait_ready()
        wait_until(lambda: len(rx.datagrams) >= 120, 60, "VMC bundles from the retargeted avatar", g)
        g.stop()
    finally:
        rx.close()
    info = read_jsonl(log, "character_info")[-1]["msg"]
    assert tuple(info["joint_names"]) == gc.character.joint_names
    ch = gc.character
    truth = np.array([r["msg"]["joint_positions"] for r in read_jsonl(log, "character_pose")])
    hips = ch.index(gc.humanoid["Hips"])
    worst, moved = 0.0, 0.0
    for _, data in rx.datagrams:
        parsed = parse(data)
        assert set(parsed["bones"]) == set(gc.humanoid)            # all 54 bones, by the VRM's map
        world = unity_world(parsed, ch, gc.humanoid)
        k = int(np.argmin(np.abs(truth[:, hips] - world["Hips"][0]).max(axis=1)))
        for b, j in gc.humanoid.items():
            worst = max(worst, float(np.abs(world[b][0] - truth[k, ch.index(j)]).max()))
        moved = max(moved, float(np.abs(parsed["bones"]["LeftLowerLeg"][1][:3]).max()))
    print(f"\nVRM avatar live: {len(rx.datagrams)} bundles of {len(gc.humanoid)} bones; worst bone {worst * 1e6:.2f} um "
          f"from character_pose")
    assert worst < 1e-5 and moved > 0.05       # the knee does bend: a walk, not the rest pose


def test_bone_tables_that_do_not_fit_are_one_line():
    from mocapgraph.bus.node import NodeConfigError
    from mocapgraph.formats.vmc import VMCError
    from mocapgraph.nodes.vmc_outlet import VMCOutlet
    ch = load_character("mixamo")
    for table, needle in (({"Hips": "Hips", "LeftElbow": "LeftForeArm"}, "not Unity humanoid bones"),
                          ({"Hips": "Pelvis"}, "has no joint 'Pelvis'"),
                          ({"Spine": "Spine"}, "no joint maps to the Hips"),
                          ({"Hips": "Hips", "Spine": "Hips"}, "one joint is given to two Unity bones")):
        with pytest.raises(VMCError, match=needle):
            humanoid_bones(ch, table)
    with pytest.raises(VMCError, match="no joint maps to the Hips"):   # a rig no table knows
        humanoid_bones(Character("odd", ("a", "b"), [-1, 0], [[0, 0, 1], [0, 0, 0.5]], [[1, 0, 0, 0]] * 2))
    with pytest.raises(NodeConfigError, match="LeftElbow"):            # refused when the node is built
        VMCOutlet("vmc", {"bones": {"Hips": "Hips", "LeftElbow": "LeftForeArm"}})
