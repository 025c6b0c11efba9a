"""Actor calibration from a base pose and a gym (range-of-motion) capture (Kiip 3.3, 4.3).

1. Base pose: the first frame in which every marker is visible.
2. Limb rotations in every gym frame relative to the base pose (weighted Kabsch, rigid.py).
3. Per joint, the offsets from the two limbs' base-pose centroids to the joint by least squares
   over all frames (Kiip Eq 7 / SCoRE, Ehrig 2006): ``[R_a  -R_b] [o_a; o_b] = c_b - c_a``, with
   Huber IRLS down-weighting outlier frames. Hinge joints get their axis from the same system's
   null space (SARA, Ehrig 2007); directions the motion does not determine (the hinge axis, or
   everything for a joint that hardly moved) are fixed by a prior: the point nearest to the
   midpoint of the two limbs' marker centroids.
4. Bone lengths: median joint-to-parent distance over the gym frames.
"""
from __future__ import annotations

import warnings
from typing import Any, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.kinematics.calibration.centres import DEFAULT_ORDER, METHODS, Candidate, CentreCandidates
from mocapgraph.kinematics.calibration.consistency import cluster_changes
from mocapgraph.kinematics.labels import missing_labels, place_labels
from mocapgraph.kinematics.model import JointQuality, ActorModel
from mocapgraph.kinematics.subject import Subject
from mocapgraph.kinematics.solving.rigid import MIN_MARKERS, fit_rigid, gather_limb_markers
from mocapgraph.kinematics.calibration.uncertainty import (
    cluster_rotation_cov, cluster_rotation_sd, hinge_axis_se, marker_noise, score_covariance, sphere_covariance, standard_error)

# Directions of the 6-D offset space whose eigenvalue (relative to the largest) is below this
# are numerically undetermined and are fixed by the prior.
_NULL_TOL = 1e-9
# For joints with too little motion, every direction weaker than this is fixed by the prior.
_LOW_MOTION_TOL = 1e-2


# Residual correlation from frame to frame under which the clusters' deviations are taken for
# measurement noise and the fits are corrected for it (errors in variables); skin moving over
# bone (real captures: 0.8-1) is slow and left alone.
_WHITE_LAG1 = 0.5
# The residual bound (mm) of functional centres when the residuals are not white noise.
_RESIDUAL_MM = 10.0

# Largest slide (m) of a hinge centre along its axis by the perpendicular-to-the-parent rule.
_MAX_AXIAL_SHIFT = 0.04


class CalibrationError(ValueError):
    """The capture cannot produce a skeleton model (message names the fault)."""


class CalibrationWarning(UserWarning):
    """The model was built, but some joints are unreliable (message names them)."""


def layout_markers(
    definition: Any,
    labels: Sequence[str],
    positions: np.ndarray,
    source: str = "capture",
    allow_missing: bool = False,
) -> np.ndarray:
    """Reorder a capture's markers float[T,N,3] (labels[N]) into the layout's order -> [T,M,3].

    Labels match case-insensitively (and without a Vicon ``Subject:`` prefix). Layout markers the
    capture lacks raise CalibrationError naming them, or become NaN with ``allow_missing``.
    """
    positions = np.asarray(positions, dtype=float)
    where, _ = place_labels(definition.marker_labels, list(labels))
    missing = missing_labels(definition.marker_labels, where)
    if missing and not allow_missing:
        raise CalibrationError(
            f"{source}: layout '{definition.name}' names markers the capture lacks: {', '.join(missing)}")
    out = positions[:, np.where(where >= 0, where, 0)]
    out[:, where < 0] = np.nan
    return out


def find_base_pose(
    markers: np.ndarray,
    labels: Sequence[str],
    max_frames: int | None = None,
    source: str = "capture",
) -> int:
    """Index of the first frame of float[T,M,3] with every marker visible.

    Only the first ``max_frames`` frames are searched (the timeout). Raises CalibrationError
    listing the markers never seen, or those missing from the most complete frame.
    """
    markers = np.asarray(markers, dtype=float)
    window = markers[: max_frames if max_frames else None]
    if window.shape[0] == 0:
        raise CalibrationError(f"{source}: no frames to search for a base pose")
    vis = np.isfinite(window).all(-1)  # [T,M]
    full = np.flatnonzero(vis.all(1))
    if full.size:
        return int(full[0])
    never = [labels[m] for m in np.flatnonzero(~vis.any(0))]
    span = f"the first {window.shape[0]} frames"
    if never:
        raise CalibrationError(
            f"{source}: no base pose in {span}: markers never visible: {', '.join(never)}")
    best = int(np.argmax(vis.sum(1)))
    missing = [labels[m] for m in np.flatnonzero(~vis[best])]
    raise CalibrationError(
        f"{source}: no base pose in {span}: no frame shows all markers at once "
        f"(best frame {best} lacks {', '.join(missing)})")


def _check_definition(definition: Any, markers: np.ndarray, source: str) -> np.ndarray:
    labels = tuple(definition.marker_labels)
    if markers.ndim != 3 or markers.shape[1:] != (len(labels), 3):
        raise CalibrationError(
            f"{source}: markers have shape {markers.shape}, expected [T, {len(labels)}, 3] "
            f"in the order of layout '{definition.name}'")
    idx = np.asarray(definition.limb_marker_index())
    counts = (idx >= 0).sum(1) + (_joint_points(definition) >= 0).sum(1)
    few = [f"{definition.limb_names[l]} ({counts[l]})" for l in np.flatnonzero(counts < MIN_MARKERS)]
    if few:
        raise CalibrationError(
            f"{source}: layout '{definition.name}': limbs with fewer than {MIN_MARKERS} markers "
            f"(fit points) cannot be tracked: {', '.join(few)}")
    jl = np.asarray(definition.joint_limbs)
    lonely = [definition.joint_names[j] for j in range(len(jl)) if (jl[j] < 0).any()]
    if lonely:
        raise CalibrationError(
            f"{source}: layout '{definition.name}': joints need two limbs to be calibrated: "
            f"{', '.join(lonely)}")
    return idx


# Share of frames farthest from the mean orientation left out of the range of motion, so that
# a few glitched frames (a marker swap) do not pass for motion.
_ROM_TRIM = 0.02


# Frames averaged (moving window) before the range is taken: marker noise on a small cluster
# jitters its orientation by degrees, and the largest pairwise angle of raw frames measures the
# noise's extremes, not the motion (a still subject with 1 mm noise "moved" 5-20 deg).
_ROM_SMOOTH = 15


def _moving_mean(x: np.ndarray, n: int = _ROM_SMOOTH) -> np.ndarray:
    """Centred moving mean of rows of x [N,D] over n frames (shorter at the ends)."""
    if x.shape[0] < 3 or n < 2:
        return x
    c = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    i = np.arange(x.shape[0])
    lo, hi = np.maximum(i - n // 2, 0), np.minimum(i + n // 2 + 1, x.shape[0])
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def _swing_range(u: np.ndarray, max_samples: int = 240) -> float:
    """Largest angle (rad) between any two of the unit directions u [N,3] (smoothed, trimmed)."""
    if u.shape[0] < 2:
        return 0.0
    u = _moving_mean(u)
    u /= np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
    mean = u.mean(0)
    dev = u @ (mean / max(np.linalg.norm(mean), 1e-12))
    u = u[dev >= np.quantile(dev, _ROM_TRIM)]
    sel = u[np.linspace(0, u.shape[0] - 1, min(max_samples, u.shape[0])).astype(int)]
    return float(np.arccos((sel @ sel.T).clip(-1.0, 1.0).min()))


def joint_range_of_motion(definition: Any, markers: np.ndarray, fit: Any | None = None,
                          idx: np.ndarray | None = None) -> np.ndarray:
    """Range of motion (rad) of every joint from markers float[T,M,3] (layout order, metres).

    Measured from the markers alone, never through joint points: a limb with a rigid fit of its
    own (>= 3 markers) gives the largest relative rotation to the other limb; a limb with fewer
    (a Plug-in Gait thigh: THI, KNE) gives the swing of its marker pair seen in the other limb's
    frame, a lower bound that ignores the twist about the pair. A fit through an estimated joint
    point would turn that point's noise into rotation (a still subject would "move" 30-180 deg).
    """
    markers = np.asarray(markers, dtype=float)
    idx = np.asarray(definition.limb_marker_index() if idx is None else idx)  # (idx: without lost markers)
    if fit is None:
        ref = gather_limb_markers(markers[0], idx)
        fit = fit_rigid(ref, gather_limb_markers(markers, idx), (idx >= 0).astype(float))
    jl = np.asarray(definition.joint_limbs)
    rom = np.zeros(len(jl))
    # Relative rotations of every joint's two limbs in one conversion (identity where unseen).
    both_all = fit.valid[:, jl[:, 0]] & fit.valid[:, jl[:, 1]]                      # [T,J]
    rel = np.swapaxes(fit.rotation[:, jl[:, 0]], -1, -2) @ fit.rotation[:, jl[:, 1]]
    rel = np.where(both_all[..., None, None], rel, np.eye(3))
    q_all = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_quat(scalar_first=True).reshape(rel.shape[:2] + (4,))
    for j, (a, b) in enumerate(jl):
        both = np.flatnonzero(both_all[:, j])
        own_a, own_b = (idx[a] >= 0).sum() >= MIN_MARKERS, (idx[b] >= 0).sum() >= MIN_MARKERS
        if own_a and own_b:
            if both.size:
                rom[j] = _range_of_motion(q_all[both, j])
            continue
        frame_l, pair_l = (a, b) if own_a else (b, a)
        pair = idx[pair_l][idx[pair_l] >= 0][:2]
        if pair.size < 2:
            continue
        v = markers[:, pair[1]] - markers[:, pair[0]]
        ok = fit.valid[:, frame_l] & np.isfinite(v).all(-1)
        u = np.einsum("tji,tj->ti", fit.rotation[ok, frame_l], v[ok])
        u /= np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
        rom[j] = _swing_range(u)
    return rom


def _range_of_motion(q_rel: np.ndarray, max_samples: int = 240) -> float:
    """Largest rotation angle (rad) between any two of the relative orientations (wxyz [N,4]),
    leaving out the ``_ROM_TRIM`` share farthest from their mean."""
    if q_rel.shape[0] < 2:
        return 0.0
    q_rel = q_rel * np.where(q_rel @ q_rel[0] < 0, -1.0, 1.0)[:, None]  # one hemisphere to average
    q_rel = _moving_mean(q_rel)
    q_rel /= np.linalg.norm(q_rel, axis=-1, keepdims=True)
    mean = q_rel.mean(0)
    closeness = np.abs(q_rel @ (mean / max(np.linalg.norm(mean), 1e-12)))  # cos(half angle from the mean)
    q_rel = q_rel[closeness >= np.quantile(closeness, _ROM_TRIM)]
    sel = q_rel[np.linspace(0, q_rel.shape[0] - 1, min(max_samples, q_rel.shape[0])).astype(int)]
    dots = np.abs(sel @ sel.T).clip(0.0, 1.0)
    return float(2.0 * np.arccos(dots.min()))


def _solve_offsets(
    nmat: np.ndarray, g: np.ndarray, hinge: bool, low_motion: bool
) -> tuple[np.ndarray, np.ndarray | None, str]:
    """Minimise the SCoRE system (normal matrix nmat [6,6], g [6]) with a prior on weak directions.

    x = [x_a, x_b] are the offsets measured from the midpoint of the two limbs' base centroids,
    so the base-pose joint is ``mid + (x_a + x_b) / 2``; directions of x the motion leaves
    undetermined (eigenvalues below the tolerance, and the hinge axis) are chosen to put that
    point nearest to the midpoint. Returns x, the hinge axis (unit, or None) and the method name.
    """
    lam, vec = np.linalg.eigh(nmat)
    lmax = max(lam[-1], 1e-300)
    keep = lam > (_LOW_MOTION_TOL if low_motion else _NULL_TOL) * lmax
    axis = None
    if hinge:
        u = vec[:, 0]
        axis = u[:3] + u[3:]
        nrm = np.linalg.norm(axis)
        axis = axis / nrm if nrm > 1e-12 else None
        keep[0] = False
    vk, lk = vec[:, keep], lam[keep]
    x0 = vk @ ((vk.T @ g) / lk)
    weak = vec[:, ~keep]
    if weak.shape[1]:
        gmat = np.hstack([np.eye(3), np.eye(3)]) * 0.5
        s, *_ = np.linalg.lstsq(gmat @ weak, -(gmat @ x0), rcond=None)
        x0 = x0 + weak @ s
    n_weak = int((~keep).sum()) - (1 if hinge else 0)
    method = ("hinge" if hinge else "ball") + ("+prior" if n_weak > 0 else "")
    if n_weak >= 3:
        method = "prior"
    return x0, axis, method


def calibrate(
    definition: Any,
    markers: np.ndarray,
    *,
    base_frame: int | None = None,
    rate_hz: float | None = None,
    max_base_search_s: float | None = 10.0,
    min_rom_deg: float = 25.0,
    huber_k: float = 3.0,
    irls_iterations: int = 8,
    source: str = "capture",
    centre_order: Sequence[str] = DEFAULT_ORDER,
    max_residual_mm: float | None = None,
    subject: Subject | None = None,
    parts: Sequence[tuple[str, int]] | None = None,
    max_uncertainty_mm: float = 2.0,
    degenerate_rotation_deg: float = 5.0,
) -> ActorModel:
    """Build an ActorModel from float[T,M,3] markers (layout order, metres, NaN = unseen).

    definition: a SkeletonDefinition (name, limb/joint/marker names and indices).
    base_frame: the base pose frame; by default the first frame with every marker visible,
    searched within ``max_base_search_s`` (needs ``rate_hz``; otherwise the whole capture).
    All frames (base pose included) are the gym motion. Joints whose two limbs rotate less than
    ``min_rom_deg`` relative to each other get no functional centre; if no joint moved enough
    and none has landmarks or a regression either, CalibrationError.

    Per joint the centre's method is the first of ``centre_order`` that applies: "functional"
    (SCoRE/SARA, or a sphere fit for joint points: range >= min_rom_deg and a standard error,
    propagated from the marker noise the clusters' own residuals show, of at most
    ``max_uncertainty_mm``; ``max_residual_mm``, if given, also bounds the residual; when the
    residuals are skin motion rather than noise, the residual bound alone, 10 mm by default),
    "anatomical" (the layout's landmark pair, midpoint over the static frames), "regression"
    (the layout's Plug-in Gait / Harrington regression with ``subject``); else the prior (a centre between the limbs, flagged unreliable). A functional hinge's place
    along its axis comes from its landmarks, else its regression, else the plane of its
    neighbours, else the mid-plane of the markers.
    parts: (file name, frame count) of concatenated captures: the first is the static trial
    (landmarks, regressions); markers absent from every later part are static-only (the model
    does not need them later); cluster distances changing by more than 3 mm between parts are
    reported as warnings naming the markers.
    A limb whose own cluster cannot fix its orientation (its rotation's standard deviation under
    the estimated noise above ``degenerate_rotation_deg``: near-collinear, tiny) is fitted
    through its joints to limbs that can (its markers as points: a sphere fit each in the
    neighbour's frame, jointly), as a layout's ``joint_points`` are.
    """
    markers = np.asarray(markers, dtype=float)
    idx = _check_definition(definition, markers, source)
    labels = tuple(definition.marker_labels)
    bad = [m for m in centre_order if m not in METHODS]
    if bad:
        raise CalibrationError(f"{source}: unknown centre method {bad[0]!r} (known: {', '.join(METHODS)})")
    n_static = int(parts[0][1]) if parts else markers.shape[0]
    idx, seen, lost_note = _drop_lost_markers(definition, idx, markers, source)
    b0 = _base_frame(seen, labels, base_frame, rate_hz, max_base_search_s, source)
    base = markers[b0]
    ref = gather_limb_markers(base, idx)                      # [L,K,3]
    c0 = np.nanmean(ref, axis=1)                              # [L,3]
    w0 = (idx >= 0).astype(float)
    fit = fit_rigid(ref, gather_limb_markers(markers, idx), w0)
    jl = np.asarray(definition.joint_limbs)
    names = tuple(definition.joint_names)
    # Range of motion from the markers' own fits, before any joint point enters a fit.
    rom = joint_range_of_motion(definition, markers, fit, idx)
    low = rom < np.radians(min_rom_deg)
    cands = CentreCandidates(definition, markers, slice(0, n_static), subject)
    if low.all() and not cands.has_any():
        hint = ("; the layout's regression centres need subject measurements (a VSK, a C3D's PROCESSING "
                "parameters or --subject)" if any(r is not None for r in cands.regressions) else "")
        raise CalibrationError(
            f"{source}: gym capture has almost no motion (every joint below {min_rom_deg:g} deg): "
            + ", ".join(f"{names[j]} {np.degrees(rom[j]):.1f} deg" for j in range(len(rom))) + hint)
    sigma, lag1 = marker_noise(gather_limb_markers(markers, idx), fit.rotation, fit.translation, fit.valid)
    white = bool(np.isfinite(lag1) and lag1 < _WHITE_LAG1)
    jpts, auto = _joint_points(definition), {}
    if white:
        base, ref, c0, fit = _mean_shape_base(base, idx, markers, fit, w0)
        jpts, auto = _auto_joint_points(definition, jpts, cluster_rotation_sd(ref, w0, sigma),
                                        np.radians(degenerate_rotation_deg))
    else:
        # Skin moving over bone (slow, correlated): the residuals are no noise model, so neither
        # degeneracy nor standard errors from them decide; the residual bound does, as it always did.
        max_residual_mm = _RESIDUAL_MM if max_residual_mm is None else max_residual_mm
        if lost_note and ((idx >= 0).sum(1) + (jpts >= 0).sum(1) < MIN_MARKERS).any():
            raise CalibrationError(lost_note[0] + " (a limb left with two markers needs its joint as a fit point: "
                                   "its residuals are skin motion, so no centre can be found from its markers)")
    picker = _CentrePicker(centre_order, cands, low, None if max_residual_mm is None else max_residual_mm / 1000.0,
                           max_uncertainty_mm / 1000.0 if white else np.inf)
    fit, quality, offsets, joint_base, axes = _centres(definition, markers, idx, ref, w0, fit, jpts, c0, rom, low,
                                                       picker, cands, huber_k, irls_iterations, source, auto,
                                                       sigma if np.isfinite(sigma) else 0.0, white, (base, b0))
    warns, static_only = _notes(definition, markers, parts, n_static, quality, cands, source,
                                min_rom_deg, max_uncertainty_mm if white else None)
    model = _actor_model(definition, idx, base, fit, c0, offsets, joint_base, axes, quality, markers, rate_hz,
                         jpts, static_only)
    model.marker_noise, model.max_uncertainty = sigma, max_uncertainty_mm / 1000.0 if white else float("nan")
    model.bone_length = _bone_lengths(model, markers)
    model.warnings = tuple(warns := lost_note + warns)
    for msg in warns:
        warnings.warn(msg, CalibrationWarning, stacklevel=2)
    return model


def _drop_lost_markers(definition: Any, idx: np.ndarray, markers: np.ndarray,
                       source: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Markers never seen in the whole capture (lost for the trial) taken out of the limbs' fit
    sets: (limb index [L,K] compacted, the markers with those columns set to 0 for the base-pose
    search, the warning naming them). A limb left with fewer than three is fitted through its
    joints, as a degenerate cluster is."""
    lost = ~np.isfinite(markers).all(-1).any(0)
    used = np.isin(np.arange(markers.shape[1]), idx[idx >= 0])
    if not (lost & used).any():
        return idx, markers, []
    rows = [[int(m) for m in r if m >= 0 and not lost[m]] for r in idx]
    out = np.full_like(idx, -1)
    for l, r in enumerate(rows):
        out[l, : len(r)] = r
    labels = definition.marker_labels
    names = ", ".join(labels[m] for m in np.flatnonzero(lost & used))
    few = [definition.limb_names[l] for l, r in enumerate(rows) if len(r) < MIN_MARKERS]
    note = (f"{source}: markers never seen in the capture, left out: {names}"
            + (f"; {', '.join(few)} fitted through {'its' if len(few) == 1 else 'their'} joints" if few else ""))
    return out, np.where(lost[None, :, None], 0.0, markers), [note]


def _mean_shape_base(base: np.ndarray, idx: np.ndarray, markers: np.ndarray, fit: Any, w0: np.ndarray):
    """The base pose with each cluster's mean shape over the gym (every frame's markers carried
    back by its rigid fit and averaged) in place of the one base frame's noisy markers, and the
    fits redone against it: a noisy base frame tilts each cluster's frame by a different small
    rotation (0.5-1 deg at 1 mm noise), which the hinge rules and the centres' average between
    two limbs would turn into millimetres. Returns (base [M,3], ref [L,K,3], c0 [L,3], fit)."""
    cur = gather_limb_markers(markers, idx)
    y = np.einsum("tlji,tlkj->tlki", np.where(fit.valid[..., None, None], fit.rotation, 0.0),
                  cur - np.where(fit.valid[..., None], fit.translation, 0.0)[:, :, None, :])
    ok = np.isfinite(y).all(-1) & fit.valid[..., None]
    cnt = ok.sum(0)
    mean = np.where(ok[..., None], y, 0.0).sum(0) / np.maximum(cnt, 1)[..., None]     # [L,K,3]
    new = base.copy()
    done = np.zeros(len(base), dtype=bool)
    for l, k in zip(*np.nonzero((idx >= 0) & (cnt >= 3))):
        if not done[idx[l, k]]:
            new[idx[l, k]], done[idx[l, k]] = mean[l, k], True
    ref = gather_limb_markers(new, idx)
    return new, ref, np.nanmean(ref, axis=1), fit_rigid(ref, cur, w0)


def _auto_joint_points(definition: Any, jpts: np.ndarray, rot_sd: np.ndarray,
                       max_rot: float) -> tuple[np.ndarray, dict[int, str]]:
    """The layout's joint points plus, for each limb whose cluster cannot fix its orientation
    (rotation sd rot_sd [L] rad above max_rot) and has none, its joints to limbs that can.
    Returns (int64[L,P], joint -> why, for the report)."""
    jl = np.asarray(definition.joint_limbs)
    hinge = np.asarray(definition.joint_hinge, dtype=bool)
    rows = [list(r[r >= 0]) for r in jpts]
    declared = np.array([bool(r) for r in rows])
    weak = (rot_sd > max_rot) & ~declared
    why: dict[int, str] = {}
    frame = declared.copy()   # limbs fitted through points (they cannot be another's frame)
    used = np.zeros(len(rows), dtype=bool)   # limbs serving as some points limb's frame
    for l in sorted(np.flatnonzero(weak), key=lambda v: -rot_sd[v]):   # the worst first
        if used[l]:
            continue
        for j in np.flatnonzero((jl == l).any(1)):
            m = int(jl[j, 0] if jl[j, 1] == l else jl[j, 1])
            # (a hinge's markers move on circles: a sphere fit cannot place it along its axis)
            if m < 0 or frame[m] or rot_sd[m] >= rot_sd[l] or hinge[j]:
                continue
            frame[l], used[m] = True, True
            rows[l].append(int(j))
            why[int(j)] = (f"{definition.limb_names[l]} cluster cannot fix its orientation (rotation sd "
                           f"{np.degrees(min(rot_sd[l], np.pi)):.0f} deg): its markers as points in "
                           f"{definition.limb_names[m]}'s frame")
    out = np.full((len(rows), max([len(r) for r in rows] + [0])), -1, dtype=np.int64)
    for l, r in enumerate(rows):
        out[l, : len(r)] = r
    return out, why


def _centres(definition, markers, idx, ref, w0, fit, jpts, c0, rom, low, picker, cands, huber_k,
             irls_iterations, source, auto, sigma, white, base_at=None):
    """Every joint's centre, its method, standard error and reliability: the functional fits
    (points limbs first), then the picker's choice per joint and the hinges placed on their axes.
    Returns (fit, JointQuality, offsets [J,2,3], joint_base [J,3], axes [J,3])."""
    jl = np.asarray(definition.joint_limbs)
    la, lb = jl[:, 0], jl[:, 1]
    J = len(jl)
    hinge = np.asarray(definition.joint_hinge, dtype=bool)
    point_centre: dict[int, tuple] = {}
    own: dict[tuple[int, int], np.ndarray] = {}
    if (jpts >= 0).any():
        fit, point_centre, own = _fit_point_limbs(definition, markers, idx, ref, w0, fit, jpts, c0, source, low,
                                             picker.pick, picker.chosen, sigma,
                                             cluster_rotation_cov(ref, w0, sigma) if white else None, base_at)
    rot_cov = cluster_rotation_cov(ref, w0, sigma) if white else None
    if rot_cov is not None:
        rot_cov[(jpts >= 0).any(1)] = 0.0  # limbs fitted through joint points: not their own clusters' noise
    offsets, axes, methods, inlier, resid, n_frames, cov, axis_se, limb_axes = _joint_offsets(
        fit, c0, la, lb, hinge, low, tuple(definition.joint_names), huber_k, irls_iterations, source, rot_cov)
    for j, (centre, rms_j, cov_j) in point_centre.items():
        offsets[j, 0], offsets[j, 1] = centre - c0[la[j]], centre - c0[lb[j]]
        methods[j] = "prior" if low[j] else "sphere"
        resid[j], cov[j] = rms_j, cov_j
    joint_base = 0.5 * ((c0[la] + offsets[:, 0]) + (c0[lb] + offsets[:, 1]))
    for (l, j), point in own.items():
        # The points limb's own view of its joint (see _own_point); the base pose keeps the joint
        # where the limb that found it holds it (the rules placing its neighbours read it there).
        offsets[j, int(lb[j] == l)] = point - c0[l]
    functional_hinge = picker.settle(joint_base, offsets, methods, resid, point_centre, hinge, c0, la, lb, fit, cov)
    before = joint_base.copy()
    _place_hinge_centres(definition, joint_base, offsets, axes, functional_hinge, methods, cands, fit, picker.chosen,
                         c0 if white else None, limb_axes)
    picked = picker.picked
    reliable = np.array([picked[j][2] for j in range(J)], dtype=bool)
    inputs = [dict(picked[j][3]) for j in range(J)]
    for j, why in auto.items():
        inputs[j]["points"] = why
    final_cov = np.array([picker.cov.get(j, cov[j]) for j in range(J)])
    # A hinge's axis: its error over the frames (bootstrap) and each cluster's one-frame base-pose
    # tilt. A centre slid along the axis by the placement rules moves across the true axis by the
    # slide times that tilt. (Not covered: where along the axis a rule through the parent joint or
    # the neighbours' plane puts it; on random arms 0.7-2.6 mm mean at 0.5-1 mm noise, see
    # benchmarks/accuracy.py.)
    t_base = np.trace(cluster_rotation_cov(ref, w0, sigma), axis1=1, axis2=2)
    for j in np.flatnonzero(hinge & np.isfinite(axis_se) & np.isfinite(axes).all(1)):
        n = axes[j] / np.linalg.norm(axes[j])
        axis_se[j] = np.sqrt(axis_se[j] ** 2 + (t_base[la[j]] + t_base[lb[j]]) / 6.0)
        slide = float((joint_base[j] - before[j]) @ n)
        final_cov[j] = final_cov[j] + 0.5 * (slide * axis_se[j]) ** 2 * (np.eye(3) - np.outer(n, n))
        reliable[j] &= bool(standard_error(final_cov[j]) <= picker.max_se)
    for j in np.flatnonzero(hinge & np.array([m.endswith("+midplane") for m in methods])):
        # Nothing measured the centre's place along the axis: the markers' mid-plane is a guess
        # as uncertain as the two clusters are wide along it.
        n = axes[j] / np.linalg.norm(axes[j])
        pts = ref[[la[j], lb[j]]].reshape(-1, 3)
        spread = np.nanstd(pts[np.isfinite(pts).all(1)] @ n)
        final_cov[j] = final_cov[j] + spread * spread * np.outer(n, n)
        if not np.isfinite(spread) or spread > picker.max_se:
            reliable[j] = False
    axis_se = np.where(hinge & np.array([m.startswith("hinge") for m in methods]), axis_se, np.nan)
    axes[~hinge] = np.nan  # the axis sign is arbitrary; only the line matters to the solver
    quality = JointQuality(residual_rms=resid, range_of_motion=rom, n_frames=n_frames.astype(np.int64),
                           outlier_fraction=1.0 - inlier.sum(0) / np.maximum(n_frames, 1), reliable=reliable,
                           method=tuple(methods), inputs=tuple(inputs), centre_se=standard_error(final_cov),
                           centre_cov=final_cov, axis_se=axis_se,
                           from_points=np.array([j in point_centre for j in range(J)]))
    return fit, quality, offsets, joint_base, axes


def _actor_model(definition: Any, idx: np.ndarray, base: np.ndarray, fit: Any, c0: np.ndarray,
                 offsets: np.ndarray, joint_base: np.ndarray, axes: np.ndarray, quality: JointQuality,
                 markers: np.ndarray, rate_hz: float | None, jpts: np.ndarray,
                 static_only: tuple[str, ...]) -> ActorModel:
    """The ActorModel of a calibration's results (bone lengths still NaN: they need the model)."""
    limb_rms = np.nanmedian(np.where(fit.valid, fit.rms, np.nan), axis=0) if fit.valid.any(0).all() \
        else np.array([np.nanmedian(fit.rms[fit.valid[:, l], l]) if fit.valid[:, l].any() else np.nan
                       for l in range(len(definition.limb_names))])
    return ActorModel(
        layout=str(definition.name),
        marker_labels=tuple(definition.marker_labels),
        limb_names=tuple(definition.limb_names),
        limb_parent=np.asarray(definition.limb_parent, dtype=np.int64),
        limb_markers=idx.astype(np.int64),
        joint_names=tuple(definition.joint_names),
        joint_limbs=np.asarray(definition.joint_limbs).astype(np.int64),
        joint_parent=np.asarray(definition.joint_parent, dtype=np.int64),
        joint_hinge=np.asarray(definition.joint_hinge, dtype=bool),
        base_markers=base.copy(),
        limb_centroid=c0,
        offsets=offsets,
        joint_base=joint_base,
        bone_length=np.full(len(joint_base), np.nan),
        hinge_axis=axes,
        limb_rms=limb_rms,
        quality=quality,
        n_gym_frames=int(markers.shape[0]),
        rate_hz=rate_hz,
        limb_joint_points=jpts,
        static_only_markers=static_only,
    )


def _base_frame(markers: np.ndarray, labels: tuple[str, ...], base_frame: int | None, rate_hz: float | None,
                max_base_search_s: float | None, source: str) -> int:
    """The base pose frame: the given one (every marker seen, else CalibrationError) or the one found."""
    if base_frame is None:
        max_frames = int(round(max_base_search_s * rate_hz)) if (rate_hz and max_base_search_s) else None
        return find_base_pose(markers, labels, max_frames, source)
    if not np.isfinite(markers[base_frame]).all():
        missing = [labels[m] for m in np.flatnonzero(~np.isfinite(markers[base_frame]).all(-1))]
        raise CalibrationError(f"{source}: base frame {base_frame} lacks markers {', '.join(missing)}")
    return base_frame


class _CentrePicker:
    """Per joint, the first method of ``centre_order`` that gives it a centre (else the prior).

    picked: joint -> (method, residual m, reliable, inputs) of the centres taken; chosen: joint ->
    the centre settled so far (a regression of a child may read its parent's); cov: joint -> the
    taken centre's covariance (m^2). A functional centre is taken when its joint moved at least
    the minimum range and its standard error is at most ``max_se`` (m; and its residual at most
    ``max_res`` when that is given)."""

    def __init__(self, centre_order: Sequence[str], cands: CentreCandidates, low: np.ndarray,
                 max_res: float | None, max_se: float = np.inf) -> None:
        self.centre_order, self.cands, self.low, self.max_res = centre_order, cands, low, max_res
        self.max_se = max_se
        self.chosen: dict[int, np.ndarray] = {}
        self.picked: dict[int, tuple[str, float, bool, dict]] = {}
        self.cov: dict[int, np.ndarray] = {}

    def trusted(self, j: int, c: Candidate) -> bool:
        """Whether a functional centre is determined well enough to be taken as reliable."""
        se = float(standard_error(c.cov))
        return (not self.low[j] and np.isfinite(se) and se <= self.max_se
                and (self.max_res is None or c.spread <= self.max_res))

    def pick(self, j: int, functional: Candidate | None, cur_fit: Any) -> Candidate:
        """The first method of centre_order that gives joint j a centre; else the prior."""
        for m in self.centre_order:
            if m == "functional" and functional is not None and self.trusted(j, functional):
                self.picked[j] = (functional.method, functional.spread, True, functional.inputs)
                self.cov[j] = functional.cov
                return functional
            got = (self.cands.anatomical(j, cur_fit) if m == "anatomical"
                   else self.cands.regression(j, cur_fit, self.chosen) if m == "regression" else None)
            if got is not None:
                self.picked[j] = (got.method, got.spread, True, got.inputs)
                self.cov[j] = got.cov
                return got
        fallback = functional if functional is not None else None
        return fallback  # type: ignore[return-value]

    def settle(self, joint_base: np.ndarray, offsets: np.ndarray, methods: list[str], resid: np.ndarray,
               point_centre: dict, hinge: np.ndarray, c0: np.ndarray, la: np.ndarray, lb: np.ndarray,
               fit: Any, cov: np.ndarray) -> np.ndarray:
        """One method per joint, in tree order (a knee chord needs its hip's chosen centre): the
        centres, offsets, methods and residuals updated in place; returns the joints that keep a
        functional hinge."""
        picked, chosen = self.picked, self.chosen
        functional_hinge = np.zeros(len(joint_base), dtype=bool)
        for j in range(len(joint_base)):
            if j in point_centre:
                if j not in picked:
                    picked[j] = (methods[j], resid[j], False, {})
                methods[j], resid[j] = picked[j][0], picked[j][1]
                chosen[j] = joint_base[j].copy()
                continue
            func = None if methods[j] == "prior" else Candidate(joint_base[j].copy(), float(resid[j]), methods[j],
                                                                {"functional": "SARA" if hinge[j] else "SCoRE"}, cov[j])
            got = self.pick(j, func, fit)
            if j not in picked:
                picked[j] = (methods[j], resid[j], False, {})
            elif got is not func:
                offsets[j, 0], offsets[j, 1] = got.point - c0[la[j]], got.point - c0[lb[j]]
                joint_base[j] = got.point
            else:
                functional_hinge[j] = bool(hinge[j])
            methods[j], resid[j] = picked[j][0], picked[j][1]
            chosen[j] = joint_base[j].copy()
        return functional_hinge


def _joint_offsets(fit: Any, c0: np.ndarray, la: np.ndarray, lb: np.ndarray, hinge: np.ndarray, low: np.ndarray,
                   names: tuple[str, ...], huber_k: float, irls_iterations: int, source: str,
                   rot_cov: np.ndarray | None = None) -> tuple:
    """Functional joint offsets from both limbs' centroids (SCoRE; SARA's axis for hinges), by
    Huber-weighted IRLS over the gym frames. Marker noise turns each limb's fitted rotation by a
    small random amount (covariance S = rot_cov [L,3,3]), so a noisy rotation is on average
    ``R (I - (tr S - S) / 2)``: shorter, which pulls least squares towards small offsets (errors
    in variables, ~0.5 mm at 1 mm noise); the normal equations are corrected for it.
    Returns (offsets [J,2,3] m, axes [J,3], methods, inlier [T,J],
    residual rms [J] m, frames with both limbs tracked [J], centre covariance [J,3,3] m^2 (a hinge's:
    across its axis), hinge axis standard error [J] rad, the axis as each limb holds it [J,2,3])."""
    J = len(la)
    rot = fit.rotation                                        # [T,L,3,3]
    cen = (rot @ c0[:, :, None])[..., 0] + fit.translation    # base centroid carried along

    valid = fit.valid[:, la] & fit.valid[:, lb]               # [T,J]
    n_frames = valid.sum(0)
    starved = [f"{names[j]} ({n_frames[j]} frames)" for j in np.flatnonzero(n_frames < 3)]
    if starved:
        raise CalibrationError(
            f"{source}: joints whose two limbs are never tracked together: {', '.join(starved)}")
    a_mat = np.concatenate([rot[:, la], -rot[:, lb]], axis=-1)  # [T,J,3,6]
    a_mat = np.where(valid[..., None, None], a_mat, 0.0)
    # Offsets are solved relative to the midpoint of the two centroids so that the prior
    # (joint near the midpoint) is x = 0 in the weak directions: o_a = x_a + (mid - c0_a).
    mid = 0.5 * (c0[la] + c0[lb])
    shift = np.concatenate([mid - c0[la], mid - c0[lb]], axis=-1)  # [J,6]
    bvec = cen[:, lb] - cen[:, la] - (a_mat @ shift[None, :, :, None])[..., 0]
    bvec = np.where(valid[..., None], bvec, 0.0)

    w = valid.astype(float)
    x = np.zeros((J, 6))
    axes = np.full((J, 3), np.nan)
    methods = [""] * J
    # E[R_noisy] = R M with M = I - (tr S - S) / 2: the normal equations use R M^-1 (their
    # R_a^T R_b blocks M_a^-1 R_a^T R_b M_b^-1; R^T R = I stays exact).
    a_fit, dfix = a_mat, np.zeros((J, 6, 6))
    if rot_cov is not None:
        m_inv = np.linalg.inv(np.eye(3) - 0.5 * (np.trace(rot_cov, axis1=1, axis2=2)[:, None, None] * np.eye(3)
                                                 - rot_cov))                                   # [L,3,3]
        a_fit = np.concatenate([a_mat[..., :3] @ m_inv[la], a_mat[..., 3:] @ m_inv[lb]], axis=-1)
        dfix[:, :3, :3], dfix[:, 3:, 3:] = m_inv[la] @ m_inv[la] - np.eye(3), m_inv[lb] @ m_inv[lb] - np.eye(3)
    b0 = bvec + (a_mat @ shift[None, :, :, None])[..., 0]
    for _ in range(max(1, irls_iterations)):
        nmat = np.einsum("tjki,tj,tjkl->jil", a_fit, w, a_fit) - w.sum(0)[:, None, None] * dfix
        g = np.einsum("tjki,tj,tjk->ji", a_fit, w, np.where(valid[..., None], b0, 0.0)) - (nmat @ shift[:, :, None])[..., 0]
        x_new = np.empty_like(x)
        for j in range(J):
            x_new[j], ax, methods[j] = _solve_offsets(nmat[j], g[j], bool(hinge[j]), bool(low[j]))
            if ax is not None:
                axes[j] = ax
        err = np.linalg.norm((a_mat @ x_new[None, :, :, None])[..., 0] - bvec, axis=-1)  # [T,J]
        med = np.array([np.median(err[valid[:, j], j]) for j in range(J)])
        c = np.maximum(huber_k * 1.4826 * med, 1e-4)
        w_new = np.where(valid, np.minimum(1.0, c / np.maximum(err, 1e-300)), 0.0)
        converged = np.abs(x_new - x).max() < 1e-9
        x, w = x_new, w_new
        if converged:
            break
    offsets = (x + shift).reshape(J, 2, 3)
    r_vec = (a_mat @ x[None, :, :, None])[..., 0] - bvec
    cov = score_covariance(a_mat, w, np.where(valid[..., None], r_vec, 0.0), hinge)
    rng = np.random.default_rng(0)  # a fixed bootstrap: one capture always gives one model
    axis_se = np.array([hinge_axis_se(a_mat[:, j], w[:, j], rng) if hinge[j] else np.nan for j in range(J)])
    inlier = valid & (err <= c)
    resid = np.array([np.sqrt(np.mean(err[inlier[:, j], j] ** 2)) if inlier[:, j].any() else np.nan
                      for j in range(J)])
    # The axis as each limb holds it (SARA's two halves): their base frames differ by a little noise.
    limb_axes = np.full((J, 2, 3), np.nan)
    for j in np.flatnonzero(hinge & np.isfinite(axes).all(1)):
        u = np.linalg.eigh(nmat[j])[1][:, 0].reshape(2, 3)
        u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
        limb_axes[j] = u * np.sign(u @ axes[j])[:, None]
    return offsets, axes, methods, inlier, resid, n_frames, cov, axis_se, limb_axes


def _notes(definition: Any, markers: np.ndarray, parts: Sequence[tuple[str, int]] | None, n_static: int,
           quality: JointQuality, cands: CentreCandidates, source: str, min_rom_deg: float,
           max_uncertainty_mm: float | None) -> tuple[list[str], tuple[str, ...]]:
    """The calibration's warnings (joints with no reliable centre, with their range and standard
    error; the candidates' notes; clusters that changed between parts) and the markers only the
    static trial needs."""
    names, labels = tuple(definition.joint_names), tuple(definition.marker_labels)
    warns: list[str] = []
    rom, se = quality.range_of_motion, quality.centre_se
    weak = np.flatnonzero(~quality.reliable)
    if weak.size:
        warns.append(
            f"{source}: no reliable centre (range of motion < {min_rom_deg:g} deg or "
            + (f"standard error > {max_uncertainty_mm:g} mm" if max_uncertainty_mm is not None else "residual too large")
            + ", and no landmarks or regression): centre from the "
            "prior or an untrusted fit: "
            + ", ".join(f"{names[j]} {np.degrees(rom[j]):.1f} deg, "
                        + (f"+-{1000 * se[j]:.1f} mm" if np.isfinite(se[j]) else "error unknown") for j in weak))
    warns.extend(f"{source}: {n}" for n in cands.notes if names[0] is not None)
    static_only: tuple[str, ...] = ()
    if parts and len(parts) > 1:
        # Only the layout's landmarks may be static-only: any other marker stays required later.
        lmk = np.zeros(len(labels), dtype=bool)
        lmk[[k for pair in (getattr(definition, "joint_landmarks", ()) or ()) for k in pair]] = True
        later = np.isfinite(markers[n_static:]).all(-1).any(0)
        static_only = tuple(labels[m] for m in np.flatnonzero(
            lmk & ~later & np.isfinite(markers[:n_static]).all(-1).any(0)))
        warns.extend(cluster_changes(definition, markers, parts))
    return warns, static_only

def _place_hinge_centres(definition: Any, joint_base: np.ndarray, offsets: np.ndarray,
                         axes: np.ndarray, hinge: np.ndarray, methods: list[str],
                         cands: CentreCandidates | None = None, fit: Any = None,
                         chosen: dict[int, np.ndarray] | None = None, c0: np.ndarray | None = None,
                         limb_axes: np.ndarray | None = None) -> None:
    """Fix each functional hinge centre's place along its axis (in place).

    Motion about one axis leaves the centre's position along it unobservable. In order: the
    point of the axis nearest the landmark midpoint (epicondyles), else nearest the regression
    centre (PiG knee width), else where the axis meets the line from the parent joint to the
    child joint (an anatomical hinge's axis is normal to the plane of its neighbours: shoulder,
    elbow, wrist), else the axis point nearest the parent joint (the segment's long axis is
    perpendicular to its flexion axis), else the mid-plane of the two limbs' markers.
    With ``c0`` (and ``fit``) the two rules are taken in the world, frame by frame (each joint as
    its own limb sees it, about the axis as that limb holds it, ``limb_axes`` [J,2,3]) and the
    median slide applied to each limb along its own axis: each limb's base frame is tilted by its
    own noise, so base-pose points from different limbs do not quite agree (mm over a bone).
    """
    jl = np.asarray(definition.joint_limbs)
    parent = np.asarray(definition.joint_parent)
    rule = _WorldRule(jl, offsets, fit, c0, limb_axes) if c0 is not None and fit is not None else None

    def slide(j: int, s: float) -> None:
        own = limb_axes[j] if rule is not None and limb_axes is not None and np.isfinite(limb_axes[j]).all() \
            else np.stack([axes[j], axes[j]])
        joint_base[j] += s * axes[j]
        offsets[j] += s * own

    for j in np.flatnonzero(hinge):
        n = axes[j]
        if cands is not None and np.isfinite(n).all():
            got = cands.anatomical(j, fit) or cands.regression(j, fit, chosen or {})
            if got is not None:
                s = float((got.point - joint_base[j]) @ n)
                joint_base[j] += s * n
                offsets[j] += s * n
                methods[j] += "+" + ("landmarks" if got.method == "landmarks" else "regression")
                continue
        kids = [k for k in np.flatnonzero(jl[:, 0] == jl[j, 1]) if not hinge[k]]
        p = parent[j]
        n = axes[j]
        if p < 0 or not kids or not np.isfinite(n).all():
            continue
        got = rule.plane(j, p, kids[0], n) if rule is not None else None
        if got is None:
            a, b = joint_base[p], joint_base[kids[0]]
            got = _plane_slide((b - a)[None], (joint_base[j] - a)[None], n[None])
        if got is None:
            continue
        slide(j, got)
        methods[j] = "hinge+plane"
    for j in np.flatnonzero(hinge):
        p = parent[j]
        n = axes[j]
        if methods[j] in ("hinge", "hinge+prior") and p >= 0 and np.isfinite(n).all():
            # The segment's long axis (parent joint to this centre) is perpendicular to its
            # flexion axis: the centre is the axis point nearest the parent joint.
            got = rule.perpendicular(j, p, n) if rule is not None else None
            s, dist = got if got is not None else (float((joint_base[p] - joint_base[j]) @ n),
                                                   float(np.linalg.norm(joint_base[p] - joint_base[j])))
            # Only a small correction: a poorly found axis would otherwise slide the centre far
            # along it (the joint is at most a few centimetres wide).
            if abs(s) < min(np.cos(np.radians(75.0)) * dist, _MAX_AXIAL_SHIFT):
                slide(j, s)
                methods[j] = "hinge+perpendicular"
        if methods[j] in ("hinge", "hinge+prior"):
            methods[j] += "+midplane"


def _plane_slide(d: np.ndarray, w: np.ndarray, n: np.ndarray) -> float | None:
    """Median slide along the axes n [F,3] that puts the points w [F,3] (relative to the line's
    start) on the lines d [F,3]; None when the line runs within 30 deg of the axis."""
    dn, dd = (d * n).sum(-1), (d * d).sum(-1)
    den = dd - dn * dn  # |d|^2 sin^2(angle between line and axis)
    ok = (dd > 0) & (den >= 0.25 * dd)
    if not ok.any() or ok.mean() < 0.5:
        return None
    s = (dn * (w * d).sum(-1) - dd * (w * n).sum(-1))[ok] / den[ok]
    return float(np.median(s))


class _WorldRule:
    """The hinge placement rules frame by frame in the world: each joint where its own limb puts it."""

    def __init__(self, jl: np.ndarray, offsets: np.ndarray, fit: Any, c0: np.ndarray,
                 limb_axes: np.ndarray | None = None, n_frames: int = 240) -> None:
        self.jl, self.offsets, self.fit, self.c0, self.n = jl, offsets, fit, c0, n_frames
        self.limb_axes = limb_axes

    def _axis(self, j: int, n: np.ndarray) -> np.ndarray:
        """The axis as joint j's proximal limb holds it (else n)."""
        la = None if self.limb_axes is None else self.limb_axes[j, 0]
        return la if la is not None and np.isfinite(la).all() else n

    def _frames(self, limbs) -> np.ndarray:
        ok = np.flatnonzero(self.fit.valid[:, list(limbs)].all(1))
        return ok[np.linspace(0, ok.size - 1, min(self.n, ok.size)).astype(int)] if ok.size else ok

    def _seen(self, j: int, limb: int, frames: np.ndarray) -> np.ndarray | None:
        k = np.flatnonzero(self.jl[j] == limb)
        if not k.size:
            return None
        pt = self.c0[limb] + self.offsets[j, k[0]]
        return (self.fit.rotation[frames, limb] @ pt) + self.fit.translation[frames, limb]

    def plane(self, j: int, p: int, kid: int, n: np.ndarray) -> float | None:
        a, b = (int(v) for v in self.jl[j])
        frames = self._frames((a, b))
        pa, kb, ja = self._seen(p, a, frames), self._seen(kid, b, frames), self._seen(j, a, frames)
        if frames.size < 10 or pa is None or kb is None:
            return None
        return _plane_slide(kb - pa, ja - pa, self.fit.rotation[frames, a] @ self._axis(j, n))

    def perpendicular(self, j: int, p: int, n: np.ndarray) -> tuple[float, float] | None:
        a = int(self.jl[j, 0])
        frames = self._frames((a,))
        pa, ja = self._seen(p, a, frames), self._seen(j, a, frames)
        if frames.size < 10 or pa is None:
            return None
        d = pa - ja
        na = self.fit.rotation[frames, a] @ self._axis(j, n)
        return float(np.median((d * na).sum(-1))), float(np.median(np.linalg.norm(d, axis=-1)))


def _joint_points(definition: Any) -> np.ndarray:
    """int64[L,P] joints usable as extra fit points per limb (-1 padding)."""
    rows = tuple(getattr(definition, "limb_joint_points", ()) or ())
    L = len(definition.limb_names)
    rows = rows + ((),) * (L - len(rows))
    out = np.full((L, max([len(r) for r in rows] + [0])), -1, dtype=np.int64)
    for l, r in enumerate(rows):
        out[l, : len(r)] = r
    return out


def _sphere_centre(y: np.ndarray, prior: np.ndarray, noise: np.ndarray | None = None) -> tuple[np.ndarray, float, np.ndarray]:
    """Centre (m) of the spheres that markers y [T,K,3] (NaN = unseen) move on, the RMS of the
    radius residual and the centre's covariance (m^2, from the fit's residuals). Directions the
    motion leaves undetermined stay at ``prior``. noise [T,K,3,3]: each point's noise covariance
    (m^2); noise in the points inflates ``g^T g`` by ``4 sum cov`` and ``g^T h`` by
    ``4 sum cov y`` (errors in variables), which are taken off."""
    yc = y - prior
    ok = np.isfinite(yc).all(-1)
    sq = (yc * yc).sum(-1)
    if noise is not None:  # E|y|^2 = |y0|^2 + tr cov, and cov varies with the point's lever arm
        sq = sq - np.trace(noise, axis1=-2, axis2=-1)
    # |y - c|^2 = r_k^2 is linear in c after removing each marker's mean.
    cnt = np.maximum(ok.sum(0), 1)
    ybar = np.where(ok[..., None], yc, 0.0).sum(0) / cnt[:, None]
    sbar = np.where(ok, sq, 0.0).sum(0) / cnt
    g = 2.0 * (yc - ybar)[ok]
    h = (sq - sbar)[ok]
    gg, gh = g.T @ g, g.T @ h
    if noise is not None:
        nz = noise[ok]
        gg = gg - 4.0 * nz.sum(0)
        gh = gh - 4.0 * np.einsum("nij,nj->i", nz, yc[ok])
    lam, vec = np.linalg.eigh(gg)
    keep = lam > _LOW_MOTION_TOL * max(lam[-1], 1e-300)
    vk = vec[:, keep]
    c = vk @ ((vk.T @ gh) / lam[keep])
    r = np.linalg.norm(yc - c, axis=-1)
    rbar = np.where(ok, r, 0.0).sum(0) / cnt
    res = (r - rbar)[ok]
    cov = sphere_covariance(g, h - g @ c, np.nonzero(ok)[0], _NULL_TOL)
    return c + prior, float(np.sqrt(np.mean(res * res))) if res.size else float("nan"), cov


def _fit_point_limbs(definition, markers, idx, ref, w0, fit, jpts, c0, source, low, pick=None, chosen=None,
                     sigma=0.0, rot_cov=None, base_at=None):
    """Joint centres used as fit points (sphere fit of the limb's markers in the other limb's
    frame; the midpoint prior for joints that hardly moved, ``low`` bool[J]), then the limbs'
    rigid fits redone with those centres as extra points."""
    jl = np.asarray(definition.joint_limbs)
    names = definition.joint_names
    pl = np.flatnonzero((jpts >= 0).any(1))
    centre: dict[int, tuple[np.ndarray, float]] = {}
    own: dict[tuple[int, int], np.ndarray] = {}
    for l in pl:
        for j in jpts[l][jpts[l] >= 0]:
            m = jl[j, 0] if jl[j, 1] == l else jl[j, 1]
            if m in pl:
                raise CalibrationError(
                    f"{source}: layout '{definition.name}': joint point {names[j]} joins two limbs "
                    f"that both need joint points ({definition.limb_names[l]}, {definition.limb_names[m]})")
            frames = np.flatnonzero(fit.valid[:, m])
            if frames.size < 10:
                raise CalibrationError(
                    f"{source}: limb {definition.limb_names[m]} is tracked in only {frames.size} frames; "
                    f"cannot locate joint {names[j]}")
            x = gather_limb_markers(markers[frames], idx[l])  # [F,K,3]
            rm = fit.rotation[frames, m]
            y = np.einsum("fji,fkj->fki", rm, x - fit.translation[frames, m][:, None, :])
            prior = 0.5 * (c0[l] + c0[m])
            noise = None
            if rot_cov is not None:
                # marker noise, the frame limb's centroid noise and its rotation noise times the lever
                d = np.cross(np.eye(3)[None, None], (y - c0[m])[:, :, None, :])          # [F,K,3,3] = [d]x
                km = max(int((idx[m] >= 0).sum()), 1)
                noise = sigma * sigma * (1.0 + 1.0 / km) * np.eye(3) + d @ rot_cov[m] @ np.swapaxes(d, -1, -2)
            sph = _sphere_centre(y, prior, noise)
            # A still joint's markers fit any sphere: the "centre" would be noise (its covariance says so).
            centre[int(j)] = (prior, float("nan"), sph[2]) if low[j] else sph
            if pick is not None:
                func = None if low[j] else Candidate(sph[0], sph[1], "sphere", {"functional": "sphere fit"}, sph[2])
                got = pick(int(j), func, fit)
                if got is not None:
                    centre[int(j)] = (got.point, got.spread, got.cov)
                chosen[int(j)] = centre[int(j)][0]
            if noise is not None and (idx[l] >= 0).sum() >= MIN_MARKERS:
                # (a cluster of two has no mean shape: its one base frame's distance is as wrong
                # as the joint's place, and the centre stays as the other limb holds it)
                own[(int(l), int(j))] = _own_point(ref[l], y, centre[int(j)][0], noise)
    vmask = jpts[pl] >= 0
    js = np.where(vmask, jpts[pl], 0)
    other = np.where(jl[js, 1] == pl[:, None], jl[js, 0], jl[js, 1])
    cref = np.zeros(js.shape + (3,))   # the centre where the other limb holds it ...
    mine = np.zeros(js.shape + (3,))   # ... and where this limb's own markers put it
    for (i, k), j in np.ndenumerate(js):
        if vmask[i, k]:
            cref[i, k] = centre[int(j)][0]
            mine[i, k] = own.get((int(pl[i]), int(j)), cref[i, k])
    cref = np.where(vmask[..., None], cref, np.nan)
    seen = np.einsum("tpkij,pkj->tpki", fit.rotation[:, other], cref) + fit.translation[:, other]
    cur2 = np.concatenate([gather_limb_markers(markers, idx[pl]), seen], axis=2)
    ref2 = np.concatenate([ref[pl], np.where(vmask[..., None], mine, np.nan)], axis=1)
    w2 = np.concatenate([w0[pl], vmask.astype(float)], axis=1)
    fit2 = fit_rigid(ref2, cur2, w2)
    moved = np.array([any((int(l), int(j)) in own for j in jpts[l][jpts[l] >= 0]) for l in pl], dtype=bool)
    if base_at is not None and moved.any():
        # The limb's own body (its markers and its own point) placed where the base frame's markers
        # and joint put it, as the other limbs' bodies are: the limbs' relative rotations (a hinge
        # axis in the base frame) then start from the base frame, not from a tilted body.
        base, b0 = base_at
        r0, t0 = fit2.rotation[b0], fit2.translation[b0]                           # [P,3,3], [P,3]
        ok = moved & fit2.valid[b0]
        placed = np.einsum("pij,pkj->pki", r0, ref2) + t0[:, None]
        ref2 = np.where(ok[:, None, None], placed, ref2)
        for i in np.flatnonzero(ok):
            l = int(pl[i])
            has = idx[l] >= 0
            ref[l, has] = ref2[i, : idx.shape[1]][has]
            base[idx[l][has]] = ref[l, has]
            c0[l] = r0[i] @ c0[l] + t0[i]
            for kk, j in enumerate(jpts[l]):
                if j >= 0 and (l, int(j)) in own:
                    own[(l, int(j))] = ref2[i, idx.shape[1] + kk]
        fit2 = fit_rigid(ref2, cur2, w2)
    merged = {k: getattr(fit, k).copy() for k in fit.__dataclass_fields__}
    for k in merged:
        if k != "n_visible":
            merged[k][:, pl] = getattr(fit2, k)
    return type(fit)(**merged), centre, own


def _own_point(ref: np.ndarray, y: np.ndarray, c: np.ndarray, noise: np.ndarray, iterations: int = 8) -> np.ndarray:
    """A joint centre in the base frame of the limb whose markers (ref [K,3], NaN padded) found it
    as points: the point at each marker's distance from the centre c over the gym (y [F,K,3] the
    markers in the other limb's frame, noise [F,K,3,3] their covariance: E|y - c|^2 = r^2 + tr).

    The two limbs' base frames are each placed by one noisy frame; c, carried over unchanged,
    would sit millimetres (the other limb's tilt times its lever arm) from where this limb's own
    markers put it, and a rigid fit of the limb through it would be a wrong body. Directions the
    distances leave open (a line-like cluster's spin) stay at c."""
    ok = np.isfinite(ref).all(-1)
    d2 = ((y - c) ** 2).sum(-1) - np.trace(noise, axis1=-2, axis2=-1)          # [F,K]
    fin = np.isfinite(d2)
    r = np.sqrt(np.maximum(np.where(fin, d2, 0.0).sum(0) / np.maximum(fin.sum(0), 1), 0.0))
    ok &= fin.any(0)
    p, r = ref[ok], r[ok]
    w = np.asarray(c, dtype=float).copy()
    mu = 1e-3   # a weak pull to c: only the directions the distances leave open follow it
    for _ in range(iterations):
        v = w - p
        n = np.maximum(np.linalg.norm(v, axis=-1), 1e-9)
        jac = np.vstack([v / n[:, None], np.sqrt(mu) * np.eye(3)])
        res = np.concatenate([n - r, np.sqrt(mu) * (w - c)])
        w = w - np.linalg.lstsq(jac, res, rcond=None)[0]
    return w


def _bone_lengths(model: ActorModel, markers: np.ndarray) -> np.ndarray:
    """Median distance from each joint to its parent joint over the gym frames (Kiip 3.3.3)."""
    from mocapgraph.kinematics.solving.solver import FrameSolver  # solver imports model only; no cycle at load

    res = FrameSolver(model, max_gap_s=0.0, enforce_lengths=False).solve_geometry(markers)
    parent = model.joint_parent
    out = np.full(len(parent), np.nan)
    for j, p in enumerate(parent):
        if p < 0:
            continue
        both = (res.joint_quality[:, j] == 2) & (res.joint_quality[:, p] == 2)
        if both.sum() >= 3:
            out[j] = float(np.median(np.linalg.norm(res.joints[both, j] - res.joints[both, p], axis=-1)))
        else:
            out[j] = float(np.linalg.norm(model.joint_base[j] - model.joint_base[p]))
    return out
