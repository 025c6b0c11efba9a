"""Subject measurements for regression joint centres (leg lengths, knee/ankle widths, pelvis).

Read from a Vicon VSK subject file, from a C3D's PROCESSING parameters (Vicon writes the
subject's measurements there), or from ``key=value`` pairs on the command line. Everything is
stored in metres; the sources give millimetres. A measurement left out (None) is derived from
the markers where Plug-in Gait does so (inter-ASIS distance, ASIS-trochanter distance).
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

# Plug-in Gait's default marker diameter is 14 mm.
DEFAULT_MARKER_RADIUS = 0.007


class SubjectError(ValueError):
    """Subject measurements cannot be read (message names the file or key)."""


@dataclass(frozen=True)
class Subject:
    """Anthropometric measurements in metres (None = unknown)."""

    leg_length_l: float | None = None
    leg_length_r: float | None = None
    inter_asis: float | None = None
    asis_trochanter_l: float | None = None
    asis_trochanter_r: float | None = None
    knee_width_l: float | None = None
    knee_width_r: float | None = None
    ankle_width_l: float | None = None
    ankle_width_r: float | None = None
    marker_radius: float = DEFAULT_MARKER_RADIUS
    source: str = ""

    def side(self, name: str, side: str) -> float | None:
        """A per-side measurement: ``side('knee_width', 'left')``."""
        return getattr(self, f"{name}_{side[0]}")

    @property
    def mean_leg_length(self) -> float | None:
        vals = [v for v in (self.leg_length_l, self.leg_length_r) if v]
        return sum(vals) / len(vals) if vals else None

    def merged(self, other: "Subject") -> "Subject":
        """This subject with every value ``other`` knows taken from ``other``."""
        upd = {f.name: getattr(other, f.name) for f in fields(self)
               if f.name not in ("source",) and getattr(other, f.name) is not None
               and not (f.name == "marker_radius" and other.marker_radius == DEFAULT_MARKER_RADIUS)}
        src = " + ".join(s for s in (self.source, other.source) if s)
        return replace(self, **upd, source=src)

    def as_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}

    @property
    def empty(self) -> bool:
        return all(getattr(self, f.name) is None for f in fields(self) if f.name not in ("marker_radius", "source"))


# Vicon names (VSK StaticParameter / C3D PROCESSING) -> our field.
_VICON = {
    "leftleglength": "leg_length_l", "rightleglength": "leg_length_r",
    "llegLength".lower(): "leg_length_l", "rleglength": "leg_length_r",
    "interasisdistance": "inter_asis", "interasisdist": "inter_asis",
    "leftasistrocanterdistance": "asis_trochanter_l", "rightasistrocanterdistance": "asis_trochanter_r",
    "lasistrocanterdistance": "asis_trochanter_l", "rasistrocanterdistance": "asis_trochanter_r",
    "leftkneewidth": "knee_width_l", "rightkneewidth": "knee_width_r",
    "lkneewidth": "knee_width_l", "rkneewidth": "knee_width_r",
    "leftanklewidth": "ankle_width_l", "rightanklewidth": "ankle_width_r",
    "lanklewidth": "ankle_width_l", "ranklewidth": "ankle_width_r",
    "markerdiameter": "marker_diameter",
}


def _from_mm(values: dict[str, float], source: str) -> Subject:
    kw: dict[str, Any] = {}
    for key, v in values.items():
        f = _VICON.get(key.lower().replace("_", ""))
        if f is None or v is None or v != v:
            continue
        if f == "marker_diameter":
            if v > 0:
                kw["marker_radius"] = float(v) / 2000.0
        elif v > 0:  # Vicon writes 0 for "derive it"
            kw[f] = float(v) / 1000.0
    return Subject(**kw, source=source)


def read_vsk(path: str | Path) -> Subject:
    """Measurements of a Vicon VSK file (its StaticParameter values, millimetres)."""
    p = Path(path)
    if p.exists() and not p.is_file():  # a device or fifo: the parser would read forever or block
        raise SubjectError(f"{p}: not a regular file")
    try:
        root = ET.parse(p).getroot()
    except FileNotFoundError:
        raise SubjectError(f"{p}: no such subject file") from None
    except (OSError, ET.ParseError) as exc:
        raise SubjectError(f"{p}: cannot read VSK subject file ({exc})") from None
    vals: dict[str, float] = {}
    for el in root.iter():
        if el.tag.endswith("Parameter") and el.get("NAME") and el.get("VALUE") not in (None, ""):
            try:
                vals.setdefault(el.get("NAME"), float(el.get("VALUE")))
            except ValueError:
                continue
    sub = _from_mm(vals, p.name)
    if sub.empty:
        raise SubjectError(f"{p}: no Plug-in Gait subject measurements (LeftLegLength, ...) in the VSK file")
    return sub


def _processing_values(path: str) -> dict[str, float]:
    """PROCESSING group scalars through ezc3d (run in a capped child: formats.capped_call)."""
    import ezc3d

    c = ezc3d.c3d(path, extract_forceplat_data=False)
    vals: dict[str, float] = {}
    for k, v in c["parameters"].get("PROCESSING", {}).items():
        if isinstance(v, dict) and "value" in v:
            try:
                vals[k] = float(list(v["value"])[0])
            except (TypeError, ValueError, IndexError):
                continue
    return vals


def read_c3d_processing(path: str | Path) -> Subject:
    """Measurements in a C3D's PROCESSING parameter group (Vicon Nexus writes them; millimetres).

    The file is checked first and ezc3d runs in a child capped by the file's size, as for markers.
    """
    from ..formats.c3d_file import inspect_c3d, library_budget
    from ..formats.capped_call import CappedCallError, capped_call
    from ..formats.errors import FormatError

    try:
        inspect_c3d(path)
        budget, timeout = library_budget(Path(path))
        vals = capped_call(_processing_values, str(path), budget_bytes=budget, timeout_s=timeout, what="ezc3d")
    except (FormatError, CappedCallError, OSError) as exc:
        raise SubjectError(f"{path}: cannot read C3D parameters ({exc})") from None
    return _from_mm(vals, f"{Path(path).name} PROCESSING")


def parse_subject_args(items: list[str]) -> Subject:
    """``--subject`` values: ``key=value`` in millimetres, keys as in Vicon (LeftLegLength) or ours
    (leg_length_l, knee_width_r, inter_asis, marker_diameter, ...)."""
    ours = {f.name for f in fields(Subject)} - {"source", "marker_radius"}
    vals: dict[str, float] = {}
    for item in items:
        for part in item.split(","):
            if not part.strip():
                continue
            key, sep, val = part.partition("=")
            key = key.strip()
            try:
                num = float(val)
            except ValueError:
                num = None
            if not sep or num is None:
                raise SubjectError(f"--subject {part!r}: expected key=value in mm (e.g. LeftLegLength=877)")
            if key in ours:
                vals[{"leg_length_l": "LeftLegLength", "leg_length_r": "RightLegLength",
                      "inter_asis": "InterAsisDistance", "asis_trochanter_l": "LeftAsisTrocanterDistance",
                      "asis_trochanter_r": "RightAsisTrocanterDistance", "knee_width_l": "LeftKneeWidth",
                      "knee_width_r": "RightKneeWidth", "ankle_width_l": "LeftAnkleWidth",
                      "ankle_width_r": "RightAnkleWidth"}[key]] = num
            elif key.lower().replace("_", "") in _VICON:
                vals[key] = num
            else:
                raise SubjectError(f"--subject {key}: unknown measurement (known: {', '.join(sorted(ours))}, "
                                   "marker_diameter, or Vicon names such as LeftKneeWidth)")
    return _from_mm(vals, "--subject")
