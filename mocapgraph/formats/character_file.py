"""Character files: a joint hierarchy from YAML or from the HIERARCHY of any BVH file, and back to YAML.

YAML form (``graph_configs/characters/*.yaml``)::

    name: my_rig
    units: m                  # m, cm, mm, in (offsets are scaled to metres on reading)
    axes: z_up                # z_up (ours: Z up, X forward, Y left) or y_up (BVH, Blender export)
    strip_prefix: "mixamorig:"   # optional: removed from every joint name
    joints:                   # parents before children
      - {name: Hips, offset: [0, 0, 0.95]}              # the root: no parent; offset = rest position
      - {name: Spine, parent: Hips, offset: [0, 0, 0.1], rest: [1, 0, 0, 0]}   # rest: wxyz, optional
      - {name: Head_End, parent: Head, offset: [0, 0, 0.2], end_site: true}

or a generated character: ``{name: standard_20, generator: standard_20, height_m: 1.75}``, or
``{name: cmu, bvh: path/to/file.bvh}`` (relative to the YAML file) to take a BVH's hierarchy.
A ``.glb``/``.gltf``/``.vrm`` file is read by :mod:`mocapgraph.formats.gltf_character` (its skin).

Every fault is one ``file:line: key: message`` error (:class:`CharacterFileError`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..retarget.character import MAX_OFFSET_M, Character, CharacterError, standard_20
from .yaml_source import GraphError, LinedDict, LinedList, load_yaml_file
from .bvh_file import BVH_TO_WORLD, BvhMotion, read_bvh
from .errors import FormatError

CHARACTERS_DIR = Path(__file__).resolve().parents[2] / "graph_configs" / "characters"
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
Y_UP_TO_WORLD = BVH_TO_WORLD  # (x, y, z) with Y up, facing +Z, left +X -> (z, x, y): X forward, Z up


class CharacterFileError(ValueError):
    """A character file that cannot be used: one line, ``file:line: key: message``."""


def _err(file, line, key: str, message: str) -> CharacterFileError:
    return CharacterFileError(str(GraphError(file, line, key, message)))


def resolve_character_path(name_or_path: str | Path) -> Path:
    """A path as given, or a shipped character by name (graph_configs/characters/NAME.yaml)."""
    p = Path(name_or_path)
    if p.suffix.lower() in (".yaml", ".yml", ".bvh", ".glb", ".gltf", ".vrm") or p.exists():
        return p
    shipped = CHARACTERS_DIR / f"{name_or_path}.yaml"
    if shipped.exists():
        return shipped
    known = sorted(x.stem for x in CHARACTERS_DIR.glob("*.yaml"))
    raise CharacterFileError(f"{name_or_path}: no such character file or shipped character "
                             f"(shipped: {', '.join(known)})")


def load_character(name_or_path: str | Path, *, height_m: float | None = None,
                   scale: float | None = None) -> Character:
    """A character from a YAML file, a BVH file's HIERARCHY, or a shipped name.

    ``height_m`` overrides a generated character's height; ``scale`` multiplies every offset.
    """
    path = resolve_character_path(name_or_path)
    if path.suffix.lower() == ".bvh":
        ch = character_from_bvh(_read_bvh(path, None))
    elif path.suffix.lower() in (".glb", ".gltf", ".vrm"):
        ch = _read_gltf(path).character
    else:
        ch = _character_from_yaml(path, height_m)
    return ch.scaled(scale) if scale not in (None, 1.0) else ch


def _read_gltf(path: Path):
    from .gltf_character import GltfCharacterError, load_gltf_character
    if not path.is_file():
        raise CharacterFileError(f"{path}: no such file")
    try:
        return load_gltf_character(path)
    except GltfCharacterError as e:
        raise CharacterFileError(str(e)) from None
    except OSError as e:
        raise CharacterFileError(f"{path}: cannot read ({e.strerror or e})") from None


def _read_bvh(path: Path, scale: float | None) -> BvhMotion:
    try:
        return read_bvh(path, scale=scale)
    except FormatError as e:
        raise CharacterFileError(str(e)) from None


def character_from_bvh(motion: BvhMotion, *, name: str | None = None, strip_prefix: str | None = None,
                       rest_root: np.ndarray | None = None) -> Character:
    """The hierarchy of a BVH file as a character: offsets in metres in the world frame (Z up),
    identity rest rotations (the BVH rest pose has every channel at 0), end sites kept.

    ``strip_prefix`` (e.g. ``mixamorig:``) is removed from joint names; when None a prefix shared
    by every joint and ending in ':' is removed. ``rest_root``: root rest position (default: the
    root OFFSET in the world frame).
    """
    names = list(motion.names)
    if strip_prefix is None:
        first = names[0].split(":")[0] + ":" if ":" in names[0] else ""
        strip_prefix = first if first and all(n.startswith(first) for n in names) else ""
    if strip_prefix:
        names = [n[len(strip_prefix):] if n.startswith(strip_prefix) else n for n in names]
    offsets = (motion.offsets * motion.scale) @ BVH_TO_WORLD.T
    root = int(np.flatnonzero(motion.parents < 0)[0])
    if rest_root is not None:
        offsets[root] = rest_root
    base = Path(motion.source).stem if motion.source else "bvh"
    rest = np.tile([1.0, 0.0, 0.0, 0.0], (len(names), 1))
    try:
        return Character(name or base, tuple(names), motion.parents, offsets, rest, motion.is_end_site,
                         allow_zero_bones=True)
    except CharacterError as e:
        raise CharacterFileError(f"{motion.source or 'bvh'}: {e}") from None


def _vec(node, key, value, n: int, file, label: str = "") -> np.ndarray:
    line = node.line_of(key) if isinstance(node, LinedDict) else None
    key = f"{label}.{key}" if label else key
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise _err(file, line, key, f"wants {n} finite numbers, got {value!r}") from None
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise _err(file, line, key, f"wants {n} finite numbers, got {value!r}")
    return arr


def _character_from_yaml(path: Path, height_m: float | None) -> Character:
    try:
        doc = load_yaml_file(path)
    except GraphError as e:
        raise CharacterFileError(str(e)) from None
    file = str(path)
    if not isinstance(doc, LinedDict):
        raise _err(file, None, "", "a character file is a YAML mapping with `name` and `joints`")
    allowed = {"name", "units", "axes", "joints", "generator", "height_m", "bvh", "strip_prefix", "doc", "scale",
               "allow_zero_bones"}
    for key in doc:
        if key not in allowed:
            raise _err(file, doc.line_of(key), str(key), f"unknown key (known: {', '.join(sorted(allowed))})")
    name = str(doc.get("name", path.stem))
    if "generator" in doc:
        if doc["generator"] != "standard_20":
            raise _err(file, doc.line_of("generator"), "generator", f"unknown generator {doc['generator']!r} "
                       "(known: standard_20)")
        h = height_m if height_m is not None else doc.get("height_m", 1.75)
        try:
            ch = standard_20(float(h), name=name)
        except (CharacterError, TypeError, ValueError) as e:
            raise _err(file, doc.line_of("height_m"), "height_m", str(e)) from None
    elif "bvh" in doc:
        bvh_path = (path.parent / str(doc["bvh"])).resolve()
        ch = character_from_bvh(_read_bvh(bvh_path, None), name=name, strip_prefix=doc.get("strip_prefix"))
    else:
        ch = _joints_from_yaml(doc, file, name)
    if "scale" in doc:
        s = doc["scale"]
        if not isinstance(s, (int, float)) or not s > 0:
            raise _err(file, doc.line_of("scale"), "scale", f"wants a positive number, got {s!r}")
        ch = ch.scaled(float(s))
    return ch


def _joints_from_yaml(doc: LinedDict, file: str, name: str) -> Character:
    units = doc.get("units", "m")
    if units not in UNITS:
        raise _err(file, doc.line_of("units"), "units", f"unknown unit {units!r} (known: {', '.join(UNITS)})")
    axes = doc.get("axes", "z_up")
    if axes not in ("z_up", "y_up"):
        raise _err(file, doc.line_of("axes"), "axes", f"{axes!r} is not z_up or y_up")
    to_world = np.eye(3) if axes == "z_up" else Y_UP_TO_WORLD
    joints = doc.get("joints")
    if not isinstance(joints, LinedList) or not joints:
        raise _err(file, doc.line_of("joints"), "joints", "wants a list of joints (name, parent, offset)")
    prefix = str(doc.get("strip_prefix") or "")
    names: list[str] = []
    parents: list[int] = []
    offsets, rests, ends = [], [], []
    lines: list[int] = []
    for i, j in enumerate(joints):
        line = joints.item_lines[i]
        if not isinstance(j, LinedDict) or "name" not in j:
            raise _err(file, line, f"joints[{i}]", "wants a mapping with at least `name` and `offset`")
        jn = str(j["name"])
        if prefix and jn.startswith(prefix):
            jn = jn[len(prefix):]
        key = f"joints[{i}] ({jn})"
        for k in j:
            if k not in ("name", "parent", "offset", "rest", "end_site"):
                raise _err(file, j.line_of(k), f"{key}.{k}", "unknown key (known: name, parent, offset, rest, end_site)")
        if jn in names:
            raise _err(file, j.line_of("name"), key, f"joint {jn!r} appears twice")
        par = j.get("parent")
        if par is None:
            parents.append(-1)
        else:
            pn = str(par)
            if prefix and pn.startswith(prefix):
                pn = pn[len(prefix):]
            if pn == jn:
                raise _err(file, j.line_of("parent"), f"{key}.parent", "a joint cannot be its own parent (a cycle)")
            if pn not in names:
                later = any(isinstance(o, LinedDict) and str(o.get("name", "")).removeprefix(prefix) == pn
                            for o in joints[i + 1:])
                why = ("is defined later: a cycle, or joints out of order (parents come first)" if later
                       else "is not a joint of this character")
                raise _err(file, j.line_of("parent"), f"{key}.parent", f"parent {pn!r} {why}")
            parents.append(names.index(pn))
        if "offset" not in j:
            raise _err(file, j.line, key, "missing `offset` (metres from the parent, or the root's rest position)")
        off = _vec(j, "offset", j["offset"], 3, file, key) * UNITS[units]
        if np.abs(off).max() > MAX_OFFSET_M:   # finite but absurd (1e300): named here, not by MuJoCo later
            raise _err(file, j.line_of("offset"), f"{key}.offset", f"{np.abs(off).max():.3g} m is beyond "
                       f"{MAX_OFFSET_M:g} m: not a body (wrong units?)")
        if parents[-1] >= 0 and np.linalg.norm(off) < 1e-6 and doc.get("allow_zero_bones") is not True:
            raise _err(file, j.line_of("offset"), f"{key}.offset", f"zero-length bone to {names[parents[-1]]!r} "
                       "(set `allow_zero_bones: true` if the rig stacks joints on purpose)")
        rest = _vec(j, "rest", j.get("rest", [1, 0, 0, 0]), 4, file, key)
        if abs(np.linalg.norm(rest) - 1.0) > 1e-3:
            raise _err(file, j.line_of("rest"), f"{key}.rest", f"not a unit quaternion (norm {np.linalg.norm(rest):.4g})")
        names.append(jn)
        offsets.append(to_world @ off)
        rests.append(rest / np.linalg.norm(rest))
        ends.append(bool(j.get("end_site", False)))
        lines.append(line)
    if parents.count(-1) != 1:
        roots = [n for n, p in zip(names, parents) if p < 0]
        raise _err(file, doc.line_of("joints"), "joints", f"a character needs exactly one root (a joint without "
                   f"parent), found {len(roots)}: {', '.join(roots)}")
    rest_m = np.array(rests)
    if axes == "y_up":  # rest orientations given in Y-up axes: conjugate into the world frame
        from ..kinematics.quaternion import matrix_to_quat, quat_to_matrix
        rest_m = matrix_to_quat(to_world @ quat_to_matrix(rest_m) @ to_world.T)
    try:
        return Character(name, tuple(names), np.array(parents), np.array(offsets), rest_m, np.array(ends),
                         allow_zero_bones=doc.get("allow_zero_bones") is True)
    except CharacterError as e:
        raise _err(file, doc.line_of("joints"), "joints", str(e)) from None


def write_character_yaml(ch: Character, path: str | Path, *, doc: str = "") -> None:
    """Write a character as an explicit YAML joint list (metres, Z up), readable by load_character."""
    lines = [f"# {doc}" if doc else "# character", f"name: {ch.name}", "units: m", "axes: z_up"]
    zero = (np.linalg.norm(ch.rest_offsets, axis=1) < 1e-6) & (ch.parents >= 0)
    if zero.any():
        lines.append("allow_zero_bones: true   # joints stacked at one place, as in the source BVH")
    lines.append("joints:")
    fmt = lambda v: "[" + ", ".join(f"{x:.9g}" for x in v) + "]"  # noqa: E731
    for j, n in enumerate(ch.joint_names):
        parts = [f"name: {_q(n)}"]
        if ch.parents[j] >= 0:
            parts.append(f"parent: {_q(ch.joint_names[ch.parents[j]])}")
        parts.append(f"offset: {fmt(ch.rest_offsets[j])}")
        if not np.allclose(ch.rest_rotations[j], [1, 0, 0, 0]):
            parts.append(f"rest: {fmt(ch.rest_rotations[j])}")
        if ch.end_sites[j]:
            parts.append("end_site: true")
        lines.append("  - {" + ", ".join(parts) + "}")
    Path(path).write_text("\n".join(lines) + "\n")


def _q(name: str) -> str:
    return f'"{name}"' if any(c in name for c in ":{}[],#&*!|>'\"%@`") or name.strip() != name else name
