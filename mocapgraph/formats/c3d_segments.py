"""C3D ROTATION group (segment poses, as Theia3D and other markerless systems write them) ->
:class:`SkeletonTrial`: :func:`read_c3d_segments`, :func:`c3d_segment_count`.

The ROTATION group stores per frame one 4x4 homogeneous matrix per segment (ezc3d reads it as
``data["rotations"]`` [4, 4, S, T], NaN where a pose is invalid). Its labels name the segments;
ROTATION:RATE (or POINT:RATE x ROTATION:RATIO) is the rate. What the reader does, each step
listed in ``trial.conversions``:

* Translations: ROTATION:UNITS, else POINT:UNITS (mm when neither says) -> metres.
* Axes: the same rule as the marker reader (``up_axis`` wins, else POINT:Y_SCREEN, else Z up,
  sign checked against the segment heights) -> world Z up, X forward. With M the file->world
  axis map, a segment's world position is ``M t`` and its world orientation ``M R``: the
  segment keeps its own local axes (the columns of R), expressed in world coordinates.
* Invalid poses (NaN or a non-rotation matrix) -> position and orientation NaN, tracking state 0;
  valid ones state 2. The file gives no hierarchy: every segment is a root (parents -1).
* Time stamps: frame n of the file at (n - 1) / POINT:RATE, so a trial keeps its start time.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .axes import describe_rotation, to_world_rotation
from .c3d_file import (_MAX_RATE_HZ, _MIN_RATE_HZ, UNIT_TO_M, _Raw, _resolve_up, _str_list, inspect_c3d,
                       library_budget)
from .capped_call import CappedCallError, capped_call
from .errors import FormatError
from .labels import unique_labels
from .skeleton_trial import NOT_TRACKED, TRACKED, SkeletonTrial


def c3d_segment_count(path: str | Path) -> int:
    """Number of segments in a C3D's ROTATION group (0 when it has none); FormatError if broken."""
    return int(inspect_c3d(path).scalars.get("ROTATION:USED", 0))


def _read_rotations(path: Path) -> tuple[np.ndarray, dict, dict, float]:
    """(rotations [4, 4, S, T], ROTATION and POINT parameters, header rate) through ezc3d;
    run in a capped child (formats.capped_call), so it returns plain data only."""
    import ezc3d

    c = ezc3d.c3d(str(path))
    params = c["parameters"]
    return (np.asarray(c["data"]["rotations"], dtype=np.float64), dict(params.get("ROTATION", {})),
            dict(params.get("POINT", {})), float(c["header"]["points"]["frame_rate"]))


def read_c3d_segments(path: str | Path, *, up_axis: str | None = None) -> SkeletonTrial:
    """Segment poses of a C3D's ROTATION group as a world-frame SkeletonTrial (see module doc).

    up_axis: the file's up axis ("+Y", "z", "auto"/None = POINT:Y_SCREEN, else Z).
    Raises FormatError (one line naming the file) when the file has no ROTATION group or it
    cannot be read.
    """
    path = Path(path)
    layout = inspect_c3d(path)
    n_seg = int(layout.scalars.get("ROTATION:USED", 0))
    if n_seg <= 0:
        raise FormatError(path, "has no segment poses (no ROTATION group, or ROTATION:USED is 0)")
    budget, timeout = library_budget(path)
    try:
        rot, group, point, header_rate = capped_call(_read_rotations, path, budget_bytes=budget,
                                                     timeout_s=timeout, what="ezc3d")
    except CappedCallError as e:  # any library refusal or crash becomes one line
        raise FormatError(path, f"unreadable ROTATION group (ezc3d: {e})") from None
    labels: list[str] = []
    for key in ["LABELS"] + [f"LABELS{k}" for k in range(2, 100)]:
        if key not in group:
            break
        labels += _str_list(group[key]["value"])
    if rot.ndim != 4 or rot.shape[:2] != (4, 4) or rot.shape[2] == 0:
        raise FormatError(path, f"ROTATION data has shape {rot.shape}, not 4 x 4 x segments x frames")
    S, T = rot.shape[2], rot.shape[3]
    if T == 0:
        raise FormatError(path, "ROTATION group holds no frames")
    notes: list[str] = list(layout.notes)
    if len(labels) < S:
        notes.append(f"ROTATION:LABELS names {len(labels)} of {S} segments; the rest are named segment<k>")
    labels = [lab or f"segment{k}" for k, lab in enumerate(labels[:S] + [""] * max(0, S - len(labels)))]
    labels, dup = unique_labels(labels, "segment")
    notes += dup

    def strings(g: dict, key: str) -> list[str]:
        v = g.get(key)
        return _str_list(v["value"]) if isinstance(v, dict) and v.get("type") == -1 else []

    given = [(src, (strings(g, "UNITS") or [""])[0].strip().lower())
             for src, g in (("ROTATION:UNITS", group), ("POINT:UNITS", point))]
    unit_src, unit = next(((src, u) for src, u in given if u), ("assumed", "mm"))
    if unit_src == "assumed":
        notes.append("neither ROTATION:UNITS nor POINT:UNITS; assumed mm")
    if unit not in UNIT_TO_M:
        raise FormatError(path, f"{unit_src} {unit!r} is not a length unit")
    scale = UNIT_TO_M[unit]

    mats = rot.transpose(3, 2, 0, 1)  # [T, S, 4, 4]
    R = mats[..., :3, :3]
    t = mats[..., :3, 3]
    ok = np.isfinite(mats).all(axis=(2, 3))
    det = np.where(ok, np.linalg.det(np.where(ok[..., None, None], R, np.eye(3))), 0.0)
    ortho = np.abs(np.einsum("tsji,tsjk->tsik", R, R) - np.eye(3)).max(axis=(2, 3))
    good = ok & (np.abs(det - 1.0) < 1e-3) & (np.where(ok, ortho, np.inf) < 1e-3)
    n_bad = int((ok & ~good).sum())
    if n_bad:
        notes.append(f"{n_bad} segment poses are not rotations (scaled or mirrored matrices); "
                     "marked not tracked")

    raw = _Raw(labels, t, np.zeros((T, S)), 0.0, 1,
               {"Y_SCREEN": strings(point, "Y_SCREEN")}, "ezc3d")
    up, fwd, why = _resolve_up(raw, np.where(good[..., None], t, np.nan), up_axis, notes)
    M = to_world_rotation(up, fwd)
    conversions = []
    if scale != 1.0:
        conversions.append(f"units {unit} -> m ({unit_src})")
    if not np.allclose(M, np.eye(3)):
        conversions.append(f"{up}-up -> Z-up ({why}; {describe_rotation(M)})")
    conversions.append("segment orientation = file->world axes x file matrix (segment local axes kept)")

    pos = np.einsum("ij,tsj->tsi", M * scale, t)
    world_R = np.einsum("ij,tsjk->tsik", M, np.where(good[..., None, None], R, np.eye(3)))
    # every matrix here was checked orthonormal (or replaced by I): skip scipy's SVD projection,
    # which costs 5x the whole file read
    quat = Rotation.from_matrix(world_R.reshape(-1, 3, 3), assume_valid=True).as_quat(
        scalar_first=True).reshape(T, S, 4)
    pos[~good] = np.nan
    quat[~good] = np.nan
    if (~good).any():
        conversions.append(f"{int((~good).sum())} invalid segment poses -> NaN, not tracked")

    point_rate = float(layout.scalars.get("POINT:RATE", 0.0)) or header_rate
    ratio = float(layout.scalars.get("ROTATION:RATIO", 1.0)) or 1.0
    rate = float(layout.scalars.get("ROTATION:RATE", 0.0)) or point_rate * ratio
    if not (_MIN_RATE_HZ <= rate <= _MAX_RATE_HZ):  # NaN fails too
        raise FormatError(path, f"gives no usable rate ({rate:g} Hz from ROTATION:RATE / POINT:RATE; "
                                f"{_MIN_RATE_HZ:g}..{_MAX_RATE_HZ:g} Hz)")
    t0 = (layout.first_frame - 1) / point_rate if point_rate > 0 else 0.0
    ts = np.round((t0 + np.arange(T) / rate) * 1e9).astype(np.int64)
    notes.append("the ROTATION group gives no hierarchy: every segment is a root")
    return SkeletonTrial(names=labels, parents=np.full(S, -1), positions=pos,
                         tracking_state=np.where(good, TRACKED, NOT_TRACKED).astype(np.int8),
                         timestamps_ns=ts, rate_hz=rate, orientations=quat, source=str(path),
                         conversions=conversions, notes=notes,
                         extra={"file_units": unit, "file_up": up, "file_to_world": M,
                                "first_frame": layout.first_frame, "point_rate": point_rate})
