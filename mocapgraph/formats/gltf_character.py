"""glTF/GLB/VRM characters in: a file's skin as a Character, its VRM humanoid bone map, its skinned mesh.

What :func:`load_gltf_character` makes of a ``.glb``, ``.gltf`` or ``.vrm`` (a GLB):

* the joints: every node of every skin (and every VRM humanoid bone node), parents before
  children; a joint's parent is its nearest ancestor that is a joint; when the joints form
  several trees their lowest common ancestor node (an "Armature") becomes the root joint;
* the rest pose: the nodes' own transforms (TRS or matrix, scale baked into the offsets), turned
  from glTF's axes (Y up, the asset's front towards +Z) into ours (Z up, X forward); a VRM 0.x
  avatar faces -Z (Unity's export), so its root is turned half a turn to face forward;
* the humanoid map (Unity bone -> joint name) of a VRM 0.x (``extensions.VRM.humanoid``) or 1.0
  (``extensions.VRMC_vrm.humanoid``) file, so no mapping file is needed
  (:func:`mocapgraph.formats.retarget_setup.build` derives the mapping through it);
* every skinned triangle primitive bound to those joints, as one mesh at the rest pose (positions,
  normals, triangles, four weights per vertex: JOINTS_0/WEIGHTS_0; materials and textures are
  not carried), when there is one.

The container is read here (a GLB is a 12-byte header and two chunks; pygltflib's reader builds a
dataclass per field, 30 s for 10^5 nodes, and bounds nothing), every count and offset checked
against the bytes there are. Every fault is one ``CharacterFileError`` line naming the file and
the place: not glTF, no skin, a buffer shorter than declared, a node that is its own ancestor or
has two parents, more joints than :data:`MAX_JOINTS`.
"""
from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..kinematics.quaternion import matrix_to_quat, quat_to_matrix
from ..retarget.character import Character, CharacterError
from .gltf_export import G, SkinnedMesh

MAX_JOINTS = 4096          # a humanoid with fingers, face and hair bones has a few hundred
MAX_NODES = 200_000
MAX_BYTES = 1 << 30        # 1 GiB
GLTF_SUFFIXES = (".glb", ".gltf", ".vrm")

_COMPONENTS = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_TURN_Y = np.diag([-1.0, 1.0, -1.0])     # half a turn about glTF's up axis


class GltfCharacterError(ValueError):
    """A glTF file that is no usable character (one line: file, place, fault)."""


@dataclass
class GltfCharacter:
    """What a glTF/VRM file holds for us."""

    character: Character
    humanoid: dict[str, str] = field(default_factory=dict)   # Unity bone -> joint name (VRM)
    vrm: str = ""                                             # "", "0.x" or "1.0"
    mesh: SkinnedMesh | None = None
    node_of_joint: np.ndarray | None = None


# ----- the container -----------------------------------------------------------------------------
class _Doc:
    """A glTF document: its JSON and its buffers' bytes, with bounded accessor reads."""

    def __init__(self, path: Path) -> None:
        self.path = path
        size = path.stat().st_size
        if size > MAX_BYTES:
            raise self.fail(f"{size / 2**20:.0f} MiB is beyond {MAX_BYTES >> 20} MiB")
        data = path.read_bytes()
        bin_chunk = None
        if data[:4] == b"glTF":
            self.json, bin_chunk = self._glb(data)
        else:
            try:
                self.json = json.loads(data.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise self.fail(f"not a glTF file (no GLB header, and not JSON: {exc})") from None
        if not isinstance(self.json, dict) or str(self.json.get("asset", {}).get("version", "")).split(".")[0] != "2":
            raise self.fail("not a glTF 2.0 document (asset.version is not 2.x)")
        self.buffers = [self._buffer(i, b, bin_chunk) for i, b in enumerate(self._list("buffers"))]

    def fail(self, msg: str) -> GltfCharacterError:
        return GltfCharacterError(f"{self.path}: {msg}")

    def _list(self, key: str) -> list:
        v = self.json.get(key, [])
        if not isinstance(v, list):
            raise self.fail(f"{key}: not a list")
        return v

    def _glb(self, data: bytes) -> tuple[dict, bytes | None]:
        if len(data) < 20:
            raise self.fail(f"GLB of {len(data)} bytes: shorter than its header")
        _magic, version, length = struct.unpack_from("<4sII", data, 0)
        if version != 2:
            raise self.fail(f"GLB version {version} (only 2 is glTF 2.0)")
        if length > len(data):
            raise self.fail(f"GLB says {length} bytes but the file has {len(data)} (cut short)")
        pos, doc, binary = 12, None, None
        while pos + 8 <= length:
            n, kind = struct.unpack_from("<II", data, pos)
            if pos + 8 + n > length:
                raise self.fail(f"GLB chunk at byte {pos} says {n} bytes, beyond the file's end (cut short)")
            chunk = data[pos + 8: pos + 8 + n]
            if kind == 0x4E4F534A and doc is None:
                try:
                    doc = json.loads(chunk.decode("utf-8"))
                except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                    raise self.fail(f"GLB JSON chunk does not parse: {exc}") from None
            elif kind == 0x004E4942 and binary is None:
                binary = chunk
            pos += 8 + n
        if doc is None:
            raise self.fail("GLB without a JSON chunk")
        return doc, binary

    def _buffer(self, i: int, b: dict, bin_chunk: bytes | None) -> bytes:
        if not isinstance(b, dict):
            raise self.fail(f"buffers[{i}]: not an object")
        uri = b.get("uri")
        if uri is None:
            data = bin_chunk if i == 0 and bin_chunk is not None else b""
        elif isinstance(uri, str) and uri.startswith("data:"):
            try:
                data = base64.b64decode(uri.split(",", 1)[1], validate=True)
            except (IndexError, ValueError):
                raise self.fail(f"buffers[{i}]: the data URI is not base64") from None
        else:
            p = (self.path.parent / str(uri)).resolve()
            if p.parent != self.path.parent.resolve() or not p.is_file():
                raise self.fail(f"buffers[{i}]: {uri!r} is not a file beside it")
            data = p.read_bytes()
        want = b.get("byteLength")
        if not isinstance(want, int) or want < 0:
            raise self.fail(f"buffers[{i}]: byteLength {want!r} is not a size")
        if len(data) < want:
            raise self.fail(f"buffers[{i}]: byteLength {want} but only {len(data)} bytes there (a broken buffer)")
        return data[:want]

    def accessor(self, i: object, what: str) -> np.ndarray:
        """Accessor ``i`` as float64 [count, width] (or [count]), every offset checked."""
        accs = self._list("accessors")
        if not isinstance(i, int) or not 0 <= i < len(accs):
            raise self.fail(f"{what}: accessor {i!r} does not exist")
        a = accs[i]
        where = f"{what} (accessors[{i}])"
        dt = _COMPONENTS.get(a.get("componentType"))
        width = _WIDTH.get(a.get("type"))
        count = a.get("count")
        if dt is None or width is None or not isinstance(count, int) or count < 0:
            raise self.fail(f"{where}: componentType/type/count not understood")
        views = self._list("bufferViews")
        v = a.get("bufferView")
        if not isinstance(v, int) or not 0 <= v < len(views):
            raise self.fail(f"{where}: bufferView {v!r} does not exist (sparse accessors are not read)")
        view = views[v]
        buf_i = view.get("buffer")
        if not isinstance(buf_i, int) or not 0 <= buf_i < len(self.buffers):
            raise self.fail(f"{where}: buffer {buf_i!r} does not exist")
        buf = self.buffers[buf_i]
        v_off, v_len = int(view.get("byteOffset", 0)), int(view.get("byteLength", -1))
        if v_off < 0 or v_len < 0 or v_off + v_len > len(buf):
            raise self.fail(f"{where}: bufferViews[{v}] spans bytes {v_off}..{v_off + v_len} of a "
                            f"{len(buf)}-byte buffer (a broken buffer)")
        item = np.dtype(dt).itemsize * width
        stride = int(view.get("byteStride") or item)
        off = int(a.get("byteOffset", 0))
        if count and (stride < item or off < 0 or off + stride * (count - 1) + item > v_len):
            raise self.fail(f"{where}: {count} items of {item} bytes do not fit bufferViews[{v}] ({v_len} bytes)")
        raw = np.frombuffer(buf, np.uint8, count=v_len, offset=v_off)[off:]
        rows = np.lib.stride_tricks.as_strided(raw, shape=(count, item), strides=(stride, 1)) if count else raw[:0]
        out = np.ascontiguousarray(rows).view(dt).reshape(count, width).astype(np.float64)
        if a.get("normalized"):
            out /= float(np.iinfo(np.dtype(dt)).max)
        return out[:, 0] if width == 1 else out


# ----- the node tree -----------------------------------------------------------------------------
def _node_matrix(doc: _Doc, i: int, n: dict) -> np.ndarray:
    m = np.eye(4)
    try:
        if "matrix" in n:
            m = np.asarray(n["matrix"], dtype=np.float64).reshape(4, 4).T    # column-major in the file
        else:
            t = np.asarray(n.get("translation", [0, 0, 0]), dtype=np.float64).reshape(3)
            x, y, z, w = np.asarray(n.get("rotation", [0, 0, 0, 1]), dtype=np.float64).reshape(4)
            s = np.asarray(n.get("scale", [1, 1, 1]), dtype=np.float64).reshape(3)
            m[:3, :3] = quat_to_matrix(np.array([w, x, y, z]) / np.linalg.norm([w, x, y, z])) * s
            m[:3, 3] = t
    except (TypeError, ValueError):
        raise doc.fail(f"nodes[{i}]: translation/rotation/scale/matrix are not numbers of the right count") from None
    if not np.isfinite(m).all():
        raise doc.fail(f"nodes[{i}]: its transform is not finite")
    return m


def _tree(doc: _Doc, nodes: list) -> tuple[np.ndarray, list[int]]:
    """(parent of every node [-1 for roots], the nodes in an order with parents first)."""
    n = len(nodes)
    parent = np.full(n, -1)
    name = lambda i: f"nodes[{i}] ({nodes[i].get('name', '')!r})"  # noqa: E731
    for i, nd in enumerate(nodes):
        if not isinstance(nd, dict):
            raise doc.fail(f"nodes[{i}]: not an object")
        for c in nd.get("children", []) or []:
            if not isinstance(c, int) or not 0 <= c < n:
                raise doc.fail(f"{name(i)}: child {c!r} is not a node")
            if c == i:
                raise doc.fail(f"{name(i)} is its own child (a cyclic node tree)")
            if parent[c] >= 0:
                raise doc.fail(f"{name(c)} is a child of both nodes[{parent[c]}] and nodes[{i}] (not a tree)")
            parent[c] = i
    order, reached = [], np.zeros(n, bool)
    frontier = list(np.flatnonzero(parent < 0))
    children: list[list[int]] = [[] for _ in range(n)]
    for c in np.flatnonzero(parent >= 0):
        children[parent[c]].append(int(c))
    frontier.reverse()
    while frontier:   # depth first, children in their listed order
        i = int(frontier.pop())
        reached[i] = True
        order.append(i)
        frontier.extend(children[i][::-1])
    if not reached.all():
        bad = int(np.flatnonzero(~reached)[0])
        raise doc.fail(f"{name(bad)} is its own ancestor (a cyclic node tree)")
    return parent, order


def _vrm_humanoid(doc: _Doc, n_nodes: int) -> tuple[dict[str, int], str]:
    """Unity bone -> node of a VRM 1.0 or 0.x file ({}, "" for plain glTF)."""
    ext = doc.json.get("extensions") or {}
    bones: dict[str, int] = {}
    if isinstance(ext.get("VRMC_vrm"), dict):
        raw = ((ext["VRMC_vrm"].get("humanoid") or {}).get("humanBones") or {})
        items = [(k, v.get("node") if isinstance(v, dict) else None) for k, v in raw.items()] if isinstance(raw, dict) else []
        version = "1.0"
    elif isinstance(ext.get("VRM"), dict):
        raw = ((ext["VRM"].get("humanoid") or {}).get("humanBones") or [])
        items = [(b.get("bone"), b.get("node")) for b in raw if isinstance(b, dict)] if isinstance(raw, list) else []
        version = "0.x"
    else:
        return {}, ""
    for bone, node in items:
        if not isinstance(bone, str) or not bone:
            continue
        if not isinstance(node, int) or not 0 <= node < n_nodes:
            raise doc.fail(f"VRM humanoid bone {bone!r}: node {node!r} is not a node")
        bones[vrm_bone_to_unity(bone, version)] = node
    return bones, version


def vrm_bone_to_unity(bone: str, version: str) -> str:
    """A VRM humanoid bone name as Unity's HumanBodyBones name (VRM 1.0 shifts the thumb's names)."""
    if version == "1.0":
        for side in ("left", "right"):
            for old, new in (("ThumbMetacarpal", "ThumbProximal"), ("ThumbProximal", "ThumbIntermediate")):
                if bone == f"{side}{old}":
                    bone = f"{side}{new}"
                    break
            else:
                continue
            break
    return bone[:1].upper() + bone[1:]


def load_gltf_character(path: str | Path, *, name: str | None = None) -> GltfCharacter:
    """A character from a .glb/.gltf/.vrm file (see the module docstring); GltfCharacterError otherwise."""
    path = Path(path)
    doc = _Doc(path)
    nodes = doc._list("nodes")
    skins = doc._list("skins")
    if not skins:
        raise doc.fail(f"no skin: a glTF character is a skinned skeleton, and this file has {len(nodes)} nodes and "
                       "no skins (export the armature with its mesh)")
    joint_set: set[int] = set()
    for k, skin in enumerate(skins):
        js = skin.get("joints") if isinstance(skin, dict) else None
        if not isinstance(js, list) or not js:
            raise doc.fail(f"skins[{k}]: no joints")
        if len(js) > MAX_JOINTS:
            raise doc.fail(f"skins[{k}] has {len(js)} joints; a character takes at most {MAX_JOINTS}")
        if not all(isinstance(j, int) and 0 <= j < len(nodes) for j in js):
            raise doc.fail(f"skins[{k}]: a joint index is not a node")
        joint_set.update(js)
    if len(nodes) > MAX_NODES:
        raise doc.fail(f"{len(nodes)} nodes; at most {MAX_NODES} are read")
    parent, order = _tree(doc, nodes)
    humanoid_nodes, vrm = _vrm_humanoid(doc, len(nodes))
    joint_set.update(humanoid_nodes.values())
    if len(joint_set) > MAX_JOINTS:
        raise doc.fail(f"{len(joint_set)} joints; a character takes at most {MAX_JOINTS}")
    joint_set = _single_root(doc, joint_set, parent, nodes)
    joints = _joint_order(skins, joint_set, parent, order)
    world = _world_matrices(doc, nodes, parent, order)
    ch = _character(doc, nodes, joints, parent, world, vrm, name or path.stem)
    names = ch.joint_names
    node_of = np.array(joints)
    humanoid = {b: names[joints.index(nd)] for b, nd in humanoid_nodes.items()}
    mesh = _skinned_mesh(doc, skins, node_of, world)
    if mesh is not None and vrm == "0.x":
        mesh.positions = mesh.positions * [-1.0, -1.0, 1.0]
        mesh.normals = mesh.normals * [-1.0, -1.0, 1.0]
    return GltfCharacter(ch, humanoid, vrm, mesh, node_of)


def _joint_order(skins: list, joint_set: set[int], parent: np.ndarray, order: list[int]) -> list[int]:
    """The skins' own joint order when it has parents first (a round trip keeps it), else the tree's."""
    listed: list[int] = []
    for skin in skins:
        listed += [j for j in skin["joints"] if j not in listed]
    listed += [j for j in order if j in joint_set and j not in listed]
    rank = {j: k for k, j in enumerate(listed)}
    ok = True
    for j in listed:
        a = int(parent[j])
        while a >= 0 and a not in rank:
            a = int(parent[a])
        ok = ok and (a < 0 or rank[a] < rank[j])
    return listed if ok else [i for i in order if i in joint_set]


def _single_root(doc: _Doc, joint_set: set[int], parent: np.ndarray, nodes: list) -> set[int]:
    def ancestors(i: int) -> list[int]:
        out = []
        while i >= 0:
            out.append(i)
            i = int(parent[i])
        return out
    roots = []
    for j in joint_set:
        a = int(parent[j])
        while a >= 0 and a not in joint_set:
            a = int(parent[a])
        if a < 0:
            roots.append(j)
    if len(roots) == 1:
        return joint_set
    common = set(ancestors(roots[0]))
    for r in roots[1:]:
        common &= set(ancestors(r))
    if not common:
        names = ", ".join(repr(nodes[r].get("name", r)) for r in roots[:4])
        raise doc.fail(f"the joints form {len(roots)} separate trees ({names}) with no common ancestor node")
    lca = max(common, key=lambda i: len(ancestors(i)))
    return joint_set | {lca}


def _world_matrices(doc: _Doc, nodes: list, parent: np.ndarray, order: list[int]) -> np.ndarray:
    world = np.empty((len(nodes), 4, 4))
    for i in order:   # once at load, parents first
        m = _node_matrix(doc, i, nodes[i])
        world[i] = m if parent[i] < 0 else world[parent[i]] @ m
    return world


def _names(nodes: list, joints: list[int]) -> tuple[str, ...]:
    out, seen = [], set()
    for i in joints:
        base = str(nodes[i].get("name") or f"node{i}").strip() or f"node{i}"
        n, k = base, 2
        while n in seen:
            n, k = f"{base}_{k}", k + 1
        seen.add(n)
        out.append(n)
    return tuple(out)


def _character(doc: _Doc, nodes: list, joints: list[int], parent: np.ndarray, world: np.ndarray, vrm: str,
               name: str) -> Character:
    idx = {nd: k for k, nd in enumerate(joints)}
    jpar = []
    for nd in joints:
        a = int(parent[nd])
        while a >= 0 and a not in idx:
            a = int(parent[a])
        jpar.append(idx.get(a, -1))
    jpar = np.array(jpar)
    m = world[joints]
    if vrm == "0.x":       # VRM 0.x faces -Z: the whole avatar half a turn about the up axis
        m = np.concatenate([_TURN_Y @ m[:, :3], m[:, 3:]], axis=1)
    lin = m[:, :3, :3]
    u, _s, vt = np.linalg.svd(lin)
    rot = u @ vt
    if (np.linalg.det(rot) < 0).any():
        bad = joints[int(np.flatnonzero(np.linalg.det(rot) < 0)[0])]
        raise doc.fail(f"nodes[{bad}] ({nodes[bad].get('name', '')!r}): a mirrored (negative scale) joint")
    r = G.T @ rot @ G                           # our axes
    p = m[:, :3, 3] @ G                         # G.T @ p per row
    has_par = jpar >= 0
    pp = np.where(has_par, jpar, 0)
    r_par = np.where(has_par[:, None, None], r[pp], np.eye(3))
    offsets = np.where(has_par[:, None], (np.swapaxes(r_par, 1, 2) @ (p - p[pp])[..., None])[..., 0], p)
    rest = matrix_to_quat(np.swapaxes(r_par, 1, 2) @ r)
    ends = np.array([bool((nodes[i].get("extras") or {}).get("end_site", False))
                     if isinstance(nodes[i].get("extras"), dict) else False for i in joints])
    try:
        return Character(name, _names(nodes, joints), jpar, offsets, rest, ends, allow_zero_bones=True)
    except CharacterError as exc:
        raise doc.fail(str(exc)) from None


def _skinned_mesh(doc: _Doc, skins: list, node_of: np.ndarray, world: np.ndarray) -> SkinnedMesh | None:
    """Every triangle primitive skinned to these joints, as one mesh in our axes at the rest pose
    (None: none). Four influences a vertex (JOINTS_0/WEIGHTS_0); materials are not carried."""
    joint_of_node = {int(nd): k for k, nd in enumerate(node_of)}
    parts: list[tuple] = []
    names: list[str] = []
    meshes = doc._list("meshes")
    for i, nd in enumerate(doc._list("nodes")):
        if not isinstance(nd.get("mesh"), int) or not isinstance(nd.get("skin"), int):
            continue
        if not 0 <= nd["skin"] < len(skins) or not 0 <= nd["mesh"] < len(meshes):
            raise doc.fail(f"nodes[{i}]: its mesh or skin does not exist")
        for k, prim in enumerate(meshes[nd["mesh"]].get("primitives", [])):
            part = _primitive(doc, prim, f"meshes[{nd['mesh']}].primitives[{k}]", skins[nd["skin"]], nd["skin"],
                              joint_of_node, world)
            if part is not None:
                parts.append(part)
                names.append(str(meshes[nd["mesh"]].get("name") or "mesh"))
    if not parts:
        return None
    base = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    pos, nrm, tri, jts, wts = (np.concatenate(x) for x in zip(*[(p[0], p[1], p[2] + b, p[3], p[4])
                                                             for p, b in zip(parts, base)]))
    return SkinnedMesh(pos @ G, nrm @ G, tri, jts, wts, name=names[0] if len(set(names)) == 1 else "body")


def _primitive(doc: _Doc, prim: dict, where: str, skin: dict, skin_i: int, joint_of_node: dict, world: np.ndarray):
    """(positions, normals, triangles, joints, weights) of one skinned primitive at the rest pose,
    glTF axes; None for what is not a skinned triangle list."""
    att = prim.get("attributes", {}) if isinstance(prim, dict) else {}
    if not {"POSITION", "JOINTS_0", "WEIGHTS_0"} <= set(att) or prim.get("mode", 4) != 4:
        return None
    pos = doc.accessor(att["POSITION"], f"{where} POSITION")
    v = len(pos)
    nrm = doc.accessor(att["NORMAL"], f"{where} NORMAL") if "NORMAL" in att else np.tile([0.0, 1.0, 0.0], (v, 1))
    jts = doc.accessor(att["JOINTS_0"], f"{where} JOINTS_0").astype(np.int64)
    wts = doc.accessor(att["WEIGHTS_0"], f"{where} WEIGHTS_0")
    tri = doc.accessor(prim["indices"], f"{where} indices").astype(np.int64) if "indices" in prim else np.arange(v)
    if len(nrm) != v or len(jts) != v or len(wts) != v or len(tri) % 3 or (len(tri) and (tri.min() < 0 or tri.max() >= v)):
        raise doc.fail(f"{where}: attribute counts or indices do not agree")
    skin_joints = np.asarray(skin["joints"])
    if jts.max(initial=0) >= len(skin_joints):
        raise doc.fail(f"{where}: JOINTS_0 names joint {int(jts.max())} of a {len(skin_joints)}-joint skin")
    ours = np.array([joint_of_node.get(int(n), -1) for n in skin_joints])
    mapped = ours[jts]
    if (mapped[wts > 0] < 0).any():
        raise doc.fail(f"{where}: a weighted joint is not a joint of the character")
    # a vertex skinned at the bind pose sits where the skin puts it: joint world x inverse bind
    if "inverseBindMatrices" in skin:
        ibm = doc.accessor(skin["inverseBindMatrices"], f"skins[{skin_i}] inverseBindMatrices")
        if len(ibm) != len(skin_joints):
            raise doc.fail(f"skins[{skin_i}]: {len(ibm)} inverse bind matrices for {len(skin_joints)} joints")
        ibm = ibm.reshape(-1, 4, 4).transpose(0, 2, 1)
    else:
        ibm = np.broadcast_to(np.eye(4), (len(skin_joints), 4, 4))
    skin_m = world[skin_joints] @ ibm                                   # [K, 4, 4]
    blend = np.einsum("vk,vkij->vij", wts / wts.sum(1, keepdims=True).clip(1e-12), skin_m[jts])
    pw = (blend[:, :3, :3] @ pos[..., None])[..., 0] + blend[:, :3, 3]
    nw = (blend[:, :3, :3] @ nrm[..., None])[..., 0]
    nw /= np.linalg.norm(nw, axis=1, keepdims=True).clip(1e-12)
    return pw, nw, tri.reshape(-1, 3), np.maximum(mapped, 0), wts
