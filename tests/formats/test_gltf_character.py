"""glTF/VRM characters in: a glTF character round-trips (load -> export -> load) with identical joints;
a VRM 1.0 and a VRM 0.x avatar the test writes itself (VRoid-style node names no role table knows,
the humanoid map in the file) retarget with no mapping file exactly as the rig they were built from;
bad files (no skin, a broken buffer, a cyclic node tree, 10^5 joints) are one clear line each and
the retarget command writes nothing."""
from __future__ import annotations

import contextlib
import io
import json
import struct
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pygltflib
import pytest

from avatar_support import vroid_name, write_vrm
from mocapgraph.formats.character_file import CharacterFileError, load_character
from mocapgraph.formats.gltf_character import load_gltf_character
from mocapgraph.formats.gltf_export import write_gltf
from mocapgraph.formats.retarget_setup import build, source_from_skeleton_info
from mocapgraph.retarget.mapping import MappingError


def _same_joints(a, b) -> None:
    assert a.joint_names == b.joint_names
    assert (a.parents == b.parents).all() and (a.end_sites == b.end_sites).all()
    np.testing.assert_allclose(a.rest_offsets, b.rest_offsets, atol=1e-12)
    np.testing.assert_allclose(np.abs((a.rest_rotations * b.rest_rotations).sum(1)), 1, atol=1e-12)


@pytest.mark.parametrize("name", ["mixamo", "cmu", "standard_20"])
def test_a_gltf_character_round_trips(tmp_path, name):
    ch = load_character(name)
    write_gltf(tmp_path / "a.glb", ch)
    once = load_character(tmp_path / "a.glb")
    _same_joints(once, ch)
    write_gltf(tmp_path / "b.gltf", once)
    _same_joints(load_character(tmp_path / "b.gltf"), once)


def test_rest_rotations_and_scaled_nodes_come_through(tmp_path):
    """A rig with its own rest orientations and a centimetre armature (scale 0.01 on a parent node,
    as FBX-born files have): the joints land where the file's node tree puts them."""
    ch = load_character("standard_20")
    rng = np.random.default_rng(5)
    q = rng.normal(size=(ch.n_joints, 4))
    from mocapgraph.retarget.character import Character
    turned = Character("t", ch.joint_names, ch.parents, ch.rest_offsets, q / np.linalg.norm(q, axis=1, keepdims=True))
    write_gltf(tmp_path / "t.glb", turned)
    back = load_character(tmp_path / "t.glb")
    _same_joints(back, turned)
    pos0, _ = turned.rest_pose()
    # wrap the skeleton in an "Armature" node scaled 0.01 with its joints' translations in cm
    doc = pygltflib.GLTF2().load(str(tmp_path / "t.glb"))
    for nd in doc.nodes:
        nd.translation = [100 * v for v in nd.translation]
    doc.nodes.append(pygltflib.Node(name="Armature", scale=[0.01, 0.01, 0.01], children=[ch.root]))
    doc.scenes[0].nodes = [len(doc.nodes) - 1]
    doc.save(str(tmp_path / "cm.glb"))
    cm = load_character(tmp_path / "cm.glb")
    assert cm.joint_names == ch.joint_names          # Armature is no joint (the skin's joints have one root)
    pos, _ = cm.rest_pose()
    np.testing.assert_allclose(pos, pos0, atol=1e-9)


# ----- VRM ---------------------------------------------------------------------------------------
def _source():
    """A BVH-like skeleton stream to retarget from: standard_20 (Kinect v1 names) with orientations."""
    s20 = load_character("standard_20")
    return s20, source_from_skeleton_info(s20.joint_names, s20.parents, s20.rest_offsets, has_orientations=True)


@pytest.mark.parametrize("version", ["1.0", "0.x"])
def test_a_vrm_avatar_needs_no_mapping_file(tmp_path, version):
    path = tmp_path / "avatar.vrm"
    table = write_vrm(path, version)
    gc = load_gltf_character(path)
    assert gc.vrm == version
    assert gc.humanoid == {b: vroid_name(b) for b in table}    # every Unity bone found, thumbs too
    mix = load_character("mixamo")
    # the same skeleton as the rig it was built from, facing forward (0.x turned back)
    pos_vrm, _ = gc.character.rest_pose()
    pos_mix, _ = mix.rest_pose()
    np.testing.assert_allclose(pos_vrm, pos_mix + [0, 0, 0.9], atol=1e-9)
    s20, src = _source()
    on_vrm = build(str(path), None, src)                       # no mapping file
    on_mix = build("mixamo", None, src)
    by_name = {e.joint: e for e in on_mix.mapping.joints}
    mine = {e.joint: e for e in on_vrm.mapping.joints}
    rename = {j: vroid_name(b) for b, j in table.items()}
    assert {rename.get(j, "J_Sec_" + j) for j in by_name} == set(mine) and len(mine) >= 15
    for j, e in by_name.items():
        f = mine[rename.get(j, "J_Sec_" + j)]
        assert (f.mode, f.rotation, f.position) == (e.mode, e.rotation, e.position)
    # and it moves the same: a few source frames of standard_20 turning its joints
    rng = np.random.default_rng(2)
    from scipy.spatial.transform import Rotation
    F = 5
    q = Rotation.from_rotvec(rng.normal(scale=0.3, size=(F * s20.n_joints, 3))).as_quat()[:, [3, 0, 1, 2]]
    q = q.reshape(F, s20.n_joints, 4)
    pts, world = s20.forward_kinematics(q, np.tile([0, 0, 1.0], (F, 1)))
    ok = np.ones(pts.shape[:2], bool)
    t = np.arange(F) / 30
    r_vrm = on_vrm.retargeter.process(pts, ok, world, ok, t)
    r_mix = on_mix.retargeter.process(pts, ok, world, ok, t)
    np.testing.assert_allclose(r_vrm.local_rotations, r_mix.local_rotations, atol=1e-9)


def test_without_the_humanoid_map_the_odd_names_do_not_map(tmp_path):
    """The control: the same file without its VRM extension gives a mapping of the root alone."""
    path = tmp_path / "avatar.vrm"
    write_vrm(path, "1.0")
    doc = pygltflib.GLTF2().load_binary(str(path))
    doc.extensions, doc.extensionsUsed = {}, []
    doc.save_binary(str(tmp_path / "plain.glb"))
    _, src = _source()
    try:
        m = build(str(tmp_path / "plain.glb"), None, src).mapping
        assert len(m.joints) <= 1
    except MappingError:
        pass


# ----- bad files ---------------------------------------------------------------------------------
def _gltf(tmp_path: Path, name: str, doc: dict) -> Path:
    p = tmp_path / name
    p.write_text(json.dumps(doc))
    return p


def _bad_files(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    ch = load_character("standard_20")
    write_gltf(tmp_path / "good.glb", ch, np.tile([1.0, 0, 0, 0], (2, ch.n_joints, 1)), np.zeros((2, 3)) + 1,
               [0, 0.1])
    data = (tmp_path / "good.glb").read_bytes()
    (tmp_path / "cut.glb").write_bytes(data[: len(data) - 200])
    doc = json.loads(data[20: 20 + struct.unpack_from("<I", data, 12)[0]])
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64,AAAA"      # 3 bytes for thousands
    big = {"asset": {"version": "2.0"}, "nodes": [{"name": f"j{i}", "children": [i + 1]} for i in range(99_999)]
           + [{"name": "last"}], "skins": [{"joints": list(range(100_000))}]}
    return {
        "no skin": (_gltf(tmp_path, "noskin.gltf", {"asset": {"version": "2.0"}, "nodes": [{"name": "a"}]}),
                    "no skin"),
        "GLB cut short": (tmp_path / "cut.glb", "cut short"),
        "broken buffer": (_gltf(tmp_path, "buffer.gltf", doc), "broken buffer"),
        "cyclic tree": (_gltf(tmp_path, "cycle.gltf", {"asset": {"version": "2.0"}, "nodes": [
            {"name": "a", "children": [1]}, {"name": "b", "children": [2]}, {"name": "c", "children": [0]}],
            "skins": [{"joints": [0, 1, 2]}]}), "cyclic node tree"),
        "two parents": (_gltf(tmp_path, "dag.gltf", {"asset": {"version": "2.0"}, "nodes": [
            {"name": "a", "children": [2]}, {"name": "b", "children": [2]}, {"name": "c"}],
            "skins": [{"joints": [0, 1, 2]}]}), "not a tree"),
        "10^5 joints": (_gltf(tmp_path, "huge.gltf", big), "at most 4096"),
        "not glTF": (_gltf(tmp_path, "text.gltf", {"hello": 1}), "not a glTF 2.0"),
    }


def test_bad_files_are_one_clear_line_each(tmp_path):
    import time
    for what, (path, needle) in _bad_files(tmp_path).items():
        t0 = time.perf_counter()
        with pytest.raises(CharacterFileError) as info:
            load_character(path)
        msg = str(info.value)
        assert needle in msg and "\n" not in msg and msg.startswith(str(path)), (what, msg)
        assert time.perf_counter() - t0 < 10.0, what     # bounded work, never a hang (0.3 s for 10^5 idle)
        print(f"\n{what}: {msg}")


def test_the_retarget_command_writes_nothing_for_a_bad_character(tmp_path):
    from mocapgraph.cli import main
    from mocapgraph.cli.retarget_cmds import write_character_bvh
    s20 = load_character("standard_20")
    res = SimpleNamespace(local_rotations=np.tile([1.0, 0, 0, 0], (10, s20.n_joints, 1)),
                          root_positions=np.tile(s20.rest_offsets[0], (10, 1)))
    write_character_bvh(tmp_path / "trial.bvh", s20, res, 1 / 30)
    bad = _bad_files(tmp_path)
    for what, (path, needle) in bad.items():
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(["retarget", str(tmp_path / "trial.bvh"), "--character", str(path), "-o",
                         str(tmp_path / "out.glb")])
        lines = [x for x in err.getvalue().splitlines() if x.strip()]
        assert code != 0 and len(lines) == 1 and needle in lines[0], (what, err.getvalue())
        assert not (tmp_path / "out.glb").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".part")]
    # and the good file does retarget
    code = main(["retarget", str(tmp_path / "trial.bvh"), "--character", str(tmp_path / "good.glb"), "-o",
                 str(tmp_path / "out.glb")])
    assert code == 0 and (tmp_path / "out.glb").exists()


def test_vmc_names_a_vrm_avatars_bones_from_its_humanoid_map(tmp_path):
    """The VMC bundle of the VRM avatar (bones from its humanoid map) says what Mixamo's says (its
    table tested against Unity-style forward kinematics in tests/nodes/test_vmc_outlet.py)."""
    from pythonosc.osc_bundle import OscBundle
    from scipy.spatial.transform import Rotation

    from mocapgraph.formats.vmc import VMCBundle
    path = tmp_path / "avatar.vrm"
    write_vrm(path, "1.0")
    gc = load_gltf_character(path)
    mix = load_character("mixamo")
    rng = np.random.default_rng(9)
    q = Rotation.from_rotvec(rng.normal(scale=0.5, size=(mix.n_joints, 3))).as_quat()[:, [3, 0, 1, 2]]

    def bones(ch, table, root):
        data = VMCBundle(ch, table).encode(q, root, np.full(ch.n_joints, 2), 0.0)
        return {m.params[0]: np.array(m.params[1:]) for m in OscBundle(data) if m.address.endswith("Bone/Pos")}
    a = bones(gc.character, gc.humanoid, [0.1, 0.2, 1.9])
    b = bones(mix, None, [0.1, 0.2, 1.0])
    assert set(a) == set(b) and len(a) == 54
    for k in a:
        np.testing.assert_allclose(a[k][3:], b[k][3:], atol=1e-6)        # rotations
        if k != "Hips":
            np.testing.assert_allclose(a[k][:3], b[k][:3], atol=1e-6)    # bone places


@pytest.mark.parametrize("name", ["mixamo", "standard_20"])
def test_a_character_goes_out_as_vrm_and_comes_back_with_its_map(tmp_path, name):
    from gltf_support import khronos_report
    from mocapgraph.formats.gltf_export import GltfExportError
    from mocapgraph.formats.mannequin import mannequin
    from mocapgraph.formats.vmc import humanoid_bones
    ch = load_character(name)
    table = humanoid_bones(ch)
    write_gltf(tmp_path / "out.vrm", ch, mesh=mannequin(ch), vrm_humanoid=table)
    report = khronos_report(tmp_path / "out.vrm")
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0
    back = load_gltf_character(tmp_path / "out.vrm")
    assert back.vrm == "1.0" and back.humanoid == table           # thumbs and all, through VRM 1.0's names
    _same_joints(back.character, ch)
    # a rig without the bones VRM requires is refused in one line, nothing written
    with pytest.raises(GltfExportError, match="cannot be a VRM avatar: no joint for the humanoid bones Spine"):
        write_gltf(tmp_path / "bad.vrm", ch, vrm_humanoid={b: j for b, j in table.items() if b != "Spine"})
    assert not (tmp_path / "bad.vrm").exists()
