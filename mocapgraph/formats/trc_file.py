"""TRC (OpenSim / Motion Analysis track row column) marker files.

Layout of a well-formed file (tab separated)::

    PathFileType  4  (X/Y/Z)  name.trc
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    60.00     60.00       300        49          mm     60.00         1                   300
    Frame#  Time  M1 <tab><tab>  M2 ...
                  X1  Y1  Z1  X2  Y2  Z2 ...
    <blank line>
    1  0.000  x y z  x y z ...

:func:`read_trc` tolerates what real files do: spaces instead of tabs in the header, names
row with one tab between names, fewer names than data columns (the rest are named
``Marker<k>``), trailing empty columns, a missing X1/Y1/Z1 row or blank line, DataRate
missing or 0 (CameraRate used), NumFrames/NumMarkers disagreeing with the data (the data
wins, with a note), blank or ``nan`` fields for missing values (-> NaN), duplicate names (later ones suffixed
``_2``... with a note, see :mod:`mocapgraph.formats.labels`).

OpenSim is Y-up with X forward; the reader converts to the world frame (Z up, X forward):
(x, y, z)_world = (x, -z, y)_file, and units (mm, cm, m) to metres, saying so in
``trial.conversions``. ``up_axis`` overrides the Y-up assumption for files exported Z-up.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from .axes import axis_name, default_forward, describe_rotation, parse_axis, to_world_rotation, up_option
from .errors import FormatError
from .labels import unique_labels
from .marker_trial import MarkerTrial

_UNITS = {"mm": 1e-3, "millimeters": 1e-3, "cm": 1e-2, "m": 1.0, "meters": 1.0, "in": 0.0254}
_XYZ = re.compile(r"^[XYZ]\d+$", re.IGNORECASE)


def _split(line: str) -> list[str]:
    """Tab split when the line has tabs, whitespace split otherwise; right blanks trimmed."""
    line = line.rstrip("\r\n")
    return [t.strip() for t in line.split("\t")] if "\t" in line else line.split()


def _used_width(fields: list[str]) -> int:
    """Number of fields up to the last non-blank one."""
    n = len(fields)
    while n > 2 and not fields[n - 1]:
        n -= 1
    return n


def _float(tok: str) -> float:
    tok = tok.strip()
    if not tok:
        return math.nan
    return float(tok)  # "nan"/"NaN" parse; anything else raises ValueError


def _read_lines(path: Path) -> list[str]:
    """The file's lines; FormatError unless it starts like a TRC with the five header lines."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise FormatError(path, f"cannot read file ({e.strerror or e})") from None
    lines = text.splitlines()
    if not lines or not lines[0].strip().lower().startswith("pathfiletype"):
        raise FormatError(path, "not a TRC file (first line does not start with PathFileType)")
    if len(lines) < 5:
        raise FormatError(path, f"TRC header is broken (file ends after line {len(lines)})")
    return lines


class _Header:
    """The key row (line 2) and value row (line 3) of a TRC header, keys matched case-blind."""

    def __init__(self, path: Path, lines: list[str]) -> None:
        self.path = path
        raw_keys = [k.strip() for k in _split(lines[1]) if k.strip()]
        keys = [k.lower() for k in raw_keys]
        self.spelled = dict(zip(keys, raw_keys))  # for messages: the key as the file writes it
        vals = [v for v in _split(lines[2]) if v.strip()]
        if not keys or "datarate" not in keys and "camerarate" not in keys:
            raise FormatError(path, "TRC header is broken (line 2 has neither DataRate nor CameraRate)")
        if len(vals) < len(keys):
            raise FormatError(path, f"TRC header is broken (line 3 has {len(vals)} values for "
                                    f"{len(keys)} keys on line 2)")
        self.values = dict(zip(keys, vals))

    def text(self, key: str) -> str:
        """The value of ``key`` as written ("" when absent)."""
        return self.values.get(key, "")

    def num(self, key: str) -> float | None:
        """The value of ``key`` as a number, None when absent; FormatError when not a number."""
        if key not in self.values:
            return None
        try:
            return float(self.values[key])
        except ValueError:
            raise FormatError(self.path, f"TRC header is broken ({self.spelled[key]} = {self.values[key]!r} "
                                         f"is not a number)") from None


def _frame_rate(path: Path, header: _Header, notes: list[str]) -> float:
    """Frames per second: DataRate, else CameraRate when DataRate is missing or 0."""
    rate = header.num("datarate")
    cam = header.num("camerarate")
    if not rate or rate <= 0:
        if not cam or cam <= 0:
            raise FormatError(path, "TRC header is broken (no positive DataRate or CameraRate)")
        notes.append(f"DataRate missing or 0; used CameraRate {cam:g} Hz")
        rate = cam
    elif cam and abs(cam - rate) > 1e-6:
        notes.append(f"DataRate {rate:g} Hz used (CameraRate {cam:g} Hz differs)")
    return rate


def _length_unit(path: Path, header: _Header, notes: list[str]) -> str:
    """The header's Units, lower case (a key of _UNITS); mm when the header names none."""
    unit = header.text("units").strip().lower()
    if not unit:
        unit = "mm"
        notes.append("no Units in the header; assumed mm")
    if unit not in _UNITS:
        raise FormatError(path, f"TRC header is broken (Units {header.values.get('units')!r} is not a "
                                f"length unit)")
    return unit


def _names_rows(path: Path, lines: list[str], notes: list[str]) -> tuple[list[str], int, int]:
    """(marker names of line 4, index of the first line after the header, markers the
    X1 Y1 Z1 row counts (0 when the file has no such row))."""
    name_tokens = _split(lines[3])
    if len(name_tokens) < 2 or name_tokens[0].lower().rstrip("#") not in ("frame", "frame#"):
        raise FormatError(path, "TRC header is broken (line 4 should start with Frame# Time)")
    names = [t for t in name_tokens[2:] if t]
    xyz_tokens = [t for t in _split(lines[4]) if t]
    if xyz_tokens and all(_XYZ.match(t) for t in xyz_tokens):
        return names, 5, len(xyz_tokens) // 3
    notes.append("no X1 Y1 Z1 row")
    return names, 4, 0


def _data_rows(path: Path, lines: list[str], row: int) -> tuple[list[list[str]], list[int]]:
    """(fields of each non-blank line from ``row`` on, the 1-based file line of each)."""
    data_rows: list[list[str]] = []
    data_lines: list[int] = []
    for k in range(row, len(lines)):
        line = lines[k]
        if not line.strip():
            continue
        data_rows.append(_split(line))
        data_lines.append(k + 1)
    if not data_rows:
        raise FormatError(path, "TRC file holds no data rows")
    return data_rows, data_lines


def _marker_count(data_rows: list[list[str]], data_lines: list[int], n_names: int, n_xyz: int,
                  notes: list[str]) -> int:
    """Markers in the trial: the most of the names row, the X1 Y1 Z1 row and the usual row width.

    The width is the one most rows share: one over-long row (a stray tab, a row glued to the
    next) must not add phantom markers to the whole trial; such rows are noted.
    """
    used = np.array([_used_width(r) for r in data_rows])
    widths, counts = np.unique(used, return_counts=True)
    width = int(widths[counts == counts.max()].max())
    n_data = -(-(width - 2) // 3)  # ceil: a last marker with blank trailing fields still counts
    M = max(n_names, n_xyz, n_data)
    long_rows = np.flatnonzero(used > 2 + 3 * M)
    if long_rows.size:
        notes.append(f"{long_rows.size} data row(s) hold more fields than the {M} markers (first: line "
                     f"{data_lines[int(long_rows[0])]}, {int(used[long_rows[0]])} fields); the extra fields "
                     "were ignored")
    return M


def _marker_labels(names: list[str], M: int, header: _Header, notes: list[str]) -> list[str]:
    """``M`` unique labels: the names row's, ``Marker<k>`` for the markers it leaves unnamed."""
    declared = header.num("nummarkers")
    if declared is not None and int(declared) != M:
        notes.append(f"header NumMarkers {int(declared)} but the file has {M} markers")
    if len(names) < M:
        notes.append(f"names row names {len(names)} of {M} markers; others named Marker<k>")
        names = names + [f"Marker{k + 1}" for k in range(len(names), M)]
    names, dup_notes = unique_labels(names, "marker")
    notes += dup_notes
    return names


def _numbers(path: Path, data_rows: list[list[str]], M: int, row: int) -> np.ndarray:
    """[T, 2 + 3M] float64: frame number, time (s), then x y z per marker in file units; NaN
    for blank or missing fields, fields past the markers dropped."""
    arr = np.full((len(data_rows), 2 + 3 * M), np.nan)
    try:
        for t, r in enumerate(data_rows):
            vals_t = [_float(x) for x in r[: 2 + 3 * M]]
            arr[t, : len(vals_t)] = vals_t
    except ValueError as e:
        raise FormatError(path, f"data row {t + 1} (line {row + t + 1}) is not numeric ({e})") from None
    return arr


def _mask_missing(pts: np.ndarray, conversions: list[str]) -> np.ndarray:
    """Set missing samples of ``pts`` [T, M, 3] (zero-coded or with a NaN) to NaN; bool [T, M]
    of which they were."""
    zero = np.all(pts == 0.0, axis=2)
    if zero.any():
        conversions.append(f"{int(zero.sum())} zero-coded samples (0,0,0) -> NaN")
    miss = zero | np.isnan(pts).any(axis=2)
    pts[miss] = np.nan
    return miss


def _to_world(pts: np.ndarray, unit: str, up_axis: str | None,
              conversions: list[str]) -> tuple[np.ndarray, str, np.ndarray]:
    """(positions [T, M, 3] metres in the world frame, the file's up axis, R with world = R @ file)."""
    scale = _UNITS[unit]
    if scale != 1.0:
        conversions.append(f"units {unit} -> m")
    up = up_option(up_axis) or "+Y"
    R = to_world_rotation(up, default_forward(up))
    if not np.allclose(R, np.eye(3)):
        conversions.append(f"{up}-up -> Z-up ({describe_rotation(R)})")
    return np.einsum("ij,tmj->tmi", R * scale, pts), up, R


def _note_uneven_times(times: np.ndarray, rate: float, notes: list[str]) -> None:
    """Note when the Time column (s) strays from 1/``rate`` steps by over half a frame."""
    if len(times) > 2 and np.all(np.isfinite(times)):
        dt = np.diff(times)
        if np.max(np.abs(dt - 1.0 / rate)) > 0.5 / rate:
            notes.append("Time column is not evenly spaced at the header rate")


def read_trc(path: str | Path, *, up_axis: str | None = "+Y") -> MarkerTrial:
    """Read a TRC file into a :class:`MarkerTrial` (metres, Z-up world).

    up_axis: the file's up axis; "+Y" for OpenSim files (default; None, "" or "auto" mean the
    same: a TRC header does not say).
    Raises FormatError (one line naming the file) for a broken header or data.
    """
    path = Path(path)
    lines = _read_lines(path)
    notes: list[str] = []
    header = _Header(path, lines)
    rate = _frame_rate(path, header, notes)
    unit = _length_unit(path, header, notes)
    names, row, n_xyz = _names_rows(path, lines, notes)
    data_rows, data_lines = _data_rows(path, lines, row)
    M = _marker_count(data_rows, data_lines, len(names), n_xyz, notes)
    names = _marker_labels(names, M, header, notes)
    arr = _numbers(path, data_rows, M, row)
    T = len(data_rows)
    declared_frames = header.num("numframes")
    if declared_frames is not None and int(declared_frames) != T:
        notes.append(f"header NumFrames {int(declared_frames)} but {T} data rows")

    first_frame = int(arr[0, 0]) if not math.isnan(arr[0, 0]) else 1
    times = arr[:, 1]
    pts = arr[:, 2:].reshape(T, M, 3)
    conversions: list[str] = []
    miss = _mask_missing(pts, conversions)
    world, up, R = _to_world(pts, unit, up_axis, conversions)
    _note_uneven_times(times, rate, notes)
    return MarkerTrial(
        labels=names, positions=world,
        residuals=np.where(miss, np.nan, 0.0),
        rate_hz=rate, first_frame=first_frame, source=str(path),
        conversions=conversions, notes=notes,
        extra={"file_units": unit, "file_up": up, "file_to_world": R, "time_s": times},
    )


def write_trc(path: str | Path, trial: MarkerTrial, *, units: str = "mm",
              up_axis: str = "+Y", decimals: int = 6) -> None:
    """Write ``trial`` as an OpenSim TRC (Y up by default, ``units`` mm or m).

    Missing samples are written as blank fields; the Time column is ``trial.file_times_s`` (the
    source's own clock). ``read_trc`` of the result gives back the trial (to the written
    precision).
    """
    if units not in _UNITS:
        raise ValueError(f"units must be one of {sorted(_UNITS)}")
    path = Path(path)
    up = axis_name(parse_axis(up_axis))
    R = to_world_rotation(up, default_forward(up))
    file_pts = np.einsum("ji,tmj->tmi", R, trial.positions) / _UNITS[units]  # R^T: world->file
    T, M = trial.n_frames, trial.n_markers
    rate = trial.rate_hz
    out = ["PathFileType\t4\t(X/Y/Z)\t" + path.name,
           "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\t"
           "OrigDataStartFrame\tOrigNumFrames",
           f"{rate:.2f}\t{rate:.2f}\t{T}\t{M}\t{units}\t{rate:.2f}\t{trial.first_frame}\t{T}",
           "Frame#\tTime\t" + "\t\t\t".join(trial.labels) + "\t\t",
           "\t\t" + "\t".join(f"X{k + 1}\tY{k + 1}\tZ{k + 1}" for k in range(M)),
           ""]
    fmt = f"{{:.{decimals}f}}"
    times = trial.file_times_s.tolist()  # the trial's own clock: a late start stays late
    flat = file_pts.reshape(T, 3 * M)
    for t in range(T):
        cells = ["" if math.isnan(v) else fmt.format(v) for v in flat[t].tolist()]
        out.append(f"{trial.first_frame + t}\t{times[t]:.6f}\t" + "\t".join(cells))
    try:
        path.write_text("\n".join(out) + "\n", encoding="utf-8")
    except OSError as e:
        raise FormatError(path, f"cannot write file ({e.strerror or e})") from None
