"""Regression joint centres of the Plug-in Gait conventions, batched over frames (metres, world).

- Hip, Davis et al. 1991 as Plug-in Gait applies it: in the pelvis frame (origin mid-ASIS,
  x forward, y left, z up) the centre sits at
  ``X = (-d_at - r) cos(beta) + C cos(theta) sin(beta)``,
  ``Y = +-(C sin(theta) - ASIS/2)`` toward the side, ``Z = (-d_at - r) sin(beta) - C cos(theta) cos(beta)``,
  with ``C = 0.115 LL - 15.3 mm`` (LL the mean leg length), ``theta = 0.5``, ``beta = 0.314`` rad,
  ``d_at = 0.1288 LL - 48.56 mm`` unless measured, ``r`` the marker radius.
- Hip, Harrington et al. 2007 (pelvis width PW between the ASIS, depth PD between mid-ASIS and
  mid-PSIS, mm): ``X = -0.24 PD - 9.9``, ``Z = -0.30 PW - 10.9``, lateral ``0.33 PW + 7.3``.
- Knee and ankle, Plug-in Gait's chord construction: the centre J lies in the plane of the
  wand marker, the proximal joint centre P and the lateral marker L, at ``|J - L| = width/2 + r``
  with the angle P-J-L a right angle (so J is on the circle over the chord P-L), on the side
  of the chord away from the wand.
"""
from __future__ import annotations

import numpy as np

from mocapgraph.kinematics.subject import Subject

_THETA, _BETA = 0.5, 0.314


class RegressionError(ValueError):
    """A regression lacks a subject measurement (message names it)."""


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def pelvis_frame(lasi: np.ndarray, rasi: np.ndarray, lpsi: np.ndarray, rpsi: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Plug-in Gait pelvis frame per frame: origin [F,3] (mid-ASIS) and axes [F,3,3] (columns
    x forward, y left, z up)."""
    origin = 0.5 * (lasi + rasi)
    y = _unit(lasi - rasi)
    fwd = origin - 0.5 * (lpsi + rpsi)
    x = _unit(fwd - (fwd * y).sum(-1, keepdims=True) * y)
    z = np.cross(x, y)
    return origin, np.stack([x, y, z], axis=-1)


def _need(value: float | None, what: str) -> float:
    if value is None:
        raise RegressionError(f"subject measurement {what} is missing (give a VSK, C3D PROCESSING or --subject)")
    return float(value)


def hip_from_local(m: dict[str, np.ndarray], local: np.ndarray) -> np.ndarray:
    """Hip centres [...,3] at ``local`` (m, pelvis frame [...,3]) from pelvis markers ``m`` [...,3]."""
    origin, axes = pelvis_frame(m["lasi"], m["rasi"], m["lpsi"], m["rpsi"])
    return origin + (axes @ np.asarray(local)[..., None])[..., 0]


def hip_centre(method: str, side: str, m: dict[str, np.ndarray], subject: Subject) -> tuple[np.ndarray, dict]:
    """Hip centres [F,3] from pelvis markers ``m`` (lasi, rasi, lpsi, rpsi: [F,3]) and the inputs
    used (``local_m``: the centre in the pelvis frame)."""
    origin, axes = pelvis_frame(m["lasi"], m["rasi"], m["lpsi"], m["rpsi"])
    sgn = 1.0 if side == "left" else -1.0
    pw = float(np.nanmedian(np.linalg.norm(m["lasi"] - m["rasi"], axis=-1)))
    r = subject.marker_radius
    if method == "pig_hip":
        ll = _need(subject.mean_leg_length, "leg length")
        aa = (subject.inter_asis or pw) / 2.0
        c = 0.115 * ll - 0.0153
        d_at = subject.side("asis_trochanter", side)
        if d_at is None:
            d_at = 0.1288 * _need(subject.side("leg_length", side), f"{side} leg length") - 0.04856
        local = np.array([(-d_at - r) * np.cos(_BETA) + c * np.cos(_THETA) * np.sin(_BETA),
                          sgn * (aa - c * np.sin(_THETA)),
                          (-d_at - r) * np.sin(_BETA) - c * np.cos(_THETA) * np.cos(_BETA)])
        inputs = {"regression": "Davis 1991 (Plug-in Gait)", "mean_leg_length_m": ll,
                  "inter_asis_m": 2 * aa, "asis_trochanter_m": d_at, "marker_radius_m": r}
    elif method == "harrington_hip":
        pd = float(np.nanmedian(np.linalg.norm(origin - 0.5 * (m["lpsi"] + m["rpsi"]), axis=-1)))
        pw_mm, pd_mm = 1000 * (subject.inter_asis or pw), 1000 * pd
        local = 1e-3 * np.array([-0.24 * pd_mm - 9.9, sgn * (0.33 * pw_mm + 7.3), -0.30 * pw_mm - 10.9])
        inputs = {"regression": "Harrington 2007", "pelvis_width_m": pw_mm / 1000, "pelvis_depth_m": pd}
    else:
        raise RegressionError(f"unknown hip regression {method!r}")
    inputs["local_m"] = [float(v) for v in local]
    return origin + (axes @ local), inputs


def chord_centre(wand: np.ndarray, proximal: np.ndarray, lateral: np.ndarray, delta: float) -> np.ndarray:
    """Plug-in Gait's chord construction, batched: the point J [F,3] in the plane of the three
    points at ``delta`` from ``lateral`` with a right angle proximal-J-lateral, on the far side
    of the chord proximal-lateral from the wand."""
    chord = proximal - lateral
    length = np.linalg.norm(chord, axis=-1, keepdims=True)
    u = chord / length
    n = _unit(np.cross(wand - lateral, chord))
    w = np.cross(n, u)  # in the plane, perpendicular to the chord, toward the wand's side... or away
    side = np.sign(((wand - lateral) * w).sum(-1, keepdims=True))
    ratio = np.clip(delta / length, 0.0, 1.0)
    return lateral + delta * (ratio * u - np.sqrt(1.0 - ratio * ratio) * side * w)


def chord_inputs(method: str, side: str, subject: Subject) -> tuple[float, dict]:
    """delta (m) of a knee or ankle chord and the inputs used."""
    what = {"pig_knee": "knee_width", "pig_ankle": "ankle_width"}[method]
    width = _need(subject.side(what, side), f"{side} {what.replace('_', ' ')}")
    r = subject.marker_radius
    return width / 2.0 + r, {"regression": f"Plug-in Gait chord ({what.split('_')[0]})",
                             f"{what}_m": width, "marker_radius_m": r, "delta_m": width / 2.0 + r}


class RegressionStage:
    """Per-frame regression centres, as Plug-in Gait computes them, for joints whose calibrated
    method is a regression: hips from the pelvis markers, then knees and ankles by the chord
    from the current markers and the just-computed proximal centre. Batched over frames and over
    the joints of one level (hips, then knees, then ankles): three vector steps per call.

    model: a ActorModel (reads ``quality.method``, ``quality.inputs``, ``joint_parent``,
    ``marker_labels``).
    """

    def __init__(self, model) -> None:
        labels = {m.lower(): i for i, m in enumerate(model.marker_labels)}
        inputs = tuple(model.quality.inputs) + ({},) * len(model.joint_names)
        parent = np.asarray(model.joint_parent)
        hips, chords = [], []
        for j, meth in enumerate(model.quality.method):
            inp = inputs[j]
            if not meth.startswith("regression:") or "markers" not in inp:
                continue
            try:
                mk = {r: labels[v.lower()] for r, v in inp["markers"].items()}
            except KeyError:
                continue
            if meth.endswith("_hip") and "local_m" in inp:
                hips.append((j, mk, np.asarray(inp["local_m"], dtype=float)))
            elif "delta_m" in inp and parent[j] >= 0:
                chords.append((j, mk, float(inp["delta_m"])))
        self.joints = np.array([h[0] for h in hips] + [c[0] for c in chords], dtype=np.int64)
        self._hip = None
        if hips:
            self._hip = (np.array([h[0] for h in hips]),
                         {r: np.array([h[1][r] for h in hips]) for r in ("lasi", "rasi", "lpsi", "rpsi")},
                         np.stack([h[2] for h in hips]))
        # Chords in levels: a chord whose parent is itself a chord waits for it.
        levels: list[list[tuple[int, dict, float]]] = []
        done = {h[0] for h in hips}
        rest = list(chords)
        while rest:
            lvl = [c for c in rest if parent[c[0]] in done or parent[c[0]] not in {d[0] for d in rest}]
            levels.append(lvl)
            done |= {c[0] for c in lvl}
            rest = [c for c in rest if c not in lvl]
        self._chords = [(np.array([c[0] for c in lvl]), parent[[c[0] for c in lvl]],
                         np.array([c[1]["wand"] for c in lvl]), np.array([c[1]["lateral"] for c in lvl]),
                         np.array([c[2] for c in lvl])) for lvl in levels]

    def __bool__(self) -> bool:
        return bool(self.joints.size)

    def apply(self, markers: np.ndarray, joints: np.ndarray, quality: np.ndarray, good: int) -> None:
        """Overwrite joints float[T,J,3] / quality int8[T,J] in place where every input is seen
        (markers float[T,M,3]); elsewhere the rigid estimates stay."""
        if self._hip is not None:
            js, roles, local = self._hip
            pts = hip_from_local({r: markers[:, k] for r, k in roles.items()}, local[None])
            ok = np.isfinite(pts).all(-1)
            joints[:, js] = np.where(ok[..., None], pts, joints[:, js])
            quality[:, js] = np.where(ok, good, quality[:, js])
        for js, ps, wand, lat, delta in self._chords:
            prox = joints[:, ps]
            with np.errstate(invalid="ignore", divide="ignore"):
                pts = chord_centre(markers[:, wand], prox, markers[:, lat], delta[None, :, None])
            ok = np.isfinite(pts).all(-1) & (quality[:, ps] == good)
            joints[:, js] = np.where(ok[..., None], pts, joints[:, js])
            quality[:, js] = np.where(ok, good, quality[:, js])
