"""Mapping files (graph_configs/mappings/*.yaml): read with file:line errors, written for people to edit.

::

    source: bvh                 # what drives it: bvh, kinect_v1, kinect_v2, optical:<layout>
    character: mixamo           # the character it was made for (a check, not a path)
    scale: auto                 # root translation ratio: auto (leg-length ratio) or a number
    legs:                       # for foot planting: hip, knee, ankle[, toe] per side
      l: [LeftUpLeg, LeftLeg, LeftFoot, LeftToeBase]
    joints:                     # character joint: how it is driven
      Hips: {rotation: Hips, position: Hips, A: [1, 0, 0, 0], R: [1, 0, 0, 0]}
      Spine: {mode: spread, position: lowerback}
      LeftShoulder: {mode: aim, position: LeftCollar}
      LeftForeArmRoll: {roll: {of: LeftHand, fraction: 0.5}}
      SpineShoulder: {rotation: SpineShoulder, D: [SpineMid, SpineBase]}

Quaternions are (w, x, y, z); Q_r = A·Q_k·D·R⁻¹·A⁻¹ (see retarget/mapping.py).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..retarget.mapping import MODES, JointMap, Mapping, MappingError
from .yaml_source import GraphError, LinedDict, LinedList, load_yaml_file

MAPPINGS_DIR = Path(__file__).resolve().parents[2] / "graph_configs" / "mappings"
_ENTRY_KEYS = ("mode", "rotation", "position", "A", "R", "D", "roll")


def resolve_mapping_path(name_or_path: str | Path) -> Path:
    p = Path(name_or_path)
    if p.suffix.lower() in (".yaml", ".yml") or p.exists():
        return p
    shipped = MAPPINGS_DIR / f"{name_or_path}.yaml"
    if shipped.exists():
        return shipped
    known = sorted(x.stem for x in MAPPINGS_DIR.glob("*.yaml"))
    raise MappingError(f"{name_or_path}: no such mapping file or shipped mapping (shipped: {', '.join(known)})")


def _err(file, line, key, msg) -> MappingError:
    return MappingError(str(GraphError(file, line, key, msg)))


def _quat(d: LinedDict, key: str, file: str, where: str) -> np.ndarray:
    v = d[key]
    try:
        q = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise _err(file, d.line_of(key), f"{where}.{key}", f"wants a quaternion [w, x, y, z], got {v!r}") from None
    if q.shape != (4,) or not np.isfinite(q).all():
        raise _err(file, d.line_of(key), f"{where}.{key}", f"wants a quaternion [w, x, y, z], got {v!r}")
    n = np.linalg.norm(q)
    if abs(n - 1.0) > 1e-3:
        raise _err(file, d.line_of(key), f"{where}.{key}", f"{list(v)} is not a unit quaternion (norm {n:.4g})")
    return q / n


def load_mapping(name_or_path: str | Path) -> Mapping:
    """Read a mapping file; any fault is one ``file:line: key: message`` MappingError."""
    path = resolve_mapping_path(name_or_path)
    file = str(path)
    try:
        doc = load_yaml_file(path)
    except GraphError as e:
        raise MappingError(str(e)) from None
    if not isinstance(doc, LinedDict) or "joints" not in doc:
        raise _err(file, None, "", "a mapping file is a YAML mapping with `source`, `character` and `joints`")
    for k in doc:
        if k not in ("source", "character", "scale", "legs", "joints", "doc"):
            raise _err(file, doc.line_of(k), str(k), "unknown key (known: source, character, scale, legs, joints)")
    scale = doc.get("scale", "auto")
    if scale == "auto" or scale is None:
        scale = None
    elif not isinstance(scale, (int, float)) or not scale > 0:
        raise _err(file, doc.line_of("scale"), "scale", f"wants `auto` or a positive number, got {scale!r}")
    legs = {}
    if "legs" in doc:
        lg = doc["legs"]
        if not isinstance(lg, LinedDict):
            raise _err(file, doc.line_of("legs"), "legs", "wants {l: [hip, knee, ankle, toe], r: [...]}")
        for side, names in lg.items():
            if side not in ("l", "r") or not isinstance(names, list) or len(names) not in (3, 4):
                raise _err(file, lg.line_of(side), f"legs.{side}", "wants side l or r with [hip, knee, ankle] or "
                           "[hip, knee, ankle, toe]")
            legs[side] = tuple(str(n) for n in names) + ((None,) if len(names) == 3 else ())
    joints = doc["joints"]
    if not isinstance(joints, LinedDict) or not joints:
        raise _err(file, doc.line_of("joints"), "joints", "wants a mapping {character joint: {rotation, position, ...}}")
    entries = []
    for name, spec in joints.items():
        where = f"joints.{name}"
        line = joints.line_of(name)
        if isinstance(spec, str):   # shorthand: `Hips: Hips` (rotation and position from that source joint)
            entries.append(JointMap(str(name), "rotate", spec, spec, line=line))
            continue
        if not isinstance(spec, LinedDict):
            raise _err(file, line, where, "wants a source joint name or {rotation, position, mode, A, R, D, roll}")
        for k in spec:
            if k not in _ENTRY_KEYS:
                raise _err(file, spec.line_of(k), f"{where}.{k}", f"unknown key (known: {', '.join(_ENTRY_KEYS)})")
        mode = str(spec.get("mode", "rotate"))
        if mode not in MODES:
            raise _err(file, spec.line_of("mode"), f"{where}.mode", f"unknown mode {mode!r} (known: {', '.join(MODES)})")
        kw = dict(mode=mode, rotation=spec.get("rotation"), position=spec.get("position"), line=line)
        for q in ("A", "R"):
            if q in spec:
                kw[q] = _quat(spec, q, file, where)
        if "D" in spec:
            d = spec["D"]
            if isinstance(d, list) and d and all(isinstance(x, str) for x in d):
                kw["D"] = tuple(d)
            else:
                kw["D"] = _quat(spec, "D", file, where)
        if "roll" in spec:
            r = spec["roll"]
            if not isinstance(r, LinedDict) or "of" not in r:
                raise _err(file, spec.line_of("roll"), f"{where}.roll", "wants {of: joint, fraction: 0..1}")
            f = r.get("fraction", 0.5)
            if not isinstance(f, (int, float)) or not 0.0 <= f <= 1.0:
                raise _err(file, r.line_of("fraction"), f"{where}.roll.fraction", f"{f!r} is not a number within 0..1")
            kw["roll_of"], kw["roll_fraction"] = str(r["of"]), float(f)
            if "rotation" not in spec:
                kw["mode"] = "rotate"
        entries.append(JointMap(str(name), **kw))
    return Mapping(str(doc.get("source", "")), str(doc.get("character", "")), tuple(entries), scale, legs,
                   file=file, line=doc.line)


def _fmt_q(q) -> str:
    return "[" + ", ".join(f"{x:.6f}".rstrip("0").rstrip(".") if abs(x) > 5e-7 else "0" for x in q) + "]"


def write_mapping(m: Mapping, path: str | Path, *, comment: str = "") -> None:
    """Write a mapping as an editable YAML file (quaternions wxyz to 6 decimals)."""
    lines = [f"# {line}" for line in (comment or "retargeting mapping").splitlines()]
    lines += ["# Q_r = A * Q_k * D * R^-1 * A^-1 (Claro Eq 4.1), quaternions (w, x, y, z).",
              "# modes: rotate (from `rotation`), spread (share of the chain, spine/neck), aim (point the bone",
              "# at the source bone, clavicles); `position` is the source point at the joint.",
              f"source: {m.source}", f"character: {m.character}",
              f"scale: {'auto' if m.scale is None else m.scale}"]
    if m.legs:
        lines.append("legs:")
        for side, names in m.legs.items():
            lines.append(f"  {side}: [{', '.join(_q(n) for n in names if n is not None)}]")
    lines.append("joints:")
    for e in m.joints:
        parts = []
        if e.mode != "rotate":
            parts.append(f"mode: {e.mode}")
        if e.rotation is not None:
            parts.append(f"rotation: {_q(e.rotation)}")
        if e.position is not None:
            parts.append(f"position: {_q(e.position)}")
        if not np.allclose(e.A, [1, 0, 0, 0], atol=5e-7):
            parts.append(f"A: {_fmt_q(e.A)}")
        if e.mode == "rotate" and e.rotation is not None:
            parts.append(f"R: {_fmt_q(e.R)}")
        if isinstance(e.D, np.ndarray):
            if not np.allclose(e.D, [1, 0, 0, 0]):
                parts.append(f"D: {_fmt_q(e.D)}")
        elif e.D:
            parts.append(f"D: [{', '.join(_q(x) for x in e.D)}]")
        if e.roll_of is not None:
            parts.append(f"roll: {{of: {_q(e.roll_of)}, fraction: {e.roll_fraction:g}}}")
        lines.append(f"  {_q(e.joint)}: {{{', '.join(parts)}}}")
    Path(path).write_text("\n".join(lines) + "\n")


def _q(name: str) -> str:
    return f'"{name}"' if any(c in name for c in ":{}[],#&*!|>'\"%@`") else name
