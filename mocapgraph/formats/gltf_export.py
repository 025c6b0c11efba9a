"""glTF 2.0 / GLB export of a character: its skeleton as a skin, its animation, an optional skinned mesh.

The container is laid out by pygltflib; this module decides what goes in it:

* one node per joint (end sites included), named as the joint, with the joint's rest offset as
  ``translation`` and its rest orientation as ``rotation``; the root's translation is its rest
  place in the world;
* a skin over those nodes with inverse bind matrices (the inverse of each joint's rest world
  transform) and the root as ``skeleton``;
* an animation ``take`` with, per joint, a ``rotation`` channel (the node's rotation each frame:
  rest orientation times the local rotation of ``CharacterPose``) and, for the root, a
  ``translation`` channel (its world position), keyed at the source's frame times (from 0 s),
  LINEAR (slerp; successive quaternions kept in one hemisphere so no key turns the long way);
* with a mesh (:class:`SkinnedMesh`, e.g. the generated mannequin), a mesh node using the skin.

Axes: glTF is Y up with the asset's front towards +Z, +X to its left (right-handed, metres);
ours is Z up, X forward, Y left, so ``gltf = G @ ours`` with ``G`` below (a proper rotation:
quaternion vector parts turn with it). :func:`write_gltf` writes ``.glb`` (binary) or ``.gltf``
(one JSON file, the buffer inlined as a data URI) atomically: a temporary file in the same folder,
renamed over the target when whole, removed on any failure.
"""
from __future__ import annotations

import base64
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..kinematics.quaternion import quat_multiply
from ..retarget.character import Character

#: ours (X forward, Y left, Z up) -> glTF (X left, Y up, Z forward)
G = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])

# glTF constants
FLOAT, UNSIGNED_SHORT, UNSIGNED_INT = 5126, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
MAX_JOINTS = 65535   # JOINTS_0 is unsigned short


class GltfExportError(ValueError):
    """What cannot be written as glTF (one line)."""


@dataclass
class SkinnedMesh:
    """A mesh bound to a character's joints, in our world frame at the rest pose (metres)."""

    positions: np.ndarray   # float [V, 3]
    normals: np.ndarray     # float [V, 3], unit
    triangles: np.ndarray   # int [T, 3], counter-clockwise seen from outside
    joints: np.ndarray      # int [V, 4] joint indices
    weights: np.ndarray     # float [V, 4], rows sum to 1
    name: str = "body"


def to_gltf_quat_xyzw(q_wxyz: np.ndarray) -> np.ndarray:
    """Our wxyz quaternions as glTF's xyzw, axes turned by G."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    return np.concatenate([q[..., 1:] @ G.T, q[..., :1]], axis=-1)


def hemisphere_continuous(q: np.ndarray) -> np.ndarray:
    """Quaternion keys [F, ..., 4] with each key's sign chosen so it is within 90 degrees of the
    previous one (the same rotations; linear slerp between keys takes the short way)."""
    if len(q) < 2:
        return q
    flip = np.einsum("f...i,f...i->f...", q[1:], q[:-1]) < 0
    sign = np.concatenate([np.ones((1,) + flip.shape[1:]), np.cumprod(np.where(flip, -1.0, 1.0), axis=0)])
    return q * sign[..., None]


class _Blob:
    """The one binary buffer: 4-byte aligned views, and accessors over them."""

    def __init__(self) -> None:
        import pygltflib as gl
        self.gl = gl
        self.parts: list[bytes] = []
        self.size = 0
        self.views: list = []
        self.accessors: list = []

    def add(self, data: np.ndarray, type_: str, component: int, *, target: int | None = None,
            minmax: bool = False) -> int:
        raw = np.ascontiguousarray(data).tobytes()
        self.views.append(self.gl.BufferView(buffer=0, byteOffset=self.size, byteLength=len(raw), target=target))
        pad = -len(raw) % 4
        self.parts.append(raw + b"\0" * pad)
        self.size += len(raw) + pad
        count = len(data)
        acc = self.gl.Accessor(bufferView=len(self.views) - 1, byteOffset=0, componentType=component, count=count,
                               type=type_)
        if minmax:
            flat = np.asarray(data, dtype=np.float64).reshape(count, -1)
            acc.min = [float(v) for v in flat.min(axis=0)]
            acc.max = [float(v) for v in flat.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def rest_world_matrices(ch: Character) -> np.ndarray:
    """[J, 4, 4] rest world transforms of the joints in glTF axes."""
    p0, w0 = ch.forward_kinematics(as_matrices=True)
    m = np.zeros((ch.n_joints, 4, 4))
    m[:, :3, :3] = G @ w0 @ G.T
    m[:, :3, 3] = p0 @ G.T
    m[:, 3, 3] = 1.0
    return m


def character_gltf(ch: Character, local_rotations: np.ndarray | None = None, root_positions: np.ndarray | None = None,
                   times_s: np.ndarray | None = None, *, mesh: SkinnedMesh | None = None,
                   vrm_humanoid: dict[str, str] | None = None):
    """The glTF document (pygltflib.GLTF2, its buffer set) of a character and, with local rotations
    [F, J, 4] wxyz, root positions [F, 3] m and strictly increasing frame times [F] s, its animation;
    with ``vrm_humanoid`` (Unity bone -> joint), the VRM 1.0 extension that makes it a VRM avatar."""
    gl = __import__("pygltflib")
    J = ch.n_joints
    if J > MAX_JOINTS:
        raise GltfExportError(f"{ch.name}: {J} joints; glTF skins here take at most {MAX_JOINTS}")
    blob = _Blob()
    nodes = []
    children: list[list[int]] = [[] for _ in range(J)]
    for j in np.flatnonzero(ch.parents >= 0):
        children[int(ch.parents[j])].append(int(j))
    trans = ch.rest_offsets @ G.T
    rest_q = to_gltf_quat_xyzw(ch.rest_rotations)
    for j, name in enumerate(ch.joint_names):
        node = gl.Node(name=name, translation=[float(v) for v in trans[j]], children=children[j] or None)
        if not np.allclose(rest_q[j], [0, 0, 0, 1], atol=1e-12):
            node.rotation = [float(v) for v in rest_q[j]]
        if ch.end_sites[j]:
            node.extras = {"end_site": True}   # a leaf marker (BVH End Site), read back by gltf_character
        nodes.append(node)
    ibm = np.linalg.inv(rest_world_matrices(ch))
    ibm[:, 3] = [0.0, 0.0, 0.0, 1.0]
    ibm_acc = blob.add(np.swapaxes(ibm, 1, 2).astype(np.float32).reshape(J, 16), "MAT4", FLOAT)
    skin = gl.Skin(name=f"{ch.name}_skin", joints=list(range(J)), skeleton=ch.root, inverseBindMatrices=ibm_acc)
    scene_nodes = [ch.root]
    meshes = []
    if mesh is not None:
        meshes.append(_mesh(blob, mesh, J))
        nodes.append(gl.Node(name=mesh.name, mesh=0, skin=0))
        scene_nodes.append(len(nodes) - 1)
    animations = []
    if local_rotations is not None:
        animations.append(_animation(blob, ch, local_rotations, root_positions, times_s))
    doc = gl.GLTF2(asset=gl.Asset(version="2.0", generator="mocapgraph (pygltflib)"), scene=0,
                   scenes=[gl.Scene(name=ch.name, nodes=scene_nodes)], nodes=nodes, skins=[skin],
                   meshes=meshes, animations=animations, accessors=blob.accessors, bufferViews=blob.views)
    if vrm_humanoid is not None:
        from .vrm_export import VrmExportError, vrm_extension
        try:
            ext = vrm_extension(ch.name, vrm_humanoid, {n: j for j, n in enumerate(ch.joint_names)})
        except VrmExportError as exc:
            raise GltfExportError(str(exc)) from None
        doc.extensionsUsed = ["VRMC_vrm"]
        doc.extensions = {"VRMC_vrm": ext}
    data = blob.bytes()
    doc.buffers = [gl.Buffer(byteLength=len(data))]
    doc.set_binary_blob(data)
    return doc


def _animation(blob: _Blob, ch: Character, local_rotations, root_positions, times_s):
    gl = blob.gl
    q = np.asarray(local_rotations, dtype=np.float64)
    F, J = q.shape[0], ch.n_joints
    if q.shape != (F, J, 4) or F == 0:
        raise GltfExportError(f"{ch.name}: local rotations of shape {q.shape}, expected [frames, {J}, 4]")
    t = np.asarray(times_s, dtype=np.float64).reshape(-1)
    root = np.asarray(root_positions, dtype=np.float64).reshape(-1, 3)
    if len(t) != F or len(root) != F:
        raise GltfExportError(f"{ch.name}: {F} frames of rotations, {len(t)} times, {len(root)} root positions")
    t = t - t[0]
    t32 = t.astype(np.float32)
    if not np.isfinite(t).all() or (F > 1 and not (np.diff(t32) > 0).all()):
        raise GltfExportError(f"{ch.name}: frame times are not strictly increasing (glTF keys must be)")
    if not (np.isfinite(q).all() and np.isfinite(root).all()):
        raise GltfExportError(f"{ch.name}: non-finite rotations or root positions (nothing written)")
    node_q = quat_multiply(ch.rest_rotations[None], q)                # rest * local, [F, J, 4]
    node_q /= np.linalg.norm(node_q, axis=-1, keepdims=True)
    keys = hemisphere_continuous(to_gltf_quat_xyzw(node_q)).astype(np.float32)
    t_acc = blob.add(t32, "SCALAR", FLOAT, minmax=True)
    samplers, channels = [], []
    for j in range(J):   # one sampler per joint: the layout, not per-frame work
        out = blob.add(keys[:, j], "VEC4", FLOAT)
        samplers.append(gl.AnimationSampler(input=t_acc, output=out, interpolation="LINEAR"))
        channels.append(gl.AnimationChannel(sampler=j, target=gl.AnimationChannelTarget(node=j, path="rotation")))
    out = blob.add((root @ G.T).astype(np.float32), "VEC3", FLOAT)
    samplers.append(gl.AnimationSampler(input=t_acc, output=out, interpolation="LINEAR"))
    channels.append(gl.AnimationChannel(sampler=J, target=gl.AnimationChannelTarget(node=ch.root, path="translation")))
    return gl.Animation(name="take", samplers=samplers, channels=channels)


def _mesh(blob: _Blob, mesh: SkinnedMesh, n_joints: int):
    gl = blob.gl
    pos = (np.asarray(mesh.positions, np.float64) @ G.T).astype(np.float32)
    nrm = np.asarray(mesh.normals, np.float64) @ G.T
    nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)
    joints = np.asarray(mesh.joints)
    if joints.min() < 0 or joints.max() >= n_joints:
        raise GltfExportError(f"mesh {mesh.name}: joint indices outside the skin's {n_joints} joints")
    w = np.asarray(mesh.weights, np.float64)
    w = (w / w.sum(axis=1, keepdims=True)).astype(np.float32)
    joints = np.where(w > 0, joints, 0).astype(np.uint16)   # unused slots name joint 0 with weight 0
    attrs = gl.Attributes(POSITION=blob.add(pos, "VEC3", FLOAT, target=ARRAY_BUFFER, minmax=True),
                          NORMAL=blob.add(nrm, "VEC3", FLOAT, target=ARRAY_BUFFER),
                          JOINTS_0=blob.add(joints, "VEC4", UNSIGNED_SHORT, target=ARRAY_BUFFER),
                          WEIGHTS_0=blob.add(w, "VEC4", FLOAT, target=ARRAY_BUFFER))
    idx = blob.add(np.asarray(mesh.triangles, np.uint32).reshape(-1), "SCALAR", UNSIGNED_INT,
                   target=ELEMENT_ARRAY_BUFFER)
    return gl.Mesh(name=mesh.name, primitives=[gl.Primitive(attributes=attrs, indices=idx, mode=4)])


def gltf_file_bytes(doc, kind: str) -> bytes:
    """The bytes of a ``.glb`` (binary container) or ``.gltf`` (JSON, buffer as a data URI)."""
    if kind in (".glb", ".vrm"):
        return b"".join(doc.save_to_bytes())
    data = doc.binary_blob()
    doc.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(data).decode("ascii")
    try:
        return doc.gltf_to_json().encode("utf-8")
    finally:
        doc.buffers[0].uri = None


def write_atomic(path: str | Path, data: bytes) -> None:
    """``data`` into ``path`` whole or not at all (a temporary file beside it, renamed when complete)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_gltf(path: str | Path, ch: Character, local_rotations: np.ndarray | None = None,
               root_positions: np.ndarray | None = None, times_s: np.ndarray | None = None, *,
               mesh: SkinnedMesh | None = None, vrm_humanoid: dict[str, str] | None = None) -> int:
    """A character (and its animation, and a mesh) as ``.glb``, ``.gltf`` or ``.vrm`` (a GLB with the
    VRM 1.0 humanoid map ``vrm_humanoid``), written atomically; returns the bytes written.
    GltfExportError (one line) for what glTF cannot hold."""
    kind = Path(path).suffix.lower()
    if kind not in (".glb", ".gltf", ".vrm"):
        raise GltfExportError(f"{path}: not a .glb, .gltf or .vrm name")
    if kind == ".vrm" and not vrm_humanoid:
        raise GltfExportError(f"{path}: a .vrm needs the character's humanoid bone map")
    doc = character_gltf(ch, local_rotations, root_positions, times_s, mesh=mesh,
                         vrm_humanoid=vrm_humanoid if kind == ".vrm" else None)
    data = gltf_file_bytes(doc, kind)
    write_atomic(path, data)
    return len(data)
