"""Marker layout files: reading and validating the YAML that says which marker rides which limb.

A layout holds topology and labels only, no geometry: positions come from the capture (metres,
world Z-up X-forward). :class:`mocapgraph.kinematics.skeleton.SkeletonDefinition` is built from it.

File format (``graph_configs/marker_layouts/*.yaml``)::

    name: kiip_full_body            # required, identifier
    description: free text          # optional
    units: labels only, no geometry # optional note; a layout never holds positions
    limbs:                          # required, a list; the order is kept where it is a valid tree
      - name: lower_torso           # the root limb: the one limb without `parent`
        markers: [LT_FL, LT_FR, LT_BL, LT_BR]
      - name: upper_leg_l
        parent: lower_torso         # limb this one hangs from (the tree's proximal side)
        joint: {name: hip_l, type: ball}   # joint between parent and this limb; type ball|hinge
        markers: [LTHI_A, LTHI_B, LTHI_C, LKNE]
      - name: lower_leg_l
        parent: upper_leg_l
        joint: {name: knee_l, type: hinge}
        markers: [LTIB_A, LTIB_B]
        shared: [LKNE]              # optional: markers OWNED by an adjacent limb also used here
        joint_points: [knee_l]      # optional: joint centres usable as extra rigid-fit points
      - name: foot_l
        parent: lower_leg_l
        joint:
          name: ankle_l
          type: hinge
          landmarks: [LANK, LMED]   # optional: anatomical centre = midpoint of these two markers
          regression: {method: pig_ankle, side: left, markers: {wand: LTIB, lateral: LANK}}

Rules (each broken rule is a one-line :class:`LayoutError` naming file, line and key):

- exactly one root limb; every other limb has one ``parent`` that exists; no cycles; limb, joint
  and marker names unique (markers case-insensitively);
- every marker is *owned* by exactly one limb (``SkeletonDefinition.marker_limb``);
- ``shared`` lists markers owned by a limb adjacent through one joint (parent or child). Sharing
  is how layouts with 2 markers on a segment (Plug-in Gait thigh/shank) still get a rigid fit: the
  shared marker joins this limb's fit set (``limb_marker_index``) while keeping one owner. It is
  exactly rigid with both limbs only when it lies on the axis of a hinge joint between them
  (a lateral knee-epicondyle marker on the knee flexion axis); elsewhere the fit is approximate;
- ``joint_points`` names joints touching this limb whose centre, once estimated from the other
  limb, may stand in as an extra fit point (Plug-in Gait thigh: THI, KNE and the hip centre);
- a limb needs ``markers + shared + joint_points >= 3`` fit points, and at least one marker of
  its own or shared;
- ``joint.landmarks`` names two markers (epicondyles, malleoli, styloids) owned by one of the
  joint's two limbs; their midpoint in a static trial is the joint's anatomical centre. Markers
  seen only in the static (medial ones) need not be in later trials;
- ``joint.regression`` names a regression (``method`` one of ``REGRESSIONS``), the ``side``
  (left/right) and the ``markers`` it reads by role (see :mod:`mocapgraph.kinematics.solving.regression`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, NoReturn

import yaml

LAYOUT_DIR = Path(__file__).resolve().parents[2] / "graph_configs" / "marker_layouts"
JOINT_TYPES = ("ball", "hinge")
# Regression centres and the marker roles each reads (kinematics/solving/regression.py computes them).
REGRESSIONS = {
    "pig_hip": ("lasi", "rasi", "lpsi", "rpsi"),        # Davis 1991, as Plug-in Gait
    "harrington_hip": ("lasi", "rasi", "lpsi", "rpsi"),  # Harrington 2007 (pelvis width and depth)
    "pig_knee": ("wand", "lateral"),                     # PiG chord: thigh marker, lateral epicondyle
    "pig_ankle": ("wand", "lateral"),                    # PiG chord: tibia marker, lateral malleolus
}
MIN_FIT_POINTS = 3

LineOf = Callable[[tuple], "int | None"]
Fail = Callable[[tuple, str], NoReturn]   # raises LayoutError naming the key at path


class LayoutError(ValueError):
    """A marker layout is malformed; the message is one line naming source, line and key."""


def layout_path(name_or_path: str | Path) -> Path:
    """Resolve a layout name (``kiip_full_body``) or a path to an existing YAML file."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p
    return LAYOUT_DIR / f"{name_or_path}.yaml"


def available_layouts() -> list[str]:
    """Names of the layouts shipped in graph_configs/marker_layouts."""
    return sorted(p.stem for p in LAYOUT_DIR.glob("*.yaml"))


def _node_line_finder(root: yaml.Node | None) -> LineOf:
    """Map a key path (``("limbs", 3, "parent")``) to its 1-based line in the YAML source."""

    def line_of(path: tuple) -> int | None:
        node, best = root, None
        for key in path:
            if node is None:
                break
            best = node.start_mark.line + 1
            nxt = None
            if isinstance(node, yaml.MappingNode):
                for k, v in node.value:
                    if getattr(k, "value", None) == key:
                        best, nxt = k.start_mark.line + 1, v
                        break
            elif isinstance(node, yaml.SequenceNode) and isinstance(key, int):
                if 0 <= key < len(node.value):
                    nxt = node.value[key]
                    best = nxt.start_mark.line + 1
            node = nxt
        if node is not None:
            best = node.start_mark.line + 1
        return best

    return line_of


def read_layout_yaml(path: str | Path) -> tuple[dict, LineOf]:
    """Load a layout file; returns the mapping and a key-path -> line lookup."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise LayoutError(f"{p}: cannot read layout file ({exc.strerror or exc})") from None
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise LayoutError(f"{p}{where}: YAML syntax error: {problem}") from None
    if not isinstance(data, dict):
        raise LayoutError(f"{p}: a layout must be a YAML mapping with `name` and `limbs`")
    return data, _node_line_finder(node)


@dataclass(frozen=True)
class Regression:
    """A joint's regression centre: method name, side (left/right), marker role -> label."""

    method: str
    side: str
    markers: dict


@dataclass(frozen=True)
class ParsedLimb:
    name: str
    parent: str | None
    joint_name: str | None
    joint_type: str | None
    markers: tuple[str, ...]
    shared: tuple[str, ...]
    joint_points: tuple[str, ...]
    landmarks: tuple[str, ...] = ()
    regression: Regression | None = None


@dataclass(frozen=True)
class ParsedLayout:
    """A validated layout with limbs in tree order (parents before children)."""

    name: str
    description: str
    limbs: tuple[ParsedLimb, ...]


def parse_layout(data: Any, source: str = "<dict>", line_of: LineOf | None = None) -> ParsedLayout:
    """Validate a layout mapping and return limbs in tree order; raises LayoutError."""
    fail = _failer(source, line_of)
    if not isinstance(data, dict):
        fail((), "a layout must be a mapping with `name` and `limbs`")
    unknown = set(data) - {"name", "description", "units", "limbs", "notes", "source"}
    if unknown:
        fail((sorted(unknown)[0],), f"unknown top-level key (allowed: name, description, units, limbs)")
    name = data.get("name")
    if not isinstance(name, str) or not name.strip():
        fail(("name",), "missing or not a string")
    desc = data.get("description", "") or ""
    limbs_raw = data.get("limbs")
    if not isinstance(limbs_raw, list) or not limbs_raw:
        fail(("limbs",), "missing or not a non-empty list of limbs")
    parsed = [_parse_limb(i, item, fail) for i, item in enumerate(limbs_raw)]
    index, order = _tree_order(parsed, fail)
    _check_markers(parsed, index, fail)
    limbs = tuple(parsed[i] for i in order)
    return ParsedLayout(name.strip(), str(desc).strip(), limbs)


def _failer(source: str, line_of: LineOf | None) -> Fail:
    """``fail(path, msg)``: raise LayoutError naming the file, the line (when known) and the key."""

    def fail(path: tuple, msg: str) -> NoReturn:
        line = line_of(path) if line_of is not None else None
        where = f"{source}:{line}" if line else source
        key = ".".join(str(k) for k in path) if path else "<top>"
        raise LayoutError(f"{where}: key `{key}`: {msg}")

    return fail


def _str_list(i: int, key: str, item: dict, fail: Fail) -> tuple[str, ...]:
    """``limbs[i].key``, a list of non-empty strings (stripped); absent or null = empty."""
    val = item.get(key, [])
    if val is None:
        val = []
    if not isinstance(val, list) or not all(isinstance(v, str) and v.strip() for v in val):
        fail(("limbs", i, key), "must be a list of non-empty strings")
    return tuple(v.strip() for v in val)


def _parse_limb(i: int, item: Any, fail: Fail) -> ParsedLimb:
    """``limbs[i]``: its name, parent, joint, markers, shared markers and joint points."""
    if not isinstance(item, dict):
        fail(("limbs", i), "each limb must be a mapping with `name` and `markers`")
    extra = set(item) - {"name", "parent", "joint", "markers", "shared", "joint_points"}
    if extra:
        fail(("limbs", i, sorted(extra)[0]), "unknown limb key (allowed: name, parent, joint, markers, shared, joint_points)")
    lname = item.get("name")
    if not isinstance(lname, str) or not lname.strip():
        fail(("limbs", i, "name"), "limb name missing or not a string")
    parent = item.get("parent")
    jname = jtype = None
    landmarks, regression = (), None
    if parent is not None:
        if not isinstance(parent, str):
            fail(("limbs", i, "parent"), f"limb `{lname}`: parent must be a limb name")
        jname, jtype, landmarks, regression = _parse_joint(i, lname, item.get("joint"), fail)
    elif "joint" in item:
        fail(("limbs", i, "joint"), f"root limb `{lname}` has no parent, so it cannot declare a joint")
    return ParsedLimb(lname.strip(), parent.strip() if parent else None, jname, jtype,
                      _str_list(i, "markers", item, fail), _str_list(i, "shared", item, fail),
                      _str_list(i, "joint_points", item, fail), landmarks, regression)


def _parse_joint(i: int, lname: str, joint: Any, fail: Fail) -> tuple[str, str, tuple[str, ...], Regression | None]:
    """``limbs[i].joint`` of a limb with a parent: (name, type, landmarks, regression)."""
    if not isinstance(joint, dict) or not isinstance(joint.get("name"), str):
        fail(("limbs", i, "joint"), f"limb `{lname}` has a parent so needs `joint: {{name: ..., type: ball|hinge}}`")
    jname = joint["name"].strip()
    jtype = joint.get("type", "ball")
    if jtype not in JOINT_TYPES:
        fail(("limbs", i, "joint", "type"), f"joint `{jname}`: type must be one of {JOINT_TYPES}, got {jtype!r}")
    jextra = set(joint) - {"name", "type", "landmarks", "regression"}
    if jextra:
        fail(("limbs", i, "joint", sorted(jextra)[0]),
             f"joint `{jname}`: unknown key (allowed: name, type, landmarks, regression)")
    lm = joint.get("landmarks", [])
    if not (isinstance(lm, list) and (len(lm) in (0, 2)) and all(isinstance(v, str) and v.strip() for v in lm)):
        fail(("limbs", i, "joint", "landmarks"), f"joint `{jname}`: landmarks must be a list of two marker labels")
    landmarks = tuple(v.strip() for v in lm)
    regression = None
    reg = joint.get("regression")
    if reg is not None:
        if not isinstance(reg, dict) or reg.get("method") not in REGRESSIONS:
            fail(("limbs", i, "joint", "regression"),
                 f"joint `{jname}`: regression needs `method:` one of {', '.join(REGRESSIONS)}")
        side = reg.get("side")
        if side not in ("left", "right"):
            fail(("limbs", i, "joint", "regression", "side"), f"joint `{jname}`: side must be left or right")
        roles = reg.get("markers")
        need = REGRESSIONS[reg["method"]]
        if not isinstance(roles, dict) or set(roles) != set(need) or not all(isinstance(v, str) for v in roles.values()):
            fail(("limbs", i, "joint", "regression", "markers"),
                 f"joint `{jname}`: regression {reg['method']} needs markers for {', '.join(need)}")
        regression = Regression(reg["method"], side, {k: v.strip() for k, v in roles.items()})
    return jname, jtype, landmarks, regression


def _tree_order(parsed: list[ParsedLimb], fail: Fail) -> tuple[dict[str, int], list[int]]:
    """(limb name -> file position, the tree order): one root, known parents, no cycle; a stable
    preorder from the root (file order among siblings)."""
    index = {}
    for i, lb in enumerate(parsed):
        if lb.name in index:
            fail(("limbs", i, "name"), f"duplicate limb name `{lb.name}`")
        index[lb.name] = i
    roots = [i for i, lb in enumerate(parsed) if lb.parent is None]
    if len(roots) != 1:
        where = ("limbs", roots[1], "name") if len(roots) > 1 else ("limbs",)
        fail(where, f"exactly one root limb (without `parent`) is required, found {len(roots)}"
                    + (f": {', '.join(parsed[r].name for r in roots)}" if roots else " (cycle?)"))
    for i, lb in enumerate(parsed):
        if lb.parent is not None and lb.parent not in index:
            fail(("limbs", i, "parent"), f"limb `{lb.name}`: unknown parent limb `{lb.parent}`")
        if lb.parent == lb.name:
            fail(("limbs", i, "parent"), f"limb `{lb.name}` is its own parent")

    # Tree order: stable preorder from the root (file order among siblings).
    children: dict[str, list[int]] = {lb.name: [] for lb in parsed}
    for i, lb in enumerate(parsed):
        if lb.parent is not None:
            children[lb.parent].append(i)
    order: list[int] = []
    stack = [roots[0]]
    while stack:
        i = stack.pop()
        order.append(i)
        stack.extend(reversed(children[parsed[i].name]))
    if len(order) != len(parsed):
        lost = min(set(range(len(parsed))) - set(order))
        fail(("limbs", lost, "parent"), f"limb `{parsed[lost].name}` is on a parent cycle, not reachable from root `{parsed[roots[0]].name}`")
    return index, order


def _check_markers(parsed: list[ParsedLimb], index: dict[str, int], fail: Fail) -> None:
    """Each marker owned by one limb; shared markers from a limb one joint away; joint points,
    landmarks and regression markers that exist; enough points for every limb's rigid fit."""
    owner: dict[str, int] = {}
    canon: dict[str, str] = {}
    joints: dict[str, int] = {}
    for i, lb in enumerate(parsed):
        if lb.joint_name is not None:
            if lb.joint_name in joints:
                fail(("limbs", i, "joint", "name"), f"duplicate joint name `{lb.joint_name}`")
            joints[lb.joint_name] = i
        for m in lb.markers:
            if m.lower() in canon:
                fail(("limbs", i, "markers"), f"marker `{m}` listed twice (also on limb `{parsed[owner[m.lower()]].name}`); use `shared` to reuse a marker")
            canon[m.lower()] = m
            owner[m.lower()] = i

    def adjacent(a: int, b: int) -> bool:
        return parsed[a].parent == parsed[b].name or parsed[b].parent == parsed[a].name

    for i, lb in enumerate(parsed):
        for m in lb.shared:
            o = owner.get(m.lower())
            if o is None:
                fail(("limbs", i, "shared"), f"limb `{lb.name}`: shared marker `{m}` is not owned by any limb")
            if o == i:
                fail(("limbs", i, "shared"), f"limb `{lb.name}`: marker `{m}` is already its own")
            if not adjacent(i, o):
                fail(("limbs", i, "shared"), f"limb `{lb.name}`: shared marker `{m}` belongs to `{parsed[o].name}`, which is not joined to it by one joint")
        for jn in lb.joint_points:
            j = joints.get(jn)
            if j is None or not (j == i or parsed[j].parent == lb.name):
                fail(("limbs", i, "joint_points"), f"limb `{lb.name}`: joint `{jn}` is not a joint of this limb")
        if len(set(m.lower() for m in lb.shared)) != len(lb.shared):
            fail(("limbs", i, "shared"), f"limb `{lb.name}`: a shared marker is listed twice")
        n_fit = len(lb.markers) + len(lb.shared) + len(set(lb.joint_points))
        if n_fit < MIN_FIT_POINTS or not (lb.markers or lb.shared):
            fail(("limbs", i, "markers"),
                 f"limb `{lb.name}` has {len(lb.markers)} marker(s) + {len(lb.shared)} shared + "
                 f"{len(lb.joint_points)} joint point(s); a rigid fit needs >= {MIN_FIT_POINTS} "
                 "(add markers, or `shared:` markers of an adjacent limb)")

    for i, lb in enumerate(parsed):
        if lb.landmarks:
            if lb.landmarks[0].lower() == lb.landmarks[1].lower():
                fail(("limbs", i, "joint", "landmarks"), f"joint `{lb.joint_name}`: the two landmarks are one marker")
            pi = index[lb.parent]
            for m in lb.landmarks:
                o = owner.get(m.lower())
                if o not in (i, pi):
                    fail(("limbs", i, "joint", "landmarks"),
                         f"joint `{lb.joint_name}`: landmark `{m}` is not a marker of `{lb.name}` or `{lb.parent}`")
        if lb.regression is not None:
            for role, m in lb.regression.markers.items():
                if m.lower() not in owner:
                    fail(("limbs", i, "joint", "regression", "markers"),
                         f"joint `{lb.joint_name}`: regression marker {role}: `{m}` is not a marker of this layout")
