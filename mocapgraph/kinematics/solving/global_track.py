"""Live global fit: one frame at a time, Gauss-Newton from the previous frame's optimum, compiled.

The same weighted least-squares problem as :mod:`mocapgraph.kinematics.solving.global_fit` (markers,
joints, hinges; its weights), solved for a live frame starting from the last frame's optimum
instead of a fresh segment-wise (Kabsch) guess, so a frame needs no SVD:

- poses step in the limb's own frame (``R <- R cay(w)``, ``c <- c + R v``): the normal matrix's
  diagonal blocks are then constant for a set of seen markers and only the joints' coupling
  blocks depend on the poses (through the relative rotations); it is factored by 6x6 blocks along
  the limb tree, and the factor made after a frame's first step also serves the next frame's
  first step (a few milliseconds of motion older).

Steps stop when the estimated distance to the optimum (from the observed linear convergence
rate) or the last step is within ``tolerance`` (m of point motion). The tracker declines a frame
(returns None; the caller solves it from the segment-wise fit and reseeds it) when it has no good
last frame, a limb cannot be fixed by its own markers, a limb's fit is poor, or the steps do not
converge.

:class:`GlobalTracker` runs each frame as one call of :func:`global_fit_kernels.track_frame`; it
takes layouts of up to 8 markers a limb (it tables every subset of a limb's markers).
:class:`.global_track_numpy.NumpyGlobalTracker` is the same tracker in numpy: its reference in the
tests, and the tracker of wider layouts.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapgraph.kinematics.solving.global_fit import GlobalFit
from mocapgraph.kinematics.solving.global_fit_kernels import TrackBuffers
from mocapgraph.kinematics.solving.rigid import fit_rigid

MAX_KERNEL_MARKERS = 8   # a limb's markers the compiled tracker's visibility table covers


@dataclass
class Tracked:
    """One tracked frame: rot [L,3,3], trans [L,3] (``x = R x_ref + t``), centroid [L,3] (m,
    where each limb's base-pose marker centroid is), valid bool[L],
    rms float[L] m (fit RMS of the limb's seen markers), n_visible int[L], iterations used."""

    rot: np.ndarray
    trans: np.ndarray
    centroid: np.ndarray
    valid: np.ndarray
    rms: np.ndarray
    n_visible: np.ndarray
    iterations: int


def lever_radius(fit: GlobalFit) -> np.ndarray:
    """[L] m: each limb's lever arm (its farthest marker or joint from the base centroid, at least
    5 cm), what turns a rotation step into point motion."""
    pad = fit._idx >= 0
    radius = np.sqrt(np.where(pad, (fit._a ** 2).sum(-1), 0.0).max(1))
    jr = np.sqrt((np.concatenate([fit._p_a, fit._p_b]) ** 2).sum(-1))
    np.maximum.at(radius, np.concatenate([fit._ja, fit._jb]), jr)
    return np.maximum(radius, 0.05)


def visibility_table(fit: GlobalFit) -> np.ndarray:
    """bool[L, 2^K]: can the limb be fixed by this subset of its markers alone (>= 3, not
    collinear)? The same test as the segment-wise fit, on the calibrated marker geometry."""
    pad = fit._idx >= 0
    K = pad.shape[1]
    bits = 1 << np.arange(K)
    codes = np.arange(1 << K)
    mask = (codes[:, None] & bits[None]) > 0                                  # [C,K]
    a = np.where(pad[:, None, :, None], fit._a[:, None], np.nan)              # [L,1,K,3]
    w = (mask[None] & pad[:, None]).astype(float)                             # [L,C,K]
    return fit_rigid(np.broadcast_to(a, w.shape + (3,)), np.broadcast_to(a, w.shape + (3,)), w).valid


class GlobalTracker:
    """Warm-started live global fit over one frame at a time (see the module docstring).

    rms_tol: float[L] m, a limb fit worse than this makes the tracker decline the frame;
    tolerance: m of point motion; max_iterations per frame. ValueError for a layout of more than
    8 markers a limb (:class:`.global_track_numpy.NumpyGlobalTracker` takes those).
    """

    def __init__(self, fit: GlobalFit, rms_tol: np.ndarray, tolerance: float = 1e-5,
                 max_iterations: int = 4) -> None:
        idx = fit._idx
        L, K = idx.shape
        if K > MAX_KERNEL_MARKERS:
            raise ValueError(f"the compiled global tracker takes at most {MAX_KERNEL_MARKERS} markers a limb, "
                             f"this layout has {K}")
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.L, self.K = L, K
        self._c0 = fit._c0
        self._all_valid = np.ones(L, dtype=bool)
        self._idx_max = int(idx.max(initial=0))   # the kernel indexes markers unchecked
        order = np.concatenate([lv[0] for lv in fit._levels] + [[fit._root]])
        self.buffers = TrackBuffers(idx, fit._a, fit._wm, fit._ja, fit._jb, fit._p_a, fit._p_b, fit._wj, fit._hj,
                                    fit._axis, fit._wh, order, lever_radius(fit), visibility_table(fit),
                                    np.asarray(rms_tol, dtype=float))
        self.reset()

    def reset(self) -> None:
        """Forget the last frames (the next frame is declined)."""
        self._R = self._c = None
        self.buffers.work.state[0] = 0

    def seed(self, rot: np.ndarray, trans: np.ndarray, good: bool) -> None:
        """The frame just solved by the full fit (rot [L,3,3], trans [L,3]); good: every limb was
        fixed by its markers and fit well. A bad frame leaves nothing to start from."""
        if not good:
            self.reset()
            return
        c = (rot @ self._c0[:, :, None])[..., 0] + trans
        self._R, self._c = np.ascontiguousarray(rot, dtype=np.float64).copy(), np.ascontiguousarray(c, dtype=np.float64)

    def track(self, markers: np.ndarray) -> Tracked | None:
        """markers float[M,3] (NaN = unseen) -> the frame's global optimum, or None (declined).
        Poses are stepped in place on the tracker's own copies; the result is fresh arrays.
        IndexError for a frame without the layout's markers."""
        if self._R is None:
            return None
        if markers.shape[0] <= self._idx_max:
            raise IndexError(f"a frame of {markers.shape[0]} markers: the layout uses marker {self._idx_max}")
        k = self.buffers
        it = k.track(np.ascontiguousarray(markers, dtype=np.float64), self._R, self._c,
                     self.tolerance, self.max_iterations)
        if it <= 0:
            self.reset()
            return None
        R, c = self._R.copy(), self._c.copy()
        trans = c - (R @ self._c0[..., None])[..., 0]
        return Tracked(R, trans, c, self._all_valid, k.work.rms.copy(), k.work.nvis.copy(), it)
