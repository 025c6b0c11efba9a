"""Stage files: the physical objects around the characters (boxes, balls, poles, walls, a mace).

A stage is a YAML file (``graph_configs/stages/``)::

    name: pole_and_boxes
    floor: {friction: 1.0}
    objects:                       # sizes in MuJoCo's convention: half-extents / radius, half-length
      - {name: pole, shape: cylinder, size: [0.04, 0.5], pos: [0.9, -0.3, 0.5], fixed: true}
      - {name: cube, shape: box, size: [0.08, 0.08, 0.08], pos: [0.9, -0.3, 1.08], mass: 0.3,
         friction: 0.6}
      - {name: mace, shape: mace, size: [0.02, 0.3, 0.08], mass: 5.0,
         held_by: {character: 0, joint: HandRight}}   # handle radius, half-length, head radius
    shooter: {from: [4.0, 0.0, 1.5], speed: 9.0, radius: 0.06, mass: 0.3, pool: 8}

Objects are fixed (part of the world, no mass needed) or free (a free joint, ``mass`` kg).
Positions are metres, world frame (Z up); ``quat`` wxyz. A held object is welded to the hand's body
(a virtual joint, Shum & Ho 6.1) and spawned there. The shooter's balls are a pool of free spheres
parked out of the way until shot.

Errors are one line, ``file:line: key: message``. The reader lives here rather than in
``formats/`` because only the physics world consumes it and the physics part may not import formats.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .body import WORLD_BIT, MAX_CHARACTERS, fmt

SHAPES = ("box", "sphere", "capsule", "cylinder", "mace")
SIZE_COUNT = {"box": 3, "sphere": 1, "capsule": 2, "cylinder": 2, "mace": 3}
PARK_X = 60.0  # parked balls wait on the floor this far away, m


class StageError(ValueError):
    """A stage file that cannot be used: ``file:line: key: message``."""


@dataclass(frozen=True)
class StageObject:
    name: str
    shape: str
    size: np.ndarray              # MuJoCo convention for the shape
    pos: np.ndarray               # m, world
    quat: np.ndarray              # wxyz
    mass: float                   # kg (free objects)
    friction: float
    fixed: bool
    held_by: tuple[int, str] | None = None   # (character number, hand joint name)
    rgba: tuple[float, float, float, float] = (0.8, 0.55, 0.3, 1.0)


@dataclass(frozen=True)
class Shooter:
    origin: np.ndarray            # m, world
    speed: float                  # m/s
    radius: float                 # m
    mass: float                   # kg
    pool: int


@dataclass(frozen=True)
class Stage:
    name: str
    objects: tuple[StageObject, ...] = ()
    floor_friction: float = 1.0
    shooter: Shooter | None = None
    source: str = ""

    @property
    def ball_names(self) -> tuple[str, ...]:
        return tuple(f"stage/ball{k}" for k in range(self.shooter.pool if self.shooter else 0))


EMPTY_STAGE = Stage("empty")


def shifted(stage: Stage, offset) -> Stage:
    """The same stage with every object (and the shooter) moved by ``offset`` (m, world)."""
    from dataclasses import replace
    d = np.asarray(offset, dtype=np.float64).reshape(3)
    objs = tuple(replace(o, pos=o.pos + d) for o in stage.objects)
    sh = replace(stage.shooter, origin=stage.shooter.origin + d) if stage.shooter else None
    return replace(stage, objects=objs, shooter=sh)


# ----- reading -----------------------------------------------------------------------------------
def _plain(node: yaml.Node) -> Any:
    """Python value of a composed node, mappings as (value dict, line dict)."""
    if isinstance(node, yaml.MappingNode):
        vals, lines = {}, {}
        for k, v in node.value:
            vals[k.value] = _plain(v)
            lines[k.value] = k.start_mark.line + 1
        return _Map(vals, lines, node.start_mark.line + 1)
    if isinstance(node, yaml.SequenceNode):
        return [_plain(v) for v in node.value]
    return yaml.safe_load(yaml.serialize(node)) if node.value != "" else None


@dataclass
class _Map:
    values: dict
    lines: dict
    line: int

    def get(self, key, default=None):
        return self.values.get(key, default)


STAGES_DIR = Path(__file__).resolve().parents[2] / "graph_configs" / "stages"


def resolve_stage_path(name_or_path: str | Path) -> Path:
    """A stage file as given, or a shipped stage by name (graph_configs/stages/NAME.yaml)."""
    p = Path(name_or_path)
    if p.exists() or p.suffix.lower() in (".yaml", ".yml"):
        return p
    shipped = STAGES_DIR / f"{name_or_path}.yaml"
    if shipped.exists():
        return shipped
    known = sorted(x.stem for x in STAGES_DIR.glob("*.yaml"))
    raise StageError(f"{name_or_path}: no such stage file or shipped stage (shipped: {', '.join(known)})")


def load_stage(path: str | Path) -> Stage:
    """Read a stage file or shipped stage (StageError naming file, line and key on any fault)."""
    path = resolve_stage_path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise StageError(f"{path}: cannot read stage file ({exc.strerror})") from None
    try:
        node = yaml.compose(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark else ""
        raise StageError(f"{path}{line}: not valid YAML ({getattr(exc, 'problem', exc)})") from None
    doc = _plain(node) if node is not None else None
    if not isinstance(doc, _Map):
        raise StageError(f"{path}: a stage file is a mapping with name, objects, floor, shooter")
    return stage_from_map(doc, str(path))


def _err(src: str, m: _Map, key: str, msg: str) -> StageError:
    return StageError(f"{src}:{m.lines.get(key, m.line)}: {key}: {msg}")


def _vec(src: str, m: _Map, key: str, n: int | tuple[int, ...], default=None, positive=False) -> np.ndarray:
    v = m.get(key, default)
    ns = (n,) if isinstance(n, int) else n
    try:
        a = np.atleast_1d(np.asarray(v, dtype=np.float64))
    except (TypeError, ValueError):
        raise _err(src, m, key, f"expected {' or '.join(map(str, ns))} numbers, got {v!r}") from None
    if a.ndim != 1 or a.shape[0] not in ns:
        raise _err(src, m, key, f"expected {' or '.join(map(str, ns))} numbers, got {v!r}")
    if not np.isfinite(a).all() or (positive and (a <= 0).any()):
        raise _err(src, m, key, f"{'positive ' if positive else ''}finite numbers needed, got {v!r}")
    return a


def _num(src: str, m: _Map, key: str, default: float, lo: float = 0.0, strict=False) -> float:
    v = m.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < lo or (strict and v <= lo):
        raise _err(src, m, key, f"expected a number {'>' if strict else '>='} {lo:g}, got {v!r}")
    return float(v)


def stage_from_map(doc: _Map, src: str) -> Stage:
    known = {"name", "objects", "floor", "shooter"}
    for k in doc.values:
        if k not in known:
            raise _err(src, doc, k, f"unknown key (known: {', '.join(sorted(known))})")
    floor = doc.get("floor") or _Map({}, {}, doc.line)
    if not isinstance(floor, _Map):
        raise _err(src, doc, "floor", "expected a mapping like {friction: 1.0}")
    objs = []
    names = set()
    raw = doc.get("objects") or []
    if not isinstance(raw, list):
        raise _err(src, doc, "objects", "expected a list of objects")
    for o in raw:
        if not isinstance(o, _Map):
            raise _err(src, doc, "objects", f"each object is a mapping, got {o!r}")
        allowed = {"name", "shape", "size", "pos", "quat", "mass", "friction", "fixed", "held_by", "rgba"}
        for k in o.values:
            if k not in allowed:
                raise _err(src, o, k, f"unknown object key (known: {', '.join(sorted(allowed))})")
        name = str(o.get("name", ""))
        if not name or "/" in name or name in names:
            raise _err(src, o, "name", f"each object needs a unique name without '/', got {name!r}")
        names.add(name)
        shape = o.get("shape")
        if shape not in SHAPES:
            raise _err(src, o, "shape", f"{shape!r} is not one of {', '.join(SHAPES)}")
        size = _vec(src, o, "size", SIZE_COUNT[shape], positive=True)
        fixed = bool(o.get("fixed", False))
        mass = _num(src, o, "mass", 1.0, 0.0, strict=not fixed)
        held = o.get("held_by")
        held_by = None
        if held is not None:
            if not isinstance(held, _Map) or "joint" not in held.values:
                raise _err(src, o, "held_by", "expected {character: N, joint: HandRight}")
            k = held.get("character", 0)
            if not isinstance(k, int) or not 0 <= k < MAX_CHARACTERS:
                raise _err(src, held, "character", f"a character number 0..{MAX_CHARACTERS - 1}, got {k!r}")
            if fixed:
                raise _err(src, o, "held_by", "a fixed object cannot be held")
            held_by = (k, str(held.get("joint")))
        q = _vec(src, o, "quat", 4, default=[1, 0, 0, 0])
        if np.linalg.norm(q) < 1e-9:
            raise _err(src, o, "quat", "a zero quaternion")
        rgba = tuple(_vec(src, o, "rgba", 4, default=[0.8, 0.55, 0.3, 1.0]))
        objs.append(StageObject(name, shape, size, _vec(src, o, "pos", 3, default=[0, 0, 0]), q / np.linalg.norm(q),
                                mass, _num(src, o, "friction", 0.8), fixed, held_by, rgba))
    shooter = None
    sh = doc.get("shooter")
    if sh is not None:
        if not isinstance(sh, _Map):
            raise _err(src, doc, "shooter", "expected a mapping {from, speed, radius, mass, pool}")
        pool = sh.get("pool", 8)
        if not isinstance(pool, int) or not 1 <= pool <= 64:
            raise _err(src, sh, "pool", f"1..64 balls, got {pool!r}")
        shooter = Shooter(_vec(src, sh, "from", 3, default=[4, 0, 1.5]), _num(src, sh, "speed", 8.0, 0, True),
                          _num(src, sh, "radius", 0.06, 0, True), _num(src, sh, "mass", 0.3, 0, True), pool)
    return Stage(str(doc.get("name", Path(src).stem)), tuple(objs), _num(src, floor, "friction", 1.0), shooter, src)


# ----- MJCF --------------------------------------------------------------------------------------
def add_stage(worldbody: ET.Element, stage: Stage) -> None:
    """Append the stage's objects and the shooter's parked balls to ``worldbody``."""
    every = (1 << (MAX_CHARACTERS + 1)) - 1
    for o in stage.objects:
        parent = worldbody
        if not o.fixed:
            parent = ET.SubElement(worldbody, "body", name=f"stage/{o.name}", pos=fmt(o.pos), quat=fmt(o.quat))
            ET.SubElement(parent, "freejoint", name=f"stage/{o.name}")
            where = {}
        else:
            where = {"pos": fmt(o.pos), "quat": fmt(o.quat)}
        common = dict(contype=str(WORLD_BIT), conaffinity=str(every), friction=fmt([o.friction, 0.005, 0.0001]),
                      rgba=fmt(o.rgba))
        if o.shape == "mace":
            r, h, head = o.size
            # the handle along the body's z, grip at the origin, the head at the far end
            body_m = o.mass
            ET.SubElement(parent, "geom", name=f"stage/{o.name}/handle", type="capsule", size=fmt([r, h]),
                          pos=fmt([0, 0, h]), mass=fmt(0.2 * body_m), **common, **{})
            ET.SubElement(parent, "geom", name=f"stage/{o.name}/head", type="sphere", size=fmt([head]),
                          pos=fmt([0, 0, 2 * h]), mass=fmt(0.8 * body_m), **common)
        else:
            extra = {} if o.fixed else {"mass": fmt(o.mass)}
            ET.SubElement(parent, "geom", name=f"stage/{o.name}", type=o.shape, size=fmt(o.size), **where,
                          **extra, **common)
    if stage.shooter is not None:
        s = stage.shooter
        for k, name in enumerate(stage.ball_names):
            b = ET.SubElement(worldbody, "body", name=name, pos=fmt([PARK_X + 0.5 * k, 0, s.radius]))
            ET.SubElement(b, "freejoint", name=name)
            ET.SubElement(b, "geom", name=name, type="sphere", size=fmt([s.radius]), mass=fmt(s.mass),
                          contype=str(WORLD_BIT), conaffinity=str(every), rgba="0.9 0.3 0.3 1",
                          solref="0.005 0.3")
