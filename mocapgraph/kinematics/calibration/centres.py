"""Anatomical and regression joint-centre candidates from a static trial, in the base-pose frame.

Each candidate is computed per static frame in the world (landmark midpoints; Plug-in Gait
regressions from :mod:`mocapgraph.kinematics.solving.regression`), carried into the base-pose frame by
the rigid fit of a limb of the joint (``R^T (p - t)``), and summarised by its median; the RMS
spread of the per-frame points is the candidate's residual (metres). The calibration picks one
method per joint from these and the functional (SCoRE/SARA) centre.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mocapgraph.kinematics.solving.regression import RegressionError, chord_centre, chord_inputs, hip_centre
from mocapgraph.kinematics.subject import Subject

METHODS = ("functional", "anatomical", "regression")
DEFAULT_ORDER = ("functional", "anatomical", "regression")
MIN_STATIC_FRAMES = 1


@dataclass
class Candidate:
    """A joint centre from one method: base-pose point (m), spread RMS (m), inputs for the model,
    covariance from the marker noise (m^2; NaN: not known)."""

    point: np.ndarray
    spread: float
    method: str
    inputs: dict = field(default_factory=dict)
    cov: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))


def _to_base(fit: Any, limb: int, frames: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, float, np.ndarray] | None:
    """World points pts [F,3] at ``frames`` -> median base-pose point of ``limb``, its spread and
    the covariance of that median from the per-frame scatter (``pi / 2`` times the mean's)."""
    ok = fit.valid[frames, limb] & np.isfinite(pts).all(-1)
    if ok.sum() < MIN_STATIC_FRAMES:
        return None
    rot, tr = fit.rotation[frames[ok], limb], fit.translation[frames[ok], limb]
    y = np.einsum("fji,fj->fi", rot, pts[ok] - tr)
    c = np.median(y, axis=0)
    cov = np.cov(y.T).reshape(3, 3) * (np.pi / 2) / y.shape[0] if y.shape[0] > 1 else np.full((3, 3), np.nan)
    return c, float(np.sqrt(np.mean(((y - c) ** 2).sum(-1)))), cov


class CentreCandidates:
    """Anatomical and regression centres of a layout's joints from the static frames.

    markers: float[T,M,3] layout order, metres; static: the frames of the static trial.
    subject: measurements for regressions (None: regressions unavailable).
    """

    def __init__(self, definition: Any, markers: np.ndarray, static: slice, subject: Subject | None) -> None:
        self.definition = definition
        self.markers = markers
        self.frames = np.arange(markers.shape[0])[static]
        self.subject = subject
        self.jl = np.asarray(definition.joint_limbs)
        self.owner = np.asarray(definition.marker_limb)
        J = len(self.jl)
        self.landmarks = tuple(getattr(definition, "joint_landmarks", ()) or ()) + ((),) * J
        self.regressions = tuple(getattr(definition, "joint_regression", ()) or ()) + (None,) * J
        self.notes: list[str] = []

    def _limbs(self, j: int, fit: Any, prefer: int | None = None) -> list[int]:
        a, b = (int(v) for v in self.jl[j])
        return [b, a] if prefer == b else [a, b]

    def _carry(self, j: int, fit: Any, pts: np.ndarray, prefer: int | None = None):
        for limb in self._limbs(j, fit, prefer):
            got = _to_base(fit, limb, self.frames, pts)
            if got is not None:
                return got
        return None

    def has_any(self) -> bool:
        """Whether some joint can get an anatomical or regression centre from the static."""
        x = self.markers[self.frames]
        for j in range(len(self.jl)):
            lm = self.landmarks[j]
            if lm and np.isfinite(x[:, list(lm)]).all((-1, -2)).any():
                return True
            if self.regressions[j] is not None and self.subject is not None and not self.subject.empty:
                return True
        return False

    def anatomical(self, j: int, fit: Any) -> Candidate | None:
        """Midpoint of the joint's two landmarks over the static frames."""
        lm = self.landmarks[j]
        if not lm:
            return None
        pts = 0.5 * (self.markers[self.frames, lm[0]] + self.markers[self.frames, lm[1]])
        got = self._carry(j, fit, pts, prefer=int(self.owner[lm[0]]))
        if got is None:
            return None
        labels = self.definition.marker_labels
        return Candidate(got[0], got[1], "landmarks", {"landmarks": [labels[lm[0]], labels[lm[1]]]}, got[2])

    def regression(self, j: int, fit: Any, chosen: dict[int, np.ndarray]) -> Candidate | None:
        """The layout's regression for joint j; knee/ankle chords need the parent joint in ``chosen``."""
        reg = self.regressions[j]
        if reg is None:
            return None
        name = self.definition.joint_names[j]
        if self.subject is None or self.subject.empty:
            self._note(f"{name}: regression {reg.method} needs subject measurements (VSK, C3D PROCESSING or --subject)")
            return None
        m = {role: self.markers[self.frames, k] for role, k in reg.markers.items()}
        try:
            if reg.method.endswith("_hip"):
                pts, inputs = hip_centre(reg.method, reg.side, m, self.subject)
                prefer = int(self.jl[j, 0])
            else:
                p = int(self.definition.joint_parent[j])
                if p < 0 or p not in chosen:
                    self._note(f"{name}: regression {reg.method} needs the proximal joint's centre")
                    return None
                lp = int(self.jl[p, 0])
                rot, tr = fit.rotation[self.frames, lp], fit.translation[self.frames, lp]
                prox = (rot @ chosen[p][:, None])[..., 0] + tr
                delta, inputs = chord_inputs(reg.method, reg.side, self.subject)
                pts = chord_centre(m["wand"], prox, m["lateral"], delta)
                prefer = int(self.jl[j, 0])
        except RegressionError as exc:
            self._note(f"{name}: {exc}")
            return None
        got = self._carry(j, fit, pts, prefer)
        if got is None:
            return None
        labels = self.definition.marker_labels
        inputs = dict(inputs, method=reg.method, markers={r: labels[k] for r, k in reg.markers.items()},
                      subject=self.subject.source)
        return Candidate(got[0], got[1], f"regression:{reg.method}", inputs, got[2])

    def _note(self, msg: str) -> None:
        if msg not in self.notes:
            self.notes.append(msg)
