"""The actor model and its results as messages: SkeletonModel (exact), ActorPose, the quality report.

Shared by the calibration and solver nodes and the batch commands (no math here):

- the kinematics :class:`~mocapgraph.kinematics.model.ActorModel` <-> the latched
  ``SkeletonModel`` message, exactly (float64 arrays as they are; the rest as JSON in
  ``extra_json``, whose float repr round-trips), so a model sent over the bus solves to the very
  same joints as the file it came from;
- placing a stream's or file's marker labels on a model's markers (:func:`marker_index`);
- a :class:`~mocapgraph.kinematics.solving.solver.SolverResult` as an ``ActorPose``;
- the per-joint quality report of a calibration (status JSON and the CLI table).

Units: metres, radians in messages; the report gives millimetres and degrees for people.
"""
from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from ..kinematics.model import ActorModel, JointQuality, ModelFileError
from ..kinematics.labels import missing_labels, place_labels
from ..messages import ActorPose, SkeletonModel
from ..messages.bounded_json import loads_bounded

if TYPE_CHECKING:   # the solver (scipy, numba kernels) for a type only: a reader's process never loads it
    from ..kinematics.solving.solver import SolverResult

EXTRA_FORMAT = "mocapgraph.skeleton_model.extra/1"


class ModelMismatchError(ModelFileError):
    """A model cannot be used with a marker stream or file (other layout, absent markers)."""


def jsonable(a: Any) -> Any:
    """Arrays, numpy scalars, dicts to plain JSON values with None for NaN (strict JSON)."""
    if isinstance(a, np.ndarray):
        a = a.tolist()
    elif isinstance(a, np.generic):
        a = a.item()
    if isinstance(a, dict):
        return {str(k): jsonable(v) for k, v in a.items()}
    if isinstance(a, (list, tuple)):
        return [jsonable(v) for v in a]
    if isinstance(a, float) and not math.isfinite(a):
        return None
    return a


def _farr(v: Any, shape: tuple[int, ...]) -> np.ndarray:
    return np.array(v, dtype=float).reshape(shape)  # None -> NaN


def owner_limbs(model: ActorModel) -> np.ndarray:
    """int32[M] limb owning each marker, from the fit sets (own markers first, then shared).

    A marker that appears in several fit sets is owned by the limb where it is listed earliest
    within the row (own markers precede shared ones); ties go to the lower limb index.
    """
    idx = np.asarray(model.limb_markers)
    M = len(model.marker_labels)
    pos = np.full((idx.shape[0], M), np.iinfo(np.int32).max, dtype=np.int64)
    rows, cols = np.nonzero(idx >= 0)
    pos[rows, idx[rows, cols]] = cols
    out = np.argmin(pos, axis=0).astype(np.int32)
    out[(pos == np.iinfo(np.int32).max).all(0)] = -1
    return out


def model_to_message(model: ActorModel, marker_limb: Sequence[int] | np.ndarray | None = None) -> SkeletonModel:
    """The latched message of a calibrated model (``marker_limb``: owners from the layout)."""
    q = model.quality
    extra = {
        "format": EXTRA_FORMAT,
        "limb_markers": np.asarray(model.limb_markers).tolist(),
        "limb_joint_points": np.asarray(model.limb_joint_points).tolist(),
        "limb_centroid": jsonable(np.asarray(model.limb_centroid, dtype=float)),
        "limb_rms": jsonable(np.asarray(model.limb_rms, dtype=float)),
        "quality": {
            "n_frames": np.asarray(q.n_frames).tolist(),
            "outlier_fraction": jsonable(np.asarray(q.outlier_fraction, dtype=float)),
            "reliable": np.asarray(q.reliable, dtype=bool).tolist(),
            "method": list(q.method),
            "inputs": jsonable(list(q.inputs)),
            "centre_cov": jsonable(np.asarray(q.centre_cov, dtype=float)),
            "axis_se": jsonable(np.asarray(q.axis_se, dtype=float)),
            "from_points": np.asarray(q.from_points, dtype=bool).tolist(),
        },
        "marker_noise": jsonable(float(model.marker_noise)),
        "max_uncertainty": jsonable(float(model.max_uncertainty)),
        "static_only_markers": list(model.static_only_markers),
        "warnings": list(model.warnings),
        "n_gym_frames": int(model.n_gym_frames),
        "rate_hz": model.rate_hz,
    }
    ml = owner_limbs(model) if marker_limb is None else np.asarray(marker_limb, dtype=np.int32)
    return SkeletonModel(
        layout_name=model.layout, fingerprint=model.marker_fingerprint,
        marker_labels=list(model.marker_labels), limb_names=list(model.limb_names),
        joint_names=list(model.joint_names), marker_limb=ml,
        limb_parent=model.limb_parent, joint_limbs=np.asarray(model.joint_limbs).reshape(-1, 2),
        joint_parent=model.joint_parent, joint_hinge=model.joint_hinge,
        base_markers=model.base_markers, joint_offsets=np.asarray(model.offsets).reshape(-1, 2, 3),
        base_joints=np.asarray(model.joint_base).reshape(-1, 3), bone_lengths=model.bone_length,
        hinge_axes=np.asarray(model.hinge_axis).reshape(-1, 3), joint_residual_rms=q.residual_rms,
        joint_rom=q.range_of_motion, joint_centre_se=np.asarray(q.centre_se, dtype=float),
        extra_json=json.dumps(extra, separators=(",", ":")),
    )


def model_from_message(msg: SkeletonModel, source: str = "skeleton_model message") -> ActorModel:
    """The kinematics model carried by a message; ModelFileError if it is malformed."""
    try:
        extra = loads_bounded(msg.extra_json or "{}", max_depth=8)  # from the bus: bounded before parsing
        if extra.get("format") != EXTRA_FORMAT:
            raise ValueError(f"extra_json format {extra.get('format')!r}, expected {EXTRA_FORMAT!r}")
        L, J = len(msg.limb_names), len(msg.joint_names)
        eq = extra["quality"]
        lm = np.array(extra["limb_markers"], dtype=np.int64).reshape(L, -1)
        jp = np.array(extra["limb_joint_points"], dtype=np.int64).reshape(L, -1)
        model = ActorModel(
            layout=msg.layout_name, marker_labels=tuple(msg.marker_labels),
            limb_names=tuple(msg.limb_names), limb_parent=msg.limb_parent.astype(np.int64),
            limb_markers=lm, joint_names=tuple(msg.joint_names),
            joint_limbs=msg.joint_limbs.astype(np.int64).reshape(J, 2),
            joint_parent=msg.joint_parent.astype(np.int64), joint_hinge=msg.joint_hinge.astype(bool),
            base_markers=msg.base_markers.copy(), limb_centroid=_farr(extra["limb_centroid"], (L, 3)),
            offsets=msg.joint_offsets.copy().reshape(J, 2, 3), joint_base=msg.base_joints.copy().reshape(J, 3),
            bone_length=msg.bone_lengths.copy(), hinge_axis=msg.hinge_axes.copy().reshape(J, 3),
            limb_rms=_farr(extra["limb_rms"], (L,)),
            quality=JointQuality(
                residual_rms=msg.joint_residual_rms.copy(), range_of_motion=msg.joint_rom.copy(),
                n_frames=np.array(eq["n_frames"], dtype=np.int64).reshape(J),
                outlier_fraction=_farr(eq["outlier_fraction"], (J,)),
                reliable=np.array(eq["reliable"], dtype=bool).reshape(J),
                method=tuple(eq["method"]),
                inputs=tuple(dict(v) for v in eq.get("inputs", ())),
                centre_se=msg.joint_centre_se.copy() if msg.joint_centre_se.shape == (J,) else np.full(J, np.nan),
                centre_cov=(_farr(eq["centre_cov"], (J, 3, 3)) if "centre_cov" in eq
                            else np.full((J, 3, 3), np.nan)),
                axis_se=_farr(eq["axis_se"], (J,)) if "axis_se" in eq else np.full(J, np.nan),
                from_points=np.array(eq.get("from_points", [False] * J), dtype=bool).reshape(J),
            ),
            static_only_markers=tuple(extra.get("static_only_markers", ())),
            warnings=tuple(extra.get("warnings", ())), n_gym_frames=int(extra.get("n_gym_frames", 0)),
            rate_hz=extra.get("rate_hz"), limb_joint_points=jp,
            marker_noise=float("nan") if extra.get("marker_noise") is None else float(extra["marker_noise"]),
            max_uncertainty=float("nan") if extra.get("max_uncertainty") is None else float(extra["max_uncertainty"]),
        )
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as exc:
        raise ModelFileError(f"{source}: malformed skeleton model ({exc})") from None
    if msg.fingerprint and msg.fingerprint != model.marker_fingerprint:
        raise ModelFileError(f"{source}: fingerprint does not match its marker labels")
    M = len(model.marker_labels)
    if model.base_markers.shape != (M, 3) or (lm >= M).any():
        raise ModelFileError(f"{source}: malformed skeleton model (marker arrays do not match {M} labels)")
    return model


# ----- labels ------------------------------------------------------------------------------------
def marker_index(model: ActorModel, stream_layout: str, stream_labels: Sequence[str],
                 source: str = "marker stream") -> np.ndarray:
    """int64[M]: for each model marker its index in the stream's labels.

    Raises ModelMismatchError (one line) when a model marker is absent from the stream: with the
    layouts named when they differ, the missing labels otherwise. A stream from another layout
    that still carries every model marker by label is accepted (the caller may note it).
    """
    where, _ = place_labels(model.marker_labels, list(stream_labels))
    # Static-only markers (medial landmarks) may be absent: -1, always missing.
    optional = {m.lower() for m in model.static_only_markers}
    missing = [m for m in missing_labels(model.marker_labels, where) if m.lower() not in optional]
    if missing:
        if stream_layout and stream_layout != model.layout:
            raise ModelMismatchError(
                f"{source}: model was calibrated for layout '{model.layout}', but the markers come in "
                f"layout '{stream_layout}' which lacks {len(missing)} of its {len(where)} markers "
                f"({', '.join(missing[:6])}{', ...' if len(missing) > 6 else ''})")
        raise ModelMismatchError(
            f"{source}: lacks {len(missing)} of the {len(where)} markers of model '{model.layout}': "
            f"{', '.join(missing)}")
    return where


# ----- poses -------------------------------------------------------------------------------------
def pose_message(res: SolverResult, actor: str, frame_number: int) -> ActorPose:
    """One solved frame (SolverResult without a T dim) as an ActorPose."""
    return ActorPose(
        actor=actor, frame_number=int(frame_number), joint_positions=res.joints,
        joint_quality=res.joint_quality, limb_orientations=res.limb_rotation,
        limb_quality=res.limb_quality, limb_visible_markers=res.limb_visible.astype(np.int16),
        joint_uncertainty=res.joint_uncertainty,
    )


def missing_pose(model: ActorModel, actor: str, frame_number: int) -> ActorPose:
    """An ActorPose with every joint and limb missing (NaN + quality 0)."""
    J, L = len(model.joint_names), len(model.limb_names)
    return ActorPose(
        actor=actor, frame_number=int(frame_number), joint_positions=np.full((J, 3), np.nan),
        joint_quality=np.zeros(J, np.int8), limb_orientations=np.full((L, 4), np.nan),
        limb_quality=np.zeros(L, np.int8), limb_visible_markers=np.zeros(L, np.int16),
        joint_uncertainty=np.full(J, np.nan),
    )


# ----- quality report ----------------------------------------------------------------------------
def quality_report(model: ActorModel, min_rom_deg: float | None = None) -> dict[str, Any]:
    """Per-joint calibration quality for people: residual mm, range of motion deg, the centre's
    standard error mm (and a hinge axis's, deg), how it was found, reliable."""
    q = model.quality
    bound = model.max_uncertainty * 1000 if np.isfinite(model.max_uncertainty) else None
    joints = []
    for j, name in enumerate(model.joint_names):
        rom = float(np.degrees(q.range_of_motion[j]))
        se = float(q.centre_se[j]) * 1000
        warn = []
        if not q.reliable[j]:
            why = [f"range of motion {rom:.1f} deg" + (f" (needs {min_rom_deg:g})" if min_rom_deg is not None else "")]
            if math.isfinite(se):
                why.append(f"standard error {se:.1f} mm" + (f" (bound {bound:g})" if bound is not None else ""))
            warn.append(", ".join(why) + ": no reliable centre (move this joint more, or give landmarks / a regression)")
        inputs = q.inputs[j] if j < len(q.inputs) else {}
        if q.from_points[j]:
            warn.append("found from markers as points: " + str(inputs.get("points", "a limb's cluster cannot fix its orientation")))
        joints.append({
            "joint": name, "method": q.method[j],
            "residual_mm": jsonable(round(float(q.residual_rms[j]) * 1000, 3)),
            "se_mm": jsonable(round(se, 3)),
            "axis_se_deg": jsonable(round(float(np.degrees(q.axis_se[j])), 3)),
            "from_points": bool(q.from_points[j]),
            "rom_deg": round(rom, 2), "frames": int(q.n_frames[j]),
            "outliers": jsonable(round(float(q.outlier_fraction[j]), 4)),
            "reliable": bool(q.reliable[j]), "warnings": warn,
            "inputs": jsonable(inputs),
        })
    return {"layout": model.layout, "gym_frames": int(model.n_gym_frames), "joints": joints,
            "marker_noise_mm": jsonable(round(float(model.marker_noise) * 1000, 3)),
            "max_uncertainty_mm": jsonable(bound), "warnings": list(model.warnings)}


def quality_table(model: ActorModel) -> str:
    """A fixed-width per-joint table (mm, deg) for the terminal."""
    rep = quality_report(model)
    w = max([len("joint")] + [len(r["joint"]) for r in rep["joints"]])
    mw = max([12] + [len(r["method"]) for r in rep["joints"]])
    lines = [f"{'joint':<{w}}  {'method':<{mw}} {'ROM deg':>8} {'resid mm':>9} {'+-SE mm':>8} {'frames':>7}  reliable"]
    for r in rep["joints"]:
        res = "-" if r["residual_mm"] is None else f"{r['residual_mm']:.2f}"
        se = "-" if r["se_mm"] is None else f"{r['se_mm']:.2f}"
        lines.append(f"{r['joint']:<{w}}  {r['method']:<{mw}} {r['rom_deg']:>8.1f} {res:>9} {se:>8} {r['frames']:>7}  "
                     f"{'yes' if r['reliable'] else 'NO'}" + ("  (points)" if r["from_points"] else ""))
    if rep["marker_noise_mm"] is not None:
        lines.append(f"marker noise from the clusters' residuals: {rep['marker_noise_mm']:.2f} mm; "
                     + (f"reliable: SE <= {rep['max_uncertainty_mm']:g} mm" if rep["max_uncertainty_mm"] is not None
                        else "residuals are skin motion, not noise: the residual bound decides"))
    return "\n".join(lines)
