"""Calibrated actor skeleton (the output of calibration, the input of the frame solver).

Everything is in the base-pose world frame (metres, Z up): a limb's pose at any frame is the rigid
transform (R, t) from its base-pose markers to the current ones, and joint ``j`` seen from limb
``joint_limbs[j, k]`` sits at ``R @ (limb_centroid[l] + offsets[j, k]) + t`` (Kiip Eq 1).
Saved as versioned, human-readable JSON.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..messages.quality import Quality  # noqa: F401  (the one definition; re-exported for the math)

MODEL_FORMAT = "mocapgraph.skeleton_model"
MODEL_VERSION = 2
#: versions this build reads (1: no uncertainties; they load as NaN, "not known")
READ_VERSIONS = (1, 2)


class ModelFileError(ValueError):
    """A model file cannot be read, or belongs to another marker layout."""


def marker_fingerprint(labels: Sequence[str]) -> str:
    """Short stable hash of the ordered marker labels (detects a model used with another layout)."""
    return hashlib.sha256("\n".join(labels).encode("utf-8")).hexdigest()[:16]


@dataclass
class JointQuality:
    """Calibration quality of each joint (arrays over J)."""

    residual_rms: np.ndarray   # m, disagreement between the two limbs' estimates over gym frames
    range_of_motion: np.ndarray  # rad, largest relative rotation between the two limbs covered
    n_frames: np.ndarray       # gym frames with both limbs visible
    outlier_fraction: np.ndarray  # share of frames down-weighted by the robust fit
    reliable: np.ndarray       # bool: a centre from a method that applies (never the prior)
    # "ball", "hinge[+plane|+landmarks|+regression|+midplane]", "sphere" (functional),
    # "landmarks" (anatomical), "regression:pig_hip" ..., "prior"
    method: tuple[str, ...]
    inputs: tuple[dict, ...] = ()  # per joint: what the method used (landmarks, measurements, m)
    # Standard error of each centre from the marker noise (m, RMS 3-D error ``sqrt(trace(cov))``;
    # a hinge's: across its axis only), its covariance (m^2, base-pose frame) and a hinge axis's
    # angular standard error (rad; NaN for ball joints). NaN: not known (a version 1 file).
    centre_se: np.ndarray = field(default_factory=lambda: np.zeros(0))
    centre_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    axis_se: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # Joints whose centre came from one limb's markers as points in the other limb's frame
    # because that limb's own cluster cannot fix its orientation (near-collinear, too small).
    from_points: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __post_init__(self) -> None:
        J = len(self.method)
        if np.shape(self.centre_se) != (J,):
            self.centre_se = np.full(J, np.nan)
        if np.shape(self.centre_cov) != (J, 3, 3):
            self.centre_cov = np.full((J, 3, 3), np.nan)
        if np.shape(self.axis_se) != (J,):
            self.axis_se = np.full(J, np.nan)
        if np.shape(self.from_points) != (J,):
            self.from_points = np.zeros(J, dtype=bool)


@dataclass
class ActorModel:
    """A calibrated actor (the kinematic model; its message is `SkeletonModel`): the layout's structure plus per-actor geometry in the base pose."""

    layout: str
    marker_labels: tuple[str, ...]
    limb_names: tuple[str, ...]
    limb_parent: np.ndarray      # int64[L], -1 for the root limb
    limb_markers: np.ndarray     # int64[L,K] marker indices per limb, -1 padding
    joint_names: tuple[str, ...]
    joint_limbs: np.ndarray      # int64[J,2] (proximal, distal) limb per joint
    joint_parent: np.ndarray     # int64[J], -1 if none
    joint_hinge: np.ndarray      # bool[J]
    base_markers: np.ndarray     # float[M,3] m, base pose
    limb_centroid: np.ndarray    # float[L,3] m, centroid of each limb's markers in the base pose
    offsets: np.ndarray          # float[J,2,3] m, joint minus limb centroid, base pose
    joint_base: np.ndarray       # float[J,3] m, joint positions in the base pose
    bone_length: np.ndarray      # float[J] m, joint to parent joint (NaN for roots)
    hinge_axis: np.ndarray       # float[J,3] unit, base-pose frame (NaN unless hinge)
    limb_rms: np.ndarray         # float[L] m, median rigid-fit RMS over the gym frames
    quality: JointQuality
    warnings: tuple[str, ...] = ()
    n_gym_frames: int = 0
    rate_hz: float | None = None
    marker_fingerprint: str = field(default="")
    # int64[L,P]: joints whose centre (seen from the joint's other limb) is an extra fit point
    # of each limb (-1 padding); for limbs with only two markers (Plug-in Gait thigh).
    limb_joint_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int64))
    # Markers seen only in the static trial (medial landmarks): later trials need not have them.
    static_only_markers: tuple[str, ...] = ()
    # Marker noise (m, per coordinate) estimated from the clusters' own rigid-fit residuals, and
    # the bound on a centre's standard error (m) under which calibration called it reliable.
    marker_noise: float = float("nan")
    max_uncertainty: float = float("nan")

    def __post_init__(self) -> None:
        if not self.marker_fingerprint:
            self.marker_fingerprint = marker_fingerprint(self.marker_labels)
        if self.limb_joint_points.shape[0] != len(self.limb_names):
            self.limb_joint_points = np.full((len(self.limb_names), 0), -1, dtype=np.int64)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_limbs(self) -> int:
        return len(self.limb_names)

    def check_layout(self, layout: str, labels: Sequence[str], source: str = "model") -> None:
        """Raise ModelFileError unless this model was calibrated for this layout and labels."""
        fp = marker_fingerprint(tuple(labels))
        if layout != self.layout or fp != self.marker_fingerprint:
            extra = ""
            if fp != self.marker_fingerprint:
                ours, theirs = set(self.marker_labels), set(labels)
                diff = sorted(ours ^ theirs)[:6]
                extra = f"; markers differ ({', '.join(diff)})" if diff else "; marker order differs"
            raise ModelFileError(
                f"{source}: model was calibrated for layout '{self.layout}', "
                f"not for layout '{layout}'{extra}"
            )

    # ---- JSON -----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        def arr(a: np.ndarray, nd: int = 6) -> Any:
            a = np.asarray(a)
            if a.dtype.kind == "f":
                return [None if not np.isfinite(v) else round(float(v), nd) for v in a.ravel()] \
                    if a.ndim == 1 else [arr(r, nd) for r in a]
            return a.tolist()

        q = self.quality
        return {
            "format": MODEL_FORMAT,
            "version": MODEL_VERSION,
            "layout": self.layout,
            "marker_fingerprint": self.marker_fingerprint,
            "units": "m",
            "frame": "base-pose world frame, Z up",
            "n_gym_frames": self.n_gym_frames,
            "rate_hz": self.rate_hz,
            "warnings": list(self.warnings),
            "marker_labels": list(self.marker_labels),
            "static_only_markers": list(self.static_only_markers),
            "marker_noise": arr(np.array([self.marker_noise]), 7)[0],
            "max_uncertainty": arr(np.array([self.max_uncertainty]), 7)[0],
            "base_markers": arr(self.base_markers, 7),
            "limbs": [
                {
                    "name": n,
                    "parent": int(self.limb_parent[i]),
                    "markers": [int(m) for m in self.limb_markers[i] if m >= 0],
                    "joint_points": [int(j) for j in self.limb_joint_points[i] if j >= 0],
                    "centroid": arr(self.limb_centroid[i], 7),
                    "fit_rms": arr(self.limb_rms[i : i + 1], 7)[0],
                }
                for i, n in enumerate(self.limb_names)
            ],
            "joints": [
                {
                    "name": n,
                    "limbs": [int(v) for v in self.joint_limbs[j]],
                    "parent": int(self.joint_parent[j]),
                    "hinge": bool(self.joint_hinge[j]),
                    "offsets": arr(self.offsets[j], 7),
                    "base_position": arr(self.joint_base[j], 7),
                    "bone_length": arr(self.bone_length[j : j + 1], 7)[0],
                    "hinge_axis": arr(self.hinge_axis[j], 7),
                    "quality": {
                        "residual_rms": arr(q.residual_rms[j : j + 1], 7)[0],
                        "range_of_motion_rad": arr(q.range_of_motion[j : j + 1], 5)[0],
                        "n_frames": int(q.n_frames[j]),
                        "outlier_fraction": arr(q.outlier_fraction[j : j + 1], 4)[0],
                        "reliable": bool(q.reliable[j]),
                        "method": q.method[j],
                        "inputs": q.inputs[j] if j < len(q.inputs) else {},
                        "centre_se": arr(q.centre_se[j : j + 1], 12)[0],
                        "centre_cov": arr(q.centre_cov[j], 14),
                        "axis_se_rad": arr(q.axis_se[j : j + 1], 6)[0],
                        "from_points": bool(q.from_points[j]),
                    },
                }
                for j, n in enumerate(self.joint_names)
            ],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "model") -> "ActorModel":
        if d.get("format") != MODEL_FORMAT:
            raise ModelFileError(f"{source}: not a skeleton model file (format {d.get('format')!r})")
        if d.get("version") not in READ_VERSIONS:
            raise ModelFileError(
                f"{source}: skeleton model version {d.get('version')} is not supported "
                f"(this build reads {', '.join(map(str, READ_VERSIONS))})"
            )

        def f(v: Any) -> float:
            return float("nan") if v is None else float(v)

        def farr(rows: Any, shape: tuple[int, ...]) -> np.ndarray:
            return np.array(rows, dtype=float).reshape(shape)  # None -> NaN

        try:
            limbs, joints = d["limbs"], d["joints"]
            L, J = len(limbs), len(joints)
            kmax = max([len(li["markers"]) for li in limbs] + [1])
            limb_markers = np.full((L, kmax), -1, dtype=np.int64)
            for i, li in enumerate(limbs):
                limb_markers[i, : len(li["markers"])] = li["markers"]
            pmax = max([len(li.get("joint_points", [])) for li in limbs] + [0])
            jpts = np.full((L, pmax), -1, dtype=np.int64)
            for i, li in enumerate(limbs):
                jpts[i, : len(li.get("joint_points", []))] = li.get("joint_points", [])
            qs = [j["quality"] for j in joints]
            model = cls(
                layout=str(d["layout"]),
                marker_labels=tuple(d["marker_labels"]),
                limb_names=tuple(li["name"] for li in limbs),
                limb_parent=np.array([li["parent"] for li in limbs], dtype=np.int64),
                limb_markers=limb_markers,
                joint_names=tuple(j["name"] for j in joints),
                joint_limbs=np.array([j["limbs"] for j in joints], dtype=np.int64).reshape(J, 2),
                joint_parent=np.array([j["parent"] for j in joints], dtype=np.int64),
                joint_hinge=np.array([j["hinge"] for j in joints], dtype=bool),
                base_markers=farr(d["base_markers"], (-1, 3)),
                limb_centroid=farr([li["centroid"] for li in limbs], (L, 3)),
                offsets=farr([j["offsets"] for j in joints], (J, 2, 3)),
                joint_base=farr([j["base_position"] for j in joints], (J, 3)),
                bone_length=np.array([f(j["bone_length"]) for j in joints], dtype=float),
                hinge_axis=farr([j["hinge_axis"] for j in joints], (J, 3)),
                limb_rms=np.array([f(li["fit_rms"]) for li in limbs], dtype=float),
                quality=JointQuality(
                    residual_rms=np.array([f(q["residual_rms"]) for q in qs], dtype=float),
                    range_of_motion=np.array([f(q["range_of_motion_rad"]) for q in qs], dtype=float),
                    n_frames=np.array([q["n_frames"] for q in qs], dtype=np.int64),
                    outlier_fraction=np.array([f(q["outlier_fraction"]) for q in qs], dtype=float),
                    reliable=np.array([q["reliable"] for q in qs], dtype=bool),
                    method=tuple(q["method"] for q in qs),
                    inputs=tuple(dict(q.get("inputs", {})) for q in qs),
                    centre_se=np.array([f(q.get("centre_se")) for q in qs], dtype=float),
                    centre_cov=np.array([np.full((3, 3), np.nan) if q.get("centre_cov") is None
                                         else farr(q["centre_cov"], (3, 3)) for q in qs]).reshape(J, 3, 3),
                    axis_se=np.array([f(q.get("axis_se_rad")) for q in qs], dtype=float),
                    from_points=np.array([bool(q.get("from_points", False)) for q in qs], dtype=bool),
                ),
                warnings=tuple(d.get("warnings", ())),
                n_gym_frames=int(d.get("n_gym_frames", 0)),
                rate_hz=d.get("rate_hz"),
                limb_joint_points=jpts,
                static_only_markers=tuple(d.get("static_only_markers", ())),
                marker_noise=f(d.get("marker_noise")),
                max_uncertainty=f(d.get("max_uncertainty")),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise ModelFileError(f"{source}: malformed skeleton model ({exc.__class__.__name__}: {exc})") from None
        if d.get("marker_fingerprint") and d["marker_fingerprint"] != model.marker_fingerprint:
            raise ModelFileError(f"{source}: marker fingerprint does not match its marker labels (edited file?)")
        return model


def save_model(model: ActorModel, path: str | Path) -> None:
    """Write the model as indented JSON."""
    Path(path).write_text(json.dumps(model.to_dict(), indent=1) + "\n", encoding="utf-8")


def as_saved(model: ActorModel, source: str = "calibration") -> ActorModel:
    """The model exactly as its file holds it (values rounded as :func:`save_model` writes them),
    so a session using it now and one loading the file later compute the same joints."""
    return ActorModel.from_dict(json.loads(json.dumps(model.to_dict())), source=source)


def load_model(
    path: str | Path,
    layout: str | None = None,
    marker_labels: Sequence[str] | None = None,
) -> ActorModel:
    """Read a model file; with ``layout`` (and labels), refuse a model calibrated for another layout.

    ``layout`` may also be any object with ``name`` and ``marker_labels`` (a SkeletonDefinition).
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ModelFileError(f"{path}: no such skeleton model file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelFileError(f"{path}: cannot read skeleton model ({exc})") from None
    if not isinstance(data, dict):
        raise ModelFileError(f"{path}: not a skeleton model file")
    model = ActorModel.from_dict(data, source=str(path))
    if layout is not None:
        if not isinstance(layout, str):
            marker_labels = tuple(layout.marker_labels)
            layout = layout.name
        model.check_layout(layout, marker_labels if marker_labels is not None else model.marker_labels,
                           source=str(path))
    return model
