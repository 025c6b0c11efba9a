"""Frame solver: joint positions from labelled markers and a calibrated ActorModel (Kiip 3.4).

Per frame: each limb's rotation from its visible markers (weighted Kabsch against the base
pose), each joint from every attached limb that is visible (``R @ base_point + t``), an
inverse-variance weighted average, then bone lengths enforced outward from the root. A joint is
GOOD only when every attached limb is seen and its calibration is reliable; else ESTIMATED. One code
path for one frame or many: :meth:`FrameSolver.solve` batches the geometry over frames and runs
the (optional) temporal stage frame by frame exactly as :meth:`FrameSolver.step` does live.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.kinematics.solving.filters import GapFiller, make_filter
from mocapgraph.kinematics.model import Quality, ActorModel
from mocapgraph.kinematics.solving.global_fit import GlobalFit, GlobalFitOptions
from mocapgraph.kinematics.solving.global_track import MAX_KERNEL_MARKERS, GlobalTracker
from mocapgraph.kinematics.solving.global_track_numpy import NumpyGlobalTracker
from mocapgraph.kinematics.solving.joint_kernels import joint_model, joints_all_seen
from mocapgraph.kinematics.solving.joint_uncertainty import JointUncertainty
from mocapgraph.kinematics.solving.regression import RegressionStage
from mocapgraph.kinematics.solving.rigid import MIN_MARKERS, fit_rigid, gather_limb_markers
from mocapgraph.kinematics.solving.rigid_kernels import fit_frame, limbs_of, scratch

FITS = ("segment", "global")
_GOOD, _EST, _MISS = np.int8(Quality.GOOD), np.int8(Quality.ESTIMATED), np.int8(Quality.MISSING)


@dataclass
class SolverResult:
    """Solved frames; leading dims ``B`` are ``[T]`` from solve() and ``[]`` from step().

    joints: float[B,J,3] m world (NaN where MISSING); joint_quality: int8[B,J] (Quality codes).
    limb_matrix: float[B,L,3,3] limb rotation relative to the base pose (NaN if MISSING).
    limb_quality: int8[B,L]; limb_visible: int64[B,L] markers used; limb_rms: float[B,L] m.
    joint_uncertainty: float[B,J] m, RMS 3-D uncertainty of each joint (the calibrated centre's
    standard error with this frame's marker noise through its limbs' fits; NaN where missing or
    the model has no standard errors); before any temporal filter or gap prediction.
    """

    joints: np.ndarray
    joint_quality: np.ndarray
    limb_matrix: np.ndarray
    limb_quality: np.ndarray
    limb_visible: np.ndarray
    limb_rms: np.ndarray
    joint_uncertainty: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.joint_uncertainty is None:
            self.joint_uncertainty = np.full(self.joint_quality.shape, np.nan)

    @property
    def limb_rotation(self) -> np.ndarray:
        """float[B,L,4] quaternions (w, x, y, z) relative to the base pose, NaN where missing."""
        m = self.limb_matrix
        flat = m.reshape(-1, 3, 3)
        ok = np.isfinite(flat).all((1, 2))
        q = np.full((flat.shape[0], 4), np.nan)
        if ok.any():
            q[ok] = Rotation.from_matrix(flat[ok]).as_quat(scalar_first=True)
        return q.reshape(m.shape[:-2] + (4,))

    def __getitem__(self, i: int | slice) -> "SolverResult":
        return SolverResult(self.joints[i], self.joint_quality[i], self.limb_matrix[i],
                            self.limb_quality[i], self.limb_visible[i], self.limb_rms[i], self.joint_uncertainty[i])


def length_levels(model: ActorModel, free: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Bone-length correction order: (children, parents, lengths m) per depth from the root, so each
    level is one vector operation; joints in ``free`` (and bones without a length) are left out."""
    parent = np.asarray(model.joint_parent)
    J = parent.size
    depth = np.zeros(J, dtype=int)
    for j in range(J):
        d, p = 0, parent[j]
        while p >= 0 and d <= J:
            d, p = d + 1, parent[p]
        depth[j] = d
    blen = np.asarray(model.bone_length, dtype=float).copy()
    blen[free] = np.nan
    return [(c, parent[c], blen[c]) for lvl in range(1, depth.max(initial=0) + 1)
            if (c := np.flatnonzero((depth == lvl) & np.isfinite(blen))).size]


class FrameSolver:
    """Solve frames of markers (in ``model.marker_labels`` order, metres, NaN = unseen).

    rate_hz: capture rate used for time stamps when none are given (defaults to the model's).
    max_gap_s: longest gap a joint is predicted over (constant velocity); 0 disables.
    enforce_lengths: apply Kiip's bone-length correction outward from the root.
    filter: None, "one_euro" or "constant_velocity"; filter_params go to its constructor.
    limb_rms_tol: a limb fit worse than this (m) is ESTIMATED and its joint estimates weigh less;
    None -> max(4 x calibrated fit RMS, 5 mm).
    fit: "segment" (each limb by itself, Kiip) or "global" (all limbs of a frame together under
    the joint constraints, :mod:`mocapgraph.kinematics.solving.global_fit`; warm-started from the
    previous frame, so it also carries state between calls).
    compiled: a live frame's limb fits (:mod:`rigid_kernels`; global: :mod:`global_fit_kernels`)
    and joint centres (:mod:`joint_kernels`) run as compiled kernels; False keeps the numpy
    reference (the same results to rounding; batches always use numpy).
    noise_scale: the markers' noise as a fraction of the calibration's (a low-pass filter's
    ``LowpassReport.noise_gain``), so the per-frame uncertainty stays honest on filtered markers.
    """

    def __init__(
        self,
        model: ActorModel,
        rate_hz: float | None = None,
        max_gap_s: float = 0.1,
        enforce_lengths: bool = True,
        filter: str | None = None,
        filter_params: dict[str, float] | None = None,
        limb_rms_tol: float | None = None,
        fit: str = "segment",
        global_options: GlobalFitOptions | None = None,
        compiled: bool = True,
        noise_scale: float = 1.0,
    ) -> None:
        if fit not in FITS:
            raise ValueError(f"unknown fit {fit!r} (expected one of {', '.join(FITS)})")
        self.model = model
        self.fit = fit
        self._global = GlobalFit(model, global_options) if fit == "global" else None
        self.rate_hz = rate_hz if rate_hz is not None else model.rate_hz
        self.max_gap_s = float(max_gap_s)
        self.enforce_lengths = enforce_lengths
        idx = np.asarray(model.limb_markers)
        self._idx = idx
        self._ref = gather_limb_markers(model.base_markers, idx)           # [L,K,3]
        self._w0 = (idx >= 0).astype(float)                                # [L,K]
        jl = np.asarray(model.joint_limbs)
        self._lab = np.concatenate([jl[:, 0], jl[:, 1]])                   # [2J]
        has = self._lab >= 0
        self._has = has
        lab = np.where(has, self._lab, 0)
        self._labs = lab
        off = np.concatenate([model.offsets[:, 0], model.offsets[:, 1]])   # [2J,3]
        self._pt = np.where(has[:, None], model.limb_centroid[lab] + off, 0.0)[:, :, None]
        # Static part of each estimate's variance: lever arm of the offset relative to the
        # cluster size (rotation error is amplified by |offset| / radius).
        radius2 = np.nanmean(((self._ref - model.limb_centroid[:, None]) ** 2).sum(-1), axis=1)
        lever = (off ** 2).sum(-1) / np.maximum(radius2[lab], 1e-8)
        self._var_static = 1.0 + lever                                      # [2J]
        sig = np.where(np.isfinite(model.limb_rms), model.limb_rms, 0.0)
        self._sig2 = np.maximum(sig, 2e-4) ** 2                           # [L]
        tol = np.maximum(4.0 * sig, 0.005) if limb_rms_tol is None else np.full_like(sig, limb_rms_tol)
        self._rms_tol = tol
        self._sig2_lab, self._tol_lab = self._sig2[lab], tol[lab]
        self._J = len(model.joint_names)
        # A joint whose calibrated centre is unreliable (from the prior, too little motion) is at
        # best ESTIMATED, however well its limbs are seen: quality flags tell the truth.
        rel = np.asarray(model.quality.reliable, dtype=bool).reshape(-1)
        self._unreliable = ~rel if rel.shape == (self._J,) else np.zeros(self._J, dtype=bool)
        self._may_be_good = ~self._unreliable
        self._n_need = has.reshape(2, self._J).sum(0)
        # Qualities when every limb is seen and fits well (None: some joint has no limb at all).
        self._jq_all_seen = (np.where(self._may_be_good, _GOOD, _EST).astype(np.int8)
                             if (self._n_need > 0).all() else None)
        # Regression joints are recomputed from the markers each frame (as Plug-in Gait does):
        # their distances to the parent follow the markers, not a calibrated length.
        self._regression = RegressionStage(model)
        self._levels = length_levels(model, self._regression.joints)
        self._setup_joint_points(model)
        self._uncertainty = JointUncertainty(model, self._ref, self._w0, self._labs, self._pt[..., 0], self._has,
                                             noise_scale)
        # The compiled live limb fit (one frame's Kabsch fits) and its scratch.
        self._kernel_fit = compiled
        if compiled:
            self._rk = limbs_of(self._ref, np.where(idx >= 0, idx, 0), self._w0, MIN_MARKERS)
            self._rk_scratch = scratch()
            self._rk_max = int(idx.max(initial=0))
        # The compiled live joint stage: every limb seen and fit well, no regression joints.
        self._kernel_joints = compiled and not self._regression and self._jq_all_seen is not None
        if self._kernel_joints:
            lv = (self._levels if enforce_lengths else []) + [(np.zeros(0, int), np.zeros(0, int), np.zeros(0))]
            self._lq_good = np.full((1, len(model.limb_names)), _GOOD)
            self._k_model = joint_model(self._labs, self._pt[..., 0], self._has, self._var_static, self._sig2_lab,
                                        self._rms_tol, np.concatenate([c for c, _, _ in lv]),
                                        np.concatenate([p for _, p, _ in lv]), np.concatenate([b for _, _, b in lv]))
        # Live global frames track the last frame's optimum; limbs fitted through joint points
        # need the segment-wise fit's second pass, so those layouts always start from it.
        # (compiled: the kernel's tracker where it takes the layout, up to 8 markers a limb)
        if self._global is not None and not self._pl.size:
            kind = GlobalTracker if compiled and self._global._idx.shape[1] <= MAX_KERNEL_MARKERS else NumpyGlobalTracker
            self._tracker = kind(self._global, tol, tolerance=self._global.options.tolerance)
        else:
            self._tracker = None
        self._gap = GapFiller(self._J, self.max_gap_s) if self.max_gap_s > 0 else None
        self._filter_spec = (filter, dict(filter_params or {}))
        self._filter = make_filter(filter, self._J, **self._filter_spec[1])
        self._frame = 0

    def _setup_joint_points(self, model: ActorModel) -> None:
        jp = np.asarray(model.limb_joint_points)
        self._pl = np.flatnonzero((jp >= 0).any(1)) if jp.size else np.zeros(0, dtype=np.int64)
        if not self._pl.size:
            return
        jp = jp[self._pl]
        jl = np.asarray(model.joint_limbs)
        J = self._J
        self._vmask = jp >= 0
        js = np.where(self._vmask, jp, 0)
        # The point's position comes from the joint's *other* limb: column j holds the estimate
        # from the proximal limb, column J + j the one from the distal limb.
        mine_is_distal = jl[js, 1] == self._pl[:, None]
        self._vcol = np.where(mine_is_distal, js, J + js)
        # ... and sits where the limb itself holds the joint (its centroid plus its own offset).
        mine = model.limb_centroid[self._pl][:, None] + np.asarray(model.offsets)[js, mine_is_distal.astype(int)]
        vref = np.where(self._vmask[..., None], mine, np.nan)
        self._ref2 = np.concatenate([self._ref[self._pl], vref], axis=1)
        self._w2 = np.concatenate([self._w0[self._pl], self._vmask.astype(float)], axis=1)

    # ---- geometry (batched over frames) ---------------------------------------------------
    def _limb_estimates(self, rot, trans, valid):
        """Each joint as seen from each attached limb: float[T,2J,3] and ok bool[T,2J]."""
        lab = self._labs
        est = (rot[:, lab] @ self._pt)[..., 0] + trans[:, lab]
        return est, valid[:, lab] & self._has

    def solve_geometry(self, markers: np.ndarray) -> SolverResult:
        """float[T,M,3] -> SolverResult over [T]; no temporal state is touched (but the global fit
        keeps the last poses as its warm start)."""
        markers = np.asarray(markers, dtype=float)
        J = self._J
        tracked = self._tracker.track(markers[0]) if self._tracker is not None and len(markers) == 1 else None
        if tracked is not None:
            rot, trans, valid = tracked.rot[None], tracked.trans[None], tracked.valid[None]
            rms_l, nfit = tracked.rms[None], tracked.n_visible[None]
            self._global.remember(tracked.rot, tracked.centroid)
            return self._joints_from_limbs(markers, rot, trans, valid, rms_l, nfit, nfit)
        rot, trans, valid, rms_l, nfit, n_seen = self._fit_limbs(markers)
        return self._joints_from_limbs(markers, rot, trans, valid, rms_l, nfit, n_seen)

    def _fit_limbs(self, markers: np.ndarray):
        """Limb poses of [T] frames by the segment-wise fit, then (global) the full global fit."""
        # A frame with too few markers for the layout takes the numpy path (its IndexError), never
        # an unchecked read in the kernel.
        if self._kernel_fit and markers.shape[0] == 1 and markers.shape[1] > self._rk_max:
            L = self._idx.shape[0]
            rot, trans, rms_l = np.empty((1, L, 3, 3)), np.empty((1, L, 3)), np.empty((1, L))
            nfit, ok = np.empty((1, L), dtype=np.int64), np.empty((1, L), dtype=np.int64)
            fit_frame(np.ascontiguousarray(markers[0], dtype=float), self._rk,
                      (rot[0], trans[0], rms_l[0], nfit[0], ok[0]), self._rk_scratch)
            valid = ok > 0
        else:
            fit = fit_rigid(self._ref, gather_limb_markers(markers, self._idx), self._w0)
            rot, trans, valid, rms_l, nfit = fit.rotation, fit.translation, fit.valid, fit.rms, fit.n_visible
        n_seen = nfit
        if self._pl.size:
            # Limbs with joint points: refit with the joint centres seen from the other limbs.
            est, ok = self._limb_estimates(rot, trans, valid)
            virt = np.where((ok[:, self._vcol] & self._vmask)[..., None], est[:, self._vcol], np.nan)
            cur2 = np.concatenate([gather_limb_markers(markers, self._idx[self._pl]), virt], axis=2)
            fit2 = fit_rigid(self._ref2, cur2, self._w2)
            rot, trans, valid = rot.copy(), trans.copy(), valid.copy()
            rms_l, nfit = rms_l.copy(), nfit.copy()
            pl = self._pl
            rot[:, pl], trans[:, pl], valid[:, pl] = fit2.rotation, fit2.translation, fit2.valid
            rms_l[:, pl], nfit[:, pl] = fit2.rms, fit2.n_visible
        if self._global is not None:
            rot, trans = self._global.refine(markers, rot, trans, valid)
            if self._tracker is not None:
                self._tracker.seed(rot[-1], trans[-1], bool(valid[-1].all() and (rms_l[-1] <= self._rms_tol).all()))
            nan = ~valid
            rot = np.where(nan[..., None, None], np.nan, rot)
            trans = np.where(nan[..., None], np.nan, trans)
        return rot, trans, valid, rms_l, nfit, n_seen

    def _joints_from_limbs(self, markers, rot, trans, valid, rms_l, nfit, n_seen) -> SolverResult:
        """Joints, qualities and the length correction from limb poses of [T] frames."""
        J, T = self._J, valid.shape[0]
        if self._kernel_joints and T == 1 and valid.all():
            # The common live frame (every limb seen and fit well) as one compiled call
            # (joint_kernels; the code below is its reference).
            joints = np.empty((1, J, 3))
            if joints_all_seen(np.ascontiguousarray(rot[0]), np.ascontiguousarray(trans[0]),
                               np.ascontiguousarray(nfit[0], dtype=np.int64), np.ascontiguousarray(rms_l[0], dtype=float),
                               self._k_model, joints[0]):
                return SolverResult(joints, self._jq_all_seen[None].copy(), rot, self._lq_good.copy(), n_seen, rms_l,
                                    self._uncertainty(valid, rms_l, nfit))
        all_seen = self._jq_all_seen is not None and bool(valid.all()) and bool((rms_l <= self._rms_tol).all())
        lab = self._labs
        rms = rms_l[:, lab]
        # Inverse-variance weights of the two estimates; a poor limb fit weighs 1000x less.
        var = (self._sig2_lab + rms * rms) * (self._var_static / np.maximum(nfit[:, lab], 1))
        est = (rot[:, lab] @ self._pt)[..., 0] + trans[:, lab]                  # [T,2J,3]
        if all_seen:
            # Every limb seen and fit well (the common live frame): no masking, known qualities.
            w2 = (self._has / var).reshape(T, 2, J)
            joints = (w2[..., None] * est.reshape(T, 2, J, 3)).sum(1) / w2.sum(1)[..., None]
            jq = np.repeat(self._jq_all_seen[None], T, axis=0)
        else:
            ok = valid[:, lab] & self._has                                      # [T,2J]
            w = np.where(ok, 1.0 / np.where(ok, var, 1.0), 0.0) * np.where(rms > self._tol_lab, 1e-3, 1.0)
            est = np.where(ok[..., None], est, 0.0)
            w2 = w.reshape(T, 2, J)
            wsum = w2.sum(1)[..., None]
            joints = np.divide((w2[..., None] * est.reshape(T, 2, J, 3)).sum(1), wsum,
                               out=np.full((T, J, 3), np.nan), where=wsum > 0)
            n_ok = ok.reshape(T, 2, J).sum(1)
            jq = np.where(n_ok == 0, _MISS, np.where((n_ok >= self._n_need) & self._may_be_good, _GOOD, _EST))
        if self._regression:
            self._regression.apply(markers, joints, jq, _GOOD)
        if self.enforce_lengths:
            complete = bool(np.isfinite(joints).all())
            for c, p, length in self._levels:
                pj = joints[:, p]
                v = joints[:, c] - pj
                d = np.sqrt((v * v).sum(-1))
                if complete:
                    # Coincident joints (d = 0) stay put, as below.
                    joints[:, c] = pj + v * (length / np.maximum(d, 1e-9))[..., None]
                    continue
                good = d > 1e-9
                scale = np.where(good, length / np.where(good, d, 1.0), 1.0)
                # NaN parents leave the child as measured.
                moved = pj + v * scale[..., None]
                joints[:, c] = np.where(np.isfinite(moved), moved, joints[:, c])
        lq = np.where(valid, np.where(rms_l > self._rms_tol, _EST, _GOOD), _MISS)
        unc = np.where(jq == _MISS, np.nan, self._uncertainty(valid, rms_l, nfit))
        return SolverResult(joints, jq, rot, lq, n_seen, rms_l, unc)

    # ---- temporal stage (frame by frame, shared by live and batch) -------------------------
    def _temporal(self, joints: np.ndarray, jq: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        if self._gap is not None:
            joints, jq = self._gap.step(joints, jq, t)
        if self._filter is not None:
            joints = self._filter.step(joints, t)
        return joints, jq

    def _time(self, t_s: float | None) -> float:
        if t_s is not None:
            return float(t_s)
        if not self.rate_hz:
            # Untimed and no rate: time counts frames, so a gap of one frame already exceeds
            # any sub-second max_gap_s and nothing is predicted.
            return float(self._frame)
        return self._frame / self.rate_hz

    def step(self, markers: np.ndarray, t_s: float | None = None) -> SolverResult:
        """Solve one live frame float[M,3] (t_s: capture time in s) -> SolverResult with no T dim."""
        res = self.solve_geometry(np.asarray(markers, dtype=float)[None])[0]
        if self._gap is not None or self._filter is not None:
            res.joints, res.joint_quality = self._temporal(res.joints, res.joint_quality, self._time(t_s))
        self._frame += 1
        return res

    def solve(self, markers: np.ndarray, times_s: np.ndarray | None = None) -> SolverResult:
        """Solve float[T,M,3] (continuing any live state) -> SolverResult over [T]."""
        res = self.solve_geometry(markers)
        if self._gap is not None or self._filter is not None:
            T = res.joints.shape[0]
            for i in range(T):
                t = float(times_s[i]) if times_s is not None else self._time(None)
                res.joints[i], res.joint_quality[i] = self._temporal(res.joints[i], res.joint_quality[i], t)
                self._frame += 1
        else:
            self._frame += res.joints.shape[0]
        return res

    def reset(self) -> None:
        """Forget temporal state (prediction, filter) and the frame counter."""
        self._gap = GapFiller(self._J, self.max_gap_s) if self.max_gap_s > 0 else None
        self._filter = make_filter(self._filter_spec[0], self._J, **self._filter_spec[1])
        self._frame = 0
        if self._global is not None:
            self._global.reset()
        if self._tracker is not None:
            self._tracker.reset()
