"""Helpers of the glTF tests: the Khronos validator (npm, node_modules/ at the repo root) and an
independent reading of a glTF file's animated joints (pygltflib's parser, our own arithmetic)."""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
VALIDATOR = REPO / "node_modules" / "gltf-validator"

_SCRIPT = """
const fs = require('fs');
const validator = require(process.argv[1]);
const data = new Uint8Array(fs.readFileSync(process.argv[2]));
validator.validateBytes(data, {maxIssues: 50})
  .then((report) => { console.log(JSON.stringify(report)); })
  .catch((e) => { console.log(JSON.stringify({fatal: String(e)})); });
"""


def khronos_report(path: Path) -> dict:
    """The Khronos glTF validator's report of a file (skips the test when node or the package is absent)."""
    node = shutil.which("node")
    if node is None or not VALIDATOR.is_dir():
        pytest.skip("the Khronos glTF validator is not installed (scripts/setup.sh: npm install)")
    r = subprocess.run([node, "-e", _SCRIPT, str(VALIDATOR), str(path)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def _accessor(doc, blob: bytes, i: int) -> np.ndarray:
    acc = doc.accessors[i]
    view = doc.bufferViews[acc.bufferView]
    n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[acc.type]
    dt = {5126: "<f4", 5123: "<u2", 5125: "<u4"}[acc.componentType]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    a = np.frombuffer(blob, dtype=dt, count=acc.count * n, offset=start)
    return a.reshape(acc.count, n) if n > 1 else a


def _quat_matrix(xyzw: np.ndarray) -> np.ndarray:
    x, y, z, w = np.moveaxis(np.asarray(xyzw, np.float64), -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                     np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                     np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def animated_world_positions(path: Path, frames: list[int]) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(node names, times [F], world positions [len(frames), N, 3] in glTF axes) of the skin's joints:
    the file read by pygltflib, each node's TRS at key ``f`` (its channel's output, else its rest
    value), composed down the node tree."""
    names, times, _r, world_p, doc, _blob = animated_nodes(path, frames)
    return names, times, world_p[:, doc.skins[0].joints]


def skinned_vertices(path: Path, frames: list[int]) -> np.ndarray:
    """[len(frames), V, 3] the first mesh's vertices skinned as glTF says (linear blend of joint world
    matrix x inverse bind matrix, JOINTS_0/WEIGHTS_0), glTF axes."""
    _names, _t, world_r, world_p, doc, blob = animated_nodes(path, frames)
    prim = doc.meshes[0].primitives[0]
    pos = _accessor(doc, blob, prim.attributes.POSITION).astype(np.float64)
    jts = _accessor(doc, blob, prim.attributes.JOINTS_0).astype(np.int64)
    wts = _accessor(doc, blob, prim.attributes.WEIGHTS_0).astype(np.float64)
    ibm = _accessor(doc, blob, doc.skins[0].inverseBindMatrices).astype(np.float64).reshape(-1, 4, 4)
    ibm = np.swapaxes(ibm, 1, 2)                       # stored column-major
    skin = np.asarray(doc.skins[0].joints)
    out = []
    for k in range(len(frames)):
        m = np.zeros((len(skin), 4, 4))
        m[:, :3, :3] = world_r[k, skin]
        m[:, :3, 3] = world_p[k, skin]
        m[:, 3, 3] = 1
        m = m @ ibm
        blend = np.einsum("vk,vkij->vij", wts, m[jts])
        out.append((blend[:, :3, :3] @ pos[..., None])[..., 0] + blend[:, :3, 3])
    return np.stack(out)


def animated_nodes(path: Path, frames: list[int]):
    """(joint names, times, world rotations [K, N, 3, 3], world positions [K, N, 3], doc, blob)."""
    import pygltflib
    doc = pygltflib.GLTF2().load(str(path))
    if doc.binary_blob() is None:      # a .gltf: its buffer is a data URI
        doc.convert_buffers(pygltflib.BufferFormat.BINARYBLOB)
    blob = doc.binary_blob()
    n = len(doc.nodes)
    t_node = np.array([nd.translation or [0, 0, 0] for nd in doc.nodes], np.float64)
    r_node = np.array([nd.rotation or [0, 0, 0, 1] for nd in doc.nodes], np.float64)
    anim = doc.animations[0]
    t_anim = np.broadcast_to(t_node, (len(frames), n, 3)).copy()
    r_anim = np.broadcast_to(r_node, (len(frames), n, 4)).copy()
    times = None
    for ch in anim.channels:
        s = anim.samplers[ch.sampler]
        times = _accessor(doc, blob, s.input)
        out = _accessor(doc, blob, s.output)
        if ch.target.path == "rotation":
            r_anim[:, ch.target.node] = out[frames]
        elif ch.target.path == "translation":
            t_anim[:, ch.target.node] = out[frames]
    parent = -np.ones(n, int)
    for i, nd in enumerate(doc.nodes):
        for c in nd.children or []:
            parent[c] = i
    world_r = np.zeros((len(frames), n, 3, 3))
    world_p = np.zeros((len(frames), n, 3))
    done = np.zeros(n, bool)
    while not done.all():   # resolve parents first (test code: clarity over speed)
        for i in range(n):
            if done[i] or (parent[i] >= 0 and not done[parent[i]]):
                continue
            lr = _quat_matrix(r_anim[:, i])
            if parent[i] < 0:
                world_r[:, i], world_p[:, i] = lr, t_anim[:, i]
            else:
                pr = world_r[:, parent[i]]
                world_r[:, i] = pr @ lr
                world_p[:, i] = world_p[:, parent[i]] + (pr @ t_anim[:, i][..., None])[..., 0]
            done[i] = True
    joints = doc.skins[0].joints
    return [doc.nodes[j].name for j in joints], times, world_r, world_p, doc, blob
