"""Our .glb in three.js: its GLTFLoader (from npm, node_modules/three) in headless Chromium loads the
file, its AnimationMixer plays the take, and the skeleton's bones sit where `character_pose` puts the
joints (within 1e-4 m) at sampled key times; three's own skinning of the mannequin's vertices agrees
with the linear blend our test reader computes from the file."""
from __future__ import annotations

import functools
import http.server
import json
import threading
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gltf_support import REPO, animated_world_positions, skinned_vertices
from mocapgraph.formats.character_file import load_character
from mocapgraph.formats.gltf_export import write_gltf
from mocapgraph.formats.mannequin import mannequin

pytestmark = pytest.mark.slow   # a browser

THREE = REPO / "node_modules" / "three"
OURS_FROM_GLTF = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

PAGE = """<!doctype html><html><body>
<script type="importmap">{"imports": {"three": "/three/build/three.module.js",
                                      "three/addons/": "/three/examples/jsm/"}}</script>
<script type="module">
import * as THREE from 'three';
import {GLTFLoader} from 'three/addons/loaders/GLTFLoader.js';
const TIMES = %(times)s, VERTS = %(verts)s;
new GLTFLoader().load('/a.glb', (gltf) => {
  let mesh = null;
  gltf.scene.traverse((o) => { if (o.isSkinnedMesh && !mesh) mesh = o; });
  const mixer = new THREE.AnimationMixer(gltf.scene);
  const action = mixer.clipAction(gltf.animations[0]);
  action.setLoop(THREE.LoopOnce); action.clampWhenFinished = true; action.play();
  const bones = [], verts = [], v = new THREE.Vector3();
  for (const t of TIMES) {
    mixer.setTime(t);
    gltf.scene.updateMatrixWorld(true);
    mesh.skeleton.update();
    bones.push(mesh.skeleton.bones.map((b) => b.getWorldPosition(v).toArray()));
    verts.push(VERTS.map((i) => { mesh.getVertexPosition(i, v); return v.applyMatrix4(mesh.matrixWorld).toArray(); }));
  }
  window.result = {names: mesh.skeleton.bones.map((b) => b.name), bones, verts,
                   clip: gltf.animations[0].name, duration: gltf.animations[0].duration};
}, undefined, (e) => { window.result = {error: String(e)}; });
</script></body></html>
"""


def _serve(folder: Path):
    handler = functools.partial(_Quiet, directory=str(folder))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


class _Quiet(http.server.SimpleHTTPRequestHandler):
    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map, ".js": "text/javascript"}

    def log_message(self, *args) -> None:
        pass


def test_threejs_gltfloader_plays_our_glb(tmp_path, browser):
    if not THREE.is_dir():
        pytest.skip("three.js is not installed (scripts/setup.sh: npm ci)")
    ch = load_character("mixamo")
    F = 12
    rng = np.random.default_rng(4)
    q = Rotation.from_rotvec(rng.normal(scale=0.5, size=(F * ch.n_joints, 3))).as_quat()[:, [3, 0, 1, 2]]
    q = q.reshape(F, ch.n_joints, 4)
    root = rng.normal(scale=0.3, size=(F, 3)) + [0, 0, 1]
    write_gltf(tmp_path / "a.glb", ch, q, root, np.arange(F) / 24, mesh=mannequin(ch))
    frames = [0, 3, 7, F - 1]
    _names, times, _ = animated_world_positions(tmp_path / "a.glb", frames)
    verts = [int(i) for i in rng.choice(len(mannequin(ch).positions), 60, replace=False)]
    (tmp_path / "three").symlink_to(THREE)
    (tmp_path / "index.html").write_text(PAGE % {"times": json.dumps([float(times[f]) for f in frames]),
                                                 "verts": json.dumps(verts)})
    server = _serve(tmp_path)
    try:
        page = browser.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(f"http://127.0.0.1:{server.server_address[1]}/index.html")
        page.wait_for_function("window.result !== undefined", timeout=30_000)
        result = page.evaluate("window.result")
        page.close()
    finally:
        server.shutdown()
    assert "error" not in result and not errors, (result.get("error"), errors)
    assert result["names"] == list(ch.joint_names) and result["clip"] == "take"
    assert abs(result["duration"] - (F - 1) / 24) < 1e-5
    truth, _ = ch.forward_kinematics(q[frames], root[frames])           # character_pose's joints
    bones = np.array(result["bones"]) @ OURS_FROM_GLTF.T
    worst = float(np.abs(bones - truth).max())
    ours = skinned_vertices(tmp_path / "a.glb", frames)[:, verts]
    skin_gap = float(np.abs(np.array(result["verts"]) - ours).max())
    print(f"\nthree.js GLTFLoader: {len(frames)} key times x {ch.n_joints} bones, worst {worst * 1e6:.2f} um from "
          f"character_pose; its skinning of 60 vertices vs ours: {skin_gap * 1e6:.2f} um")
    assert worst < 1e-4 and skin_gap < 1e-4
