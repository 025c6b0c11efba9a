"""Blender's own glTF importer on our .glb: joint positions at sampled frames against the character's.

Not a test (Blender's Python module is a 350 MB wheel for one Python version): run it by hand with
a Python that has ``bpy`` (``python3.11 -m venv /tmp/bpy && /tmp/bpy/bin/pip install bpy==4.2.0``):

    .venv/bin/python scripts/blender_gltf_check.py --bpy-python /tmp/bpy/bin/python

It writes a 24-frame random take of the Mixamo character with its mannequin at 24 fps, imports it
into an empty Blender scene (bpy.ops.import_scene.gltf), reads every pose bone's head in the world
at frames 0, 5, 11 and 23, turns Blender's axes (Z up, front -Y) into ours and prints the largest
distance to the character's forward kinematics.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FRAMES = (0, 5, 11, 23)
READER = """
import bpy, json, sys
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=sys.argv[-2])
arm = [o for o in bpy.data.objects if o.type == "ARMATURE"][0]
out = {}
for f in %s:
    bpy.context.scene.frame_set(f)
    bpy.context.view_layer.update()
    out[f] = {b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones}
bpy.context.scene.frame_set(11)
mesh = [o for o in bpy.data.objects if o.type == "MESH" and o.name == "mannequin"][0]
ev = mesh.evaluated_get(bpy.context.evaluated_depsgraph_get())
verts = [list(ev.matrix_world @ v.co) for v in ev.to_mesh().vertices]
json.dump({"version": bpy.app.version_string, "frames": out, "verts11": verts}, open(sys.argv[-1], "w"))
""" % (list(FRAMES),)


def main() -> int:
    from mocapgraph.formats.character_file import load_character
    from mocapgraph.formats.gltf_export import write_gltf
    from mocapgraph.formats.mannequin import mannequin
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bpy-python", required=True, help="a Python interpreter that can `import bpy`")
    args = ap.parse_args()
    ch = load_character("mixamo")
    rng = np.random.default_rng(4)
    F = 24
    v = rng.normal(scale=0.5, size=(F, ch.n_joints, 3))
    a = np.linalg.norm(v, axis=-1, keepdims=True)
    q = np.concatenate([np.cos(a / 2), np.sin(a / 2) * v / np.maximum(a, 1e-12)], axis=-1)
    root = rng.normal(scale=0.3, size=(F, 3)) + [0, 0, 1]
    truth, _ = ch.forward_kinematics(q, root)
    with tempfile.TemporaryDirectory() as tmp:
        glb, out, reader = Path(tmp) / "take.glb", Path(tmp) / "heads.json", Path(tmp) / "reader.py"
        write_gltf(glb, ch, q, root, np.arange(F) / 24, mesh=mannequin(ch))
        reader.write_text(READER)
        r = subprocess.run([args.bpy_python, str(reader), str(glb), str(out)], capture_output=True, text=True,
                           timeout=600)
        if not out.exists():   # (bpy 4.2 as a module may crash at exit, after writing: the file decides)
            print(f"Blender's Python exited {r.returncode} without an answer:\n{r.stderr[-2000:]}")
            return 1
        got = json.loads(out.read_text())
    worst = 0.0
    for f, heads in got["frames"].items():
        b = np.array([heads[n] for n in ch.joint_names])
        ours = np.stack([-b[:, 1], b[:, 0], b[:, 2]], axis=1)      # Blender (x, y, z) -> ours (x fwd, y left, z up)
        worst = max(worst, float(np.abs(ours - truth[int(f)]).max()))
    # the mannequin as Blender skins it at frame 11, against our linear blend of the same weights
    from scipy.spatial import cKDTree
    mesh = mannequin(ch)
    p0, w0 = ch.forward_kinematics(as_matrices=True)
    p11, w11 = ch.forward_kinematics(q[11], root[11], as_matrices=True)
    moved = np.einsum("jab,jcb->jac", w11, w0)                          # W(f) W0^-1 per joint
    each = np.einsum("vkab,vkb->vka", moved[mesh.joints], mesh.positions[:, None] - p0[mesh.joints]) + p11[mesh.joints]
    ours_v = np.einsum("vk,vka->va", mesh.weights, each)
    b = np.array(got["verts11"])
    gap = float(cKDTree(ours_v).query(np.stack([-b[:, 1], b[:, 0], b[:, 2]], axis=1))[0].max())
    print(f"Blender {got['version']} glTF import: {ch.n_joints} joints at frames {list(FRAMES)}: "
          f"worst {worst * 1e6:.2f} um from the character's forward kinematics; its skinned mannequin at frame 11: "
          f"{len(b)} vertices, each within {gap * 1e6:.2f} um of our linear blend")
    return 0 if worst < 1e-4 and gap < 1e-4 else 1


if __name__ == "__main__":
    sys.exit(main())
