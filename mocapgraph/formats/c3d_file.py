"""C3D marker files: :func:`read_c3d` -> :class:`MarkerTrial`, :func:`write_c3d`.

Reading goes through ezc3d; where ezc3d refuses a file that the pure-Python ``c3d`` package
can read (e.g. PhoeniX files with a non-integer ANALOG:OFFSET) that package is used instead
and its warnings are collected into ``trial.notes``.

Before either library sees the file, a small bounded walk over the 512-byte header and the
parameter section checks it is whole and consistent (ezc3d can spend tens of seconds on a file
cut inside its parameter section, and silently returns fewer frames for one cut inside its
data). Faults become a one-line :class:`FormatError`, e.g.
``mocap36.c3d: POINT:LABELS parameter is broken (...)``.

What the reader does to the data, every time saying so in ``trial.conversions``:

* POINT:UNITS (mm, cm, m, in) -> metres; a file already in metres is left alone.
* Up axis -> world Z up, X forward (right-handed): an explicit ``up_axis`` argument wins;
  otherwise POINT:Y_SCREEN names the up axis (X_SCREEN/Y_SCREEN is how C3D says how to show
  the data); otherwise Z up is assumed. If marker heights contradict the declared sign (most
  samples below the floor) the sign is flipped and a note says so (Qualisys QTM writes
  Y_SCREEN = -Z for Z-up data). Forward is the file's +X (its +Y when X is up).
* Points coded missing (negative residual, or exactly 0,0,0) -> NaN.
* Duplicate labels: the first keeps its name, later ones get ``_2``, ``_3``... with a note
  naming both point indices (:mod:`mocapgraph.formats.labels` says why).
* Frame count: the header's first/last frame, unless POINT:FRAMES disagrees and the data
  block holds POINT:FRAMES frames (ezc3d's rule; a note says which was used).
* A ROTATION group (segment poses, markerless systems) is not markers: a note names it and
  :mod:`mocapgraph.formats.c3d_segments` reads it; a file with no points at all is refused, saying
  whether it holds segment poses instead.
* Unlabelled points (``*NNN`` or empty labels) are left out unless ``include_unlabelled``.
  PhoeniX ``ChannelNNN`` names are kept as markers: those are active LEDs identified by the
  hardware, so the name is a stable identity, not an anonymous trajectory.
* Vicon model outputs stored as points (angles, forces, moments, powers, modelled markers,
  segment axes such as PELO/PELA/PELL/PELP) go to ``trial.model_outputs`` instead of being
  markers (``include_model_outputs=True`` keeps them as markers too).
"""
from __future__ import annotations

import re
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .axes import (axis_name, default_forward, describe_rotation, optional_axis, parse_axis,
                   to_world_rotation, up_option)
from .capped_call import CappedCallError, capped_call
from .errors import FormatError
from .labels import unique_labels
from .marker_trial import MarkerTrial

UNIT_TO_M = {"mm": 1e-3, "millimeter": 1e-3, "millimeters": 1e-3, "millimetre": 1e-3,
             "cm": 1e-2, "m": 1.0, "meter": 1.0, "meters": 1.0, "metre": 1.0,
             "in": 0.0254, "inch": 0.0254, "inches": 0.0254, "dm": 0.1}

# POINT parameters listing which points are model outputs rather than markers (Vicon, BTK).
_OUTPUT_GROUPS = {"ANGLES": "angle", "FORCES": "force", "MOMENTS": "moment", "POWERS": "power",
                  "SCALARS": "scalar", "REACTIONS": "reaction",
                  "MODELED_MARKERS": "position", "MODELLED_MARKERS": "position"}
_OUTPUT_UNIT_PARAM = {"angle": "ANGLE_UNITS", "force": "FORCE_UNITS", "moment": "MOMENT_UNITS",
                      "power": "POWER_UNITS", "scalar": "SCALAR_UNITS",
                      "reaction": "REACTION_UNITS"}
_UNLABELLED = re.compile(r"^\*\d+$")
_MAX_RATE_HZ = 1e6  # beyond any capture system (a flipped exponent bit gives 1e30 or 1e-38)
_MIN_RATE_HZ = 1e-3  # one frame per 1000 s: slower is no capture (and its ns stamps overflow soon)
_MAX_DIMS = 7  # the C3D spec's limit; ezc3d loops for minutes on a parameter claiming 127
_MAX_HEADER_FRAMES = 65535  # header frame numbers are uint16; longer files need parameters


# ---------------------------------------------------------------------------------------
# structural check (pure Python, bounded by the file size: it cannot hang)
# ---------------------------------------------------------------------------------------
@dataclass
class C3DLayout:
    """What the header and parameter walk found (file units, 1-based frames)."""

    n_points: int
    analog_per_frame: int
    first_frame: int
    last_frame: int
    float_data: bool
    data_start_byte: int
    frame_bytes: int
    frames_in_file: int
    parameters: list[str] = field(default_factory=list)  # "GROUP:NAME" in file order
    notes: list[str] = field(default_factory=list)
    #: "GROUP:NAME" -> value of every single-number integer/float parameter (int16 read unsigned,
    #: as C3D frame counts are)
    scalars: dict[str, float] = field(default_factory=dict)
    frames_source: str = "header"  # where n_frames came from: "header" or "POINT:FRAMES"

    @property
    def n_frames(self) -> int:
        """Point frames the file holds, as used by the reader."""
        return self.last_frame - self.first_frame + 1


def inspect_c3d(path: str | Path) -> C3DLayout:
    """Check a C3D file's header, parameter section and data size; FormatError on a fault.

    Runs in time linear in the number of parameters, never reads the data block, and bounds
    every count the file states (points, analog channels, segments, frames) by what its size
    can hold, so no reader is asked to allocate for data that is not there.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise FormatError(path, f"cannot read file ({e.strerror or e})") from None
    size = len(raw)
    if size < 512:
        raise FormatError(path, f"not a C3D file: {size} bytes, shorter than the 512-byte header")
    pblock, key = raw[0], raw[1]
    if key != 0x50 or pblock < 2:
        raise FormatError(path, "not a C3D file (header key byte is not 0x50)")
    poff = (pblock - 1) * 512
    if poff + 4 > size:
        raise FormatError(path, "file is truncated before its parameter section")
    proc = raw[poff + 3]
    if proc not in (84, 85, 86):
        raise FormatError(path, f"unknown processor type {proc} in the parameter section")
    end = ">" if proc == 86 else "<"
    n_points, n_analog, first, last = struct.unpack(end + "HHHH", raw[2:10])
    data_start_block = struct.unpack(end + "H", raw[16:18])[0]
    # sign bit of the header scale factor: negative scale = float32 data
    sign_byte = {84: raw[15], 85: raw[13], 86: raw[12]}[proc]
    float_data = bool(sign_byte & 0x80)
    params, scalars = _walk_parameters(path, raw, poff + 4, end, proc)

    if data_start_block < 1:
        raise FormatError(path, "header gives no data start block")
    data_start = (data_start_block - 1) * 512
    frame_bytes = (4 * n_points + n_analog) * (4 if float_data else 2)
    avail = max(size - data_start, 0)
    frames_in_file = avail // frame_bytes if frame_bytes else 0
    layout = C3DLayout(n_points, n_analog, first, last, float_data, data_start, frame_bytes,
                       frames_in_file, params, scalars=scalars)
    _choose_frame_count(path, layout, avail)
    _check_counts(path, layout, avail)
    return layout


def _walk_parameters(path: Path, raw: bytes, i: int, end: str, proc: int) -> tuple[list[str], dict[str, float]]:
    """("GROUP:NAME" in file order, scalar values) of the parameter section starting at ``i``.

    Groups are named after the walk: the C3D spec lets a parameter come before its group's
    record (an Optotrak export does), so a name is only known once the whole section is read.
    """
    size = len(raw)
    groups: dict[int, str] = {}
    entries: list[tuple[int, str, float | None]] = []  # (group id, name, scalar value)

    def label(gid: int, name: str) -> str:
        return f"{groups.get(gid, f'GROUP{gid}')}:{name}"

    while True:
        if i + 2 > size:
            raise FormatError(path, "file is truncated inside its parameter section")
        nlen = struct.unpack("b", raw[i:i + 1])[0]
        gid = struct.unpack("b", raw[i + 1:i + 2])[0]
        if nlen == 0:
            break
        j = i + 2 + abs(nlen)
        if j + 2 > size:
            raise FormatError(path, "file is truncated inside its parameter section")
        name = raw[i + 2:j].decode("latin-1", "replace").strip().upper()
        off = struct.unpack(end + "h", raw[j:j + 2])[0]
        nxt = j + off
        if gid < 0:
            groups[-gid] = name
        else:
            if j + 4 > size:
                raise FormatError(path, f"file is truncated inside parameter {label(gid, name)}")
            ptype = struct.unpack("b", raw[j + 2:j + 3])[0]
            ndim = raw[j + 3]
            if ndim > _MAX_DIMS:
                raise FormatError(path, f"{label(gid, name)} parameter is broken ({ndim} dimensions; "
                                        f"C3D allows {_MAX_DIMS})")
            dims = list(raw[j + 4:j + 4 + ndim])
            n = 1
            for d in dims:
                n *= d
            content_end = j + 4 + ndim + abs(ptype) * n
            if content_end >= size:
                raise FormatError(path, f"file is truncated inside parameter {label(gid, name)}")
            value = None
            if n == 1 and ptype in (1, 2, 4):
                at = j + 4 + ndim
                fmt = {1: "B", 2: "H", 4: "f"}[ptype]
                value = float(struct.unpack(end + fmt, raw[at:at + abs(ptype)])[0])
                # DEC floats share IEEE's layout with an exponent bias larger by 2
                value = value / 4.0 if (ptype == 4 and proc == 85) else value
            content_end += 1 + raw[content_end]  # description
            if ptype not in (-1, 1, 2, 4):
                raise FormatError(path, f"{label(gid, name)} parameter is broken (unknown data type {ptype})")
            if off != 0 and content_end > nxt:
                shape = "x".join(map(str, dims)) or "scalar"
                raise FormatError(path, f"{label(gid, name)} parameter is broken (its {shape} values "
                                        f"overrun the next entry by {content_end - nxt} bytes)")
            entries.append((gid, name, value))
        if off == 0:
            break
        if off < 0 or nxt <= i:
            raise FormatError(path, f"parameter section is broken (entry {name!r} points backwards)")
        i = nxt
    params = [label(gid, name) for gid, name, _ in entries]
    scalars = {label(gid, name): v for gid, name, v in entries if v is not None}
    return params, scalars


def _check_counts(path: Path, layout: C3DLayout, avail: int) -> None:
    """Refuse counts in the parameters that the data block could not hold (a flipped byte in
    POINT:USED, ANALOG:USED or ROTATION:USED would otherwise size a reader's arrays)."""
    word = 4 if layout.float_data else 2
    frames = max(layout.n_frames, 1)
    sc = layout.scalars
    used = sc.get("POINT:USED")
    if used is not None and int(used) != layout.n_points:
        need = frames * 4 * int(used) * word
        if need > avail:
            raise FormatError(path, f"POINT:USED {int(used)} disagrees with the header's {layout.n_points} "
                                    f"points, and {frames} frames of {int(used)} points need {need} bytes "
                                    f"where the data block holds {avail}")
        layout.notes.append(f"POINT:USED {int(used)} disagrees with the header's {layout.n_points} points")
    channels = sc.get("ANALOG:USED")
    if channels is not None and frames * int(channels) * word > avail:
        raise FormatError(path, f"ANALOG:USED {int(channels)} channels over {frames} frames need more "
                                f"than the {avail} bytes of the data block")
    segments = sc.get("ROTATION:USED", 0.0)
    ratio = sc.get("ROTATION:RATIO", 1.0)
    ratio = int(ratio) if np.isfinite(ratio) and ratio >= 1 else 1
    need = int(segments) * 12 * 4 * frames * ratio  # at least a float 3x4 pose per segment and sample
    if segments > 0 and need > avail:
        raise FormatError(path, f"ROTATION:USED {int(segments)} segments over {frames} frames need {need} "
                                f"bytes where the data block holds {avail}")


def _choose_frame_count(path: Path, layout: C3DLayout, avail: int) -> None:
    """Set ``layout.last_frame`` from the header or POINT:FRAMES; FormatError for a cut data block."""
    first, last, frame_bytes = layout.first_frame, layout.last_frame, layout.frame_bytes
    frames_in_file = layout.frames_in_file
    header_n = last - first + 1
    param_n = layout.scalars.get("POINT:FRAMES")
    expected = header_n
    if param_n is not None and param_n >= 1 and int(param_n) == param_n and int(param_n) != header_n \
            and frame_bytes:
        # Header and POINT:FRAMES disagree. The parameter is what ezc3d (and most writers) use,
        # and the only place for counts over 65535; the header's uint16 last frame is the one
        # writers get wrong (an Optotrak export promising 1149 frames while holding 29). Use
        # the parameter when the data block holds that many frames, else report the cut.
        pn = int(param_n)
        if frames_in_file >= pn:
            layout.last_frame = first + pn - 1
            layout.frames_source = "POINT:FRAMES"
            if last < _MAX_HEADER_FRAMES:
                layout.notes.append(f"header frames {first}..{last} ({header_n}) disagree with "
                                    f"POINT:FRAMES {pn}; used POINT:FRAMES (the data block holds "
                                    f"{frames_in_file} frames)")
            return
        if frames_in_file < header_n:
            raise FormatError(path, f"file is truncated: data block holds {frames_in_file} frames, "
                                    f"POINT:FRAMES promises {pn} and the header {header_n}")
        layout.notes.append(f"POINT:FRAMES {pn} is more than the data block holds "
                            f"({frames_in_file}); used the header's {header_n}")
    if frame_bytes and last < _MAX_HEADER_FRAMES and expected > 0:
        # One frame short with the file ending exactly on a frame boundary is a writer's
        # off-by-one in the header (PhoeniX golfswing.c3d); anything else is a cut file.
        partial = avail % frame_bytes
        if frames_in_file < expected - 1 or (frames_in_file == expected - 1 and partial):
            raise FormatError(path, f"file is truncated: data block holds {frames_in_file} of the "
                                    f"{expected} frames the header promises")
        if frames_in_file == expected - 1:
            layout.notes.append(f"header promises {expected} frames but the data block holds "
                                f"{frames_in_file}; the last frame is missing")


# ---------------------------------------------------------------------------------------
# the two backends, returning the same raw structure (file units and axes)
# ---------------------------------------------------------------------------------------
@dataclass
class _Raw:
    labels: list[str]
    points: np.ndarray  # [T, M, 3] file units, NaN where missing
    residuals: np.ndarray  # [T, M] file units, NaN where missing
    rate: float
    first_frame: int  # 1-based
    strings: dict[str, list[str]]  # POINT string parameters (UNITS, X_SCREEN, ANGLES...)
    backend: str
    notes: list[str] = field(default_factory=list)


def _str_list(v) -> list[str]:
    if isinstance(v, str):
        return [v.strip()]
    return [str(s).strip() for s in v]


def _read_ezc3d(path: Path) -> _Raw:
    import ezc3d

    c = ezc3d.c3d(str(path))
    p = c["parameters"]["POINT"]
    labels: list[str] = []
    for key in ["LABELS"] + [f"LABELS{k}" for k in range(2, 100)]:
        if key not in p:
            break
        labels += _str_list(p[key]["value"])
    pts = np.asarray(c["data"]["points"], dtype=np.float64)  # [4, M, T]
    res = np.asarray(c["data"]["meta_points"]["residuals"], dtype=np.float64)[0]  # [M, T]
    strings = {k: _str_list(v["value"]) for k, v in p.items()
               if isinstance(v, dict) and v.get("type") == -1}
    hdr = c["header"]["points"]
    return _Raw(labels, pts[:3].transpose(2, 1, 0), res.T, float(hdr["frame_rate"]),
                int(hdr["first_frame"]) + 1, strings, "ezc3d")


def _read_c3dpkg(path: Path) -> _Raw:
    import c3d

    with open(path, "rb") as fh, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = c3d.Reader(fh)
        frames = [pts[:, :4].copy() for _, pts, _ in r.read_frames(copy=False)]
        group = r.get("POINT")
        strings: dict[str, list[str]] = {}
        for name in list(group.param_keys()):
            prm = group.get(name)
            if prm is not None and prm.bytes_per_element == -1:
                try:
                    strings[name.upper()] = _str_list(prm.string_array.reshape(-1))
                except Exception:  # noqa: BLE001 - a broken optional string is just skipped
                    pass
        labels = _str_list(r.point_labels)
        rate = float(r.point_rate)
        first = int(r.first_frame)
    notes = [f"c3d package: {' '.join(str(w.message).split())}" for w in caught
             if "unclosed file" not in str(w.message)]
    arr = np.stack(frames).astype(np.float64) if frames else np.zeros((0, len(labels), 4))
    pts = arr[..., :3]
    res = arr[..., 3]
    pts[res < 0] = np.nan
    res = np.where(res < 0, np.nan, res)
    return _Raw(labels, pts, res, rate, first, strings, "c3d", notes)


def library_budget(path: Path) -> tuple[int, float]:
    """(bytes, seconds) a C3D library may use to read ``path``: what its size allows.

    ezc3d needs up to 9x the file size to read the shared captures (C++ objects per sample,
    then float64 arrays); 24x plus 128 MB leaves room for any honest file and stops a flipped
    count long before gigabytes. It reads them in 0.1-0.3 s; 10 s + 2 s per MB leaves room for a
    loaded machine and ends the loops some damaged files send it into.
    """
    size = path.stat().st_size
    return 24 * size + (128 << 20), 10.0 + 2.0 * size / (1 << 20)


def _load(path: Path) -> tuple[_Raw, list[str]]:
    """Read through ezc3d, else the c3d package, each in a capped child (formats.capped_call)."""
    notes: list[str] = []
    budget, timeout = library_budget(path)
    try:
        return capped_call(_read_ezc3d, path, budget_bytes=budget, timeout_s=timeout, what="ezc3d"), notes
    except CappedCallError as e1:  # any refusal or crash sends us to the fallback
        first_error = str(e1) or "refused"
    try:
        raw = capped_call(_read_c3dpkg, path, budget_bytes=budget, timeout_s=timeout, what="the c3d package")
    except CappedCallError as e2:
        raise FormatError(path, f"unreadable C3D (ezc3d: {first_error}; c3d: {e2})") from None
    notes.append(f"read with the c3d package because ezc3d refused the file ({first_error})")
    return raw, notes


# ---------------------------------------------------------------------------------------
# from raw to MarkerTrial
# ---------------------------------------------------------------------------------------
def _segment_axis_points(labels: list[str]) -> set[str]:
    """Vicon "bone" outputs: a 3-letter stem with all of O, A, L, P present (PELO, PELA...)."""
    have = set(labels)
    out: set[str] = set()
    for lab in labels:
        if len(lab) == 4 and lab.endswith("O"):
            quad = {lab[:3] + s for s in "OALP"}
            if quad <= have:
                out |= quad
    return out


def _classify(raw: _Raw) -> dict[str, str]:
    """label -> kind for model outputs."""
    kinds: dict[str, str] = {}
    group_names = dict(_OUTPUT_GROUPS)
    tg = raw.strings.get("TYPE_GROUPS", [])
    for k in range(0, len(tg) - 1, 2):  # Vicon: pairs (parameter name, type)
        group_names.setdefault(tg[k].upper(), tg[k + 1].lower())
    for group, kind in group_names.items():
        for lab in raw.strings.get(group, []):
            if lab:
                kinds[lab] = "position" if kind in ("modeled_marker", "modelled_marker") else kind
    for lab in _segment_axis_points(raw.labels):
        kinds.setdefault(lab, "position")
    return kinds


def _resolve_up(raw: _Raw, pts_marker: np.ndarray, up_axis: str | None,
                notes: list[str]) -> tuple[str, str, str]:
    """(up, forward, why) in file axes.

    ``up_axis`` (None/""/"auto" = not given) wins; else POINT:Y_SCREEN; else +Z. An absent or
    empty Y_SCREEN is "not given", not an error; one that names no axis is noted and ignored.
    """
    requested = up_option(up_axis)
    if requested is not None:
        return requested, default_forward(requested), "as requested"
    ys = (raw.strings.get("Y_SCREEN") or [""])[0]
    declared = None
    try:
        declared = optional_axis(ys)
    except ValueError:
        notes.append(f"POINT:Y_SCREEN {ys!r} names no axis; ignored")
    if declared is not None:
        up, why, said = axis_name(declared), f"from POINT:Y_SCREEN={ys}", "POINT:Y_SCREEN says"
    else:
        up, why, said = "+Z", "assumed: no usable POINT:Y_SCREEN", "assumed"
        notes.append("no usable POINT:Y_SCREEN; Z up assumed (set up_axis / --up if the file is Y-up)")
    v = parse_axis(up)
    h = pts_marker.reshape(-1, 3) @ v
    h = h[~np.isnan(h)]
    if h.size >= 10 and np.mean(h < 0) > 0.9:
        flipped = axis_name(-v)
        notes.append(f"{said} {up} is up but {100 * np.mean(h < 0):.0f}% of marker "
                     f"samples lie below 0 along it; used {flipped} as up")
        up, why = flipped, f"{why}, sign corrected from the marker heights"
    return up, default_forward(up), why


def _drop_padding(raw: _Raw, layout: C3DLayout, notes: list[str]) -> None:
    """Cut ``raw`` to the frame count the layout chose (the c3d package goes by the header;
    what is past the chosen count is padding)."""
    if raw.points.shape[0] > layout.n_frames > 0:
        notes.append(f"{raw.backend} returned {raw.points.shape[0]} frames; kept the "
                     f"{layout.n_frames} of {layout.frames_source}")
        raw.points, raw.residuals = raw.points[:layout.n_frames], raw.residuals[:layout.n_frames]


def _point_labels(raw: _Raw, n_points: int, notes: list[str]) -> list[str]:
    """One unique label per point: POINT:LABELS, ``*k`` for point k where it names none."""
    labels = list(raw.labels[:n_points]) + [""] * max(0, n_points - len(raw.labels))
    if len(raw.labels) < n_points:
        notes.append(f"POINT:LABELS names {len(raw.labels)} of {n_points} points; the rest are unlabelled")
    labels = [lab if lab else f"*{k}" for k, lab in enumerate(labels)]
    labels, dup_notes = unique_labels(labels)
    notes += dup_notes
    return labels


def _check_points(path: Path, raw: _Raw, layout: C3DLayout, notes: list[str]) -> None:
    """FormatError unless the file holds point frames at a usable rate; notes segment poses."""
    T, M = raw.points.shape[:2]
    if T == 0:
        raise FormatError(path, "file holds no point frames")
    if not (_MIN_RATE_HZ <= raw.rate <= _MAX_RATE_HZ):  # NaN fails too
        raise FormatError(path, f"point rate {raw.rate:g} Hz (POINT:RATE / header) is not a usable rate "
                                f"({_MIN_RATE_HZ:g}..{_MAX_RATE_HZ:g} Hz)")
    n_seg = int(layout.scalars.get("ROTATION:USED", 0))
    if M == 0:
        if n_seg > 0:
            raise FormatError(path, f"holds no markers, only {n_seg} segment poses in its ROTATION group: "
                                    "read it as a skeleton (node c3d_segment_reader; bag convert writes "
                                    "skeleton_pose)")
        raise FormatError(path, "holds no 3-D points (POINT:USED is 0)")
    if n_seg > 0:
        notes.append(f"also holds {n_seg} segment poses in its ROTATION group (node c3d_segment_reader "
                     "reads them)")


def _mask_missing(raw: _Raw, conversions: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(points [T, M, 3], residuals [T, M]) in file units, NaN wherever a sample is missing:
    zero-coded (0,0,0), NaN, or a negative residual."""
    pts = raw.points.copy()
    res = raw.residuals.copy()
    zero = np.all(pts == 0.0, axis=2)
    if zero.any():
        conversions.append(f"{int(zero.sum())} zero-coded samples (0,0,0) -> NaN")
    missing = zero | np.isnan(pts).any(axis=2) | ~(res >= 0)
    pts[missing] = np.nan
    res[missing] = np.nan
    return pts, res


def _length_unit(path: Path, raw: _Raw, notes: list[str], conversions: list[str]) -> tuple[str, float]:
    """(POINT:UNITS name, metres per file unit); mm when the file names none."""
    unit = (raw.strings.get("UNITS") or ["mm"])[0].strip().lower() or "mm"
    if unit not in UNIT_TO_M:
        raise FormatError(path, f"POINT:UNITS {unit!r} is not a length unit")
    scale = UNIT_TO_M[unit]
    if not raw.strings.get("UNITS"):
        notes.append("no POINT:UNITS; assumed mm")
    if scale != 1.0:
        conversions.append(f"units {unit} -> m")
    return unit, scale


@dataclass
class _PointColumns:
    """Which point columns are what: unlabelled, model outputs, and those kept as markers."""

    unlabelled: list[int]
    outputs: list[int]
    markers: list[int]

    @classmethod
    def sort(cls, labels: list[str], kinds: dict[str, str], include_unlabelled: bool,
             include_model_outputs: bool) -> "_PointColumns":
        unlabelled = [k for k, lab in enumerate(labels) if _UNLABELLED.match(lab)]
        outputs = [k for k, lab in enumerate(labels) if lab in kinds]
        markers = [k for k in range(len(labels))
                   if (include_unlabelled or k not in unlabelled)
                   and (include_model_outputs or labels[k] not in kinds)]
        return cls(unlabelled, outputs, markers)

    def real_markers(self, n_points: int) -> list[int]:
        """Columns that are labelled markers whatever the options: the ones whose heights
        tell the up axis."""
        return [k for k in range(n_points) if k not in self.outputs and k not in self.unlabelled]


def _file_to_world(raw: _Raw, pts: np.ndarray, columns: _PointColumns, up_axis: str | None,
                   notes: list[str], conversions: list[str]) -> tuple[str, str, np.ndarray]:
    """(file up axis, file forward axis, R [3, 3]) with world = R @ file (Z up, X forward)."""
    up, fwd, why = _resolve_up(raw, pts[:, columns.real_markers(pts.shape[1])], up_axis, notes)
    R = to_world_rotation(up, fwd)
    if not np.allclose(R, np.eye(3)):
        conversions.append(f"{up}-up -> Z-up ({why}; {describe_rotation(R)})")
    return up, fwd, R


def _model_outputs(raw: _Raw, labels: list[str], kinds: dict[str, str], columns: list[int],
                   pts: np.ndarray, world: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """(label -> [T, 3] values, label -> "kind [unit, frame]") of the model-output points.

    Positions are in metres in the world like markers; the other kinds stay in file units and
    axes, except angles in degrees, which become radians.
    """
    values: dict[str, np.ndarray] = {}
    described: dict[str, str] = {}
    for k in columns:
        lab, kind = labels[k], kinds[labels[k]]
        if kind == "position":
            values[lab] = world[:, k].copy()
            described[lab] = "position [m, world]"
            continue
        unit_param = _OUTPUT_UNIT_PARAM.get(kind)
        u = (raw.strings.get(unit_param) or [""])[0] if unit_param else ""
        v = pts[:, k].copy()
        if kind == "angle" and u.lower().startswith("deg"):
            v = np.deg2rad(v)
            u = "rad"
        values[lab] = v
        described[lab] = f"{kind} [{u or 'file units'}, file axes]"
    return values, described


def read_c3d(path: str | Path, *, include_unlabelled: bool = False, up_axis: str | None = None,
             include_model_outputs: bool = False) -> MarkerTrial:
    """Read a C3D file's 3-D points into a :class:`MarkerTrial` (metres, Z-up world).

    include_unlabelled: keep ``*NNN`` / unnamed points as markers.
    up_axis: the file's up axis ("+Y", "Z", ...) overriding POINT:Y_SCREEN.
    include_model_outputs: also keep model outputs (angles, segment axes...) as markers.
    Raises FormatError (one line, names the file) for anything unreadable.
    """
    path = Path(path)
    layout = inspect_c3d(path)
    raw, notes = _load(path)
    notes = layout.notes + notes + raw.notes
    _drop_padding(raw, layout, notes)
    labels = _point_labels(raw, raw.points.shape[1], notes)
    _check_points(path, raw, layout, notes)

    conversions: list[str] = []
    pts, res = _mask_missing(raw, conversions)
    unit, scale = _length_unit(path, raw, notes, conversions)
    kinds = _classify(raw)
    columns = _PointColumns.sort(labels, kinds, include_unlabelled, include_model_outputs)
    up, fwd, R = _file_to_world(raw, pts, columns, up_axis, notes, conversions)
    world = np.einsum("ij,tmj->tmi", R * scale, pts)
    model_outputs, model_kinds = _model_outputs(raw, labels, kinds, columns.outputs, pts, world)
    if columns.outputs:
        conversions.append(f"{len(columns.outputs)} model-output points put aside in model_outputs"
                           + (" (also kept as markers)" if include_model_outputs else ""))
    if columns.unlabelled and not include_unlabelled:
        conversions.append(f"{len(columns.unlabelled)} unlabelled points left out")

    keep = columns.markers
    return MarkerTrial(
        labels=[labels[k] for k in keep],
        positions=world[:, keep],
        residuals=res[:, keep] * scale,
        rate_hz=raw.rate,
        first_frame=raw.first_frame,
        source=str(path),
        conversions=conversions,
        notes=notes,
        model_outputs=model_outputs,
        model_output_kinds=model_kinds,
        extra={"backend": raw.backend, "file_units": unit, "file_up": up, "file_forward": fwd,
               "file_to_world": R, "n_unlabelled": len(columns.unlabelled)},
    )


def write_c3d(path: str | Path, trial: MarkerTrial, *, units: str = "mm") -> None:
    """Write ``trial``'s markers as a float C3D (Z up, POINT:UNITS ``units``).

    Missing samples are written the C3D way (residual -1, coordinates 0). Residual values
    and model outputs are not written.
    """
    import ezc3d

    if units not in ("mm", "m", "cm"):
        raise ValueError(f"units must be mm, cm or m, not {units!r}")
    path = Path(path)
    pos = trial.positions / UNIT_TO_M[units]
    miss = np.isnan(pos).any(axis=2)  # [T, M]
    pts = np.ones((4, trial.n_markers, trial.n_frames))
    pts[:3] = np.where(miss[..., None], 0.0, pos).transpose(2, 1, 0)
    res = np.where(miss, -1.0, 0.0).T[None]
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(trial.rate_hz)]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(trial.labels)
    c["data"]["points"] = pts
    if trial.first_frame >= 1:  # C3D header frame numbers are 1-based, ezc3d's 0-based
        c["header"]["points"]["first_frame"] = int(trial.first_frame) - 1
    c["data"]["meta_points"] = {"residuals": res,
                                "camera_masks": np.zeros((7, trial.n_markers, trial.n_frames),
                                                         dtype=bool)}
    c.add_parameter("POINT", "UNITS", units)
    c.add_parameter("POINT", "X_SCREEN", "+X")
    c.add_parameter("POINT", "Y_SCREEN", "+Z")
    try:
        c.write(str(path))
    except Exception as e:  # noqa: BLE001
        raise FormatError(path, f"cannot write C3D ({' '.join(str(e).split())})") from None
