"""The generated mannequin: a skinned body from the character's own bones, written into the glTF by
our code. The Khronos validator reports 0 errors and 0 warnings; skinned as the file says (its
weights, joints, inverse bind matrices and animated nodes, read back by pygltflib), the middle of
every capsule keeps its distance to its bone as `character_pose` moves it, and the blend zones stay
near the joint they bend around; a glTF character's own mesh comes back from the file it was written to."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gltf_support import khronos_report, skinned_vertices
from mocapgraph.formats.character_file import load_character
from mocapgraph.formats.gltf_character import load_gltf_character
from mocapgraph.formats.gltf_export import write_gltf
from mocapgraph.formats.mannequin import mannequin

OURS_FROM_GLTF = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _segment_distance(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(np.einsum("vi,vi->v", x - a, ab) / np.einsum("vi,vi->v", ab, ab), 0, 1)
    return np.linalg.norm(x - (a + t[:, None] * ab), axis=1)


@pytest.mark.parametrize("name", ["mixamo", "cmu", "standard_20"])
def test_the_mannequin_follows_the_character(tmp_path, name):
    ch = load_character(name)
    mesh = mannequin(ch)
    F = 6
    rng = np.random.default_rng(11)
    q = Rotation.from_rotvec(rng.normal(scale=0.5, size=(F * ch.n_joints, 3))).as_quat()[:, [3, 0, 1, 2]]
    q = q.reshape(F, ch.n_joints, 4)
    root = rng.normal(scale=0.3, size=(F, 3)) + [0, 0, 1]
    write_gltf(tmp_path / "m.glb", ch, q, root, np.arange(F) / 30, mesh=mesh)
    report = khronos_report(tmp_path / "m.glb")
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0, report["issues"]["messages"][:5]
    verts = skinned_vertices(tmp_path / "m.glb", list(range(F))) @ OURS_FROM_GLTF.T
    truth, _ = ch.forward_kinematics(q, root)                       # character_pose's joints
    p0, _ = ch.rest_pose()
    parent, child = mesh.joints[:, 0], mesh.joints[:, 2]
    rigid = mesh.weights[:, 0] == 1.0
    rest_d = _segment_distance(mesh.positions, p0[parent], p0[child])
    worst = 0.0
    for f in range(F):
        d = _segment_distance(verts[f], truth[f, parent], truth[f, child])
        worst = max(worst, float(np.abs(d - rest_d)[rigid].max()))
        # a blended vertex stays within its capsule's reach of the joint it bends around
        near = np.where(mesh.weights[:, 1] > 0, parent, child)[~rigid]
        reach = np.linalg.norm(mesh.positions[~rigid] - p0[near], axis=1)
        assert (np.linalg.norm(verts[f][~rigid] - truth[f, near], axis=1) <= reach + 1e-4).all()
    print(f"\n{name}: {len(mesh.positions)} vertices, {len(mesh.triangles)} triangles, {rigid.mean() * 100:.0f} % "
          f"rigid; rigid vertices keep their distance to the bone within {worst * 1e6:.2f} um")
    assert rigid.mean() > 0.25 and worst < 1e-4


def test_a_gltf_characters_own_mesh_comes_back(tmp_path):
    ch = load_character("mixamo")
    mesh = mannequin(ch)
    write_gltf(tmp_path / "avatar.glb", ch, mesh=mesh)
    back = load_gltf_character(tmp_path / "avatar.glb").mesh
    assert back is not None and (back.triangles == mesh.triangles).all()
    np.testing.assert_allclose(back.positions, mesh.positions, atol=1e-6)       # float32 in the file
    w = mesh.weights > 0
    assert (back.joints[w] == mesh.joints[w]).all()
    np.testing.assert_allclose(back.weights, mesh.weights, atol=1e-6)
    # an avatar of several skinned primitives (body, face, hair...): all of them, one mesh
    import pygltflib
    doc = pygltflib.GLTF2().load(str(tmp_path / "avatar.glb"))
    doc.meshes[0].primitives.append(doc.meshes[0].primitives[0])
    doc.save(str(tmp_path / "two.glb"))
    two = load_gltf_character(tmp_path / "two.glb").mesh
    V = len(mesh.positions)
    assert len(two.positions) == 2 * V and (two.triangles[len(mesh.triangles):] == mesh.triangles + V).all()
    np.testing.assert_allclose(two.positions[V:], mesh.positions, atol=1e-6)
