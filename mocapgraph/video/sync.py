"""Cameras' time offsets found from their detections: the shifts that make the triangulation agree (pure).

Videos started by hand, or cameras without a shared sync signal, see the same instant at
different frame numbers. :func:`estimate_offsets` finds each camera's offset (in frames of the
reference, the first camera; sub-frame by linear interpolation between frames) as the shift that
minimises the median reprojection error of the consensus triangulation over the body's joints:
a coarse search over whole frames camera by camera (the others held), then rounds of half-frame
steps around the offsets found, camera by camera, while the error falls.
:func:`shifted` resamples one camera's detections at the found offset.
"""
from __future__ import annotations

import numpy as np

from .multiview import Camera, triangulate_frames


def shifted(x: np.ndarray, s: float) -> np.ndarray:
    """x [T, ...] sampled at frame t + s (linear between frames; NaN outside the clip)."""
    x = np.asarray(x, dtype=np.float64)
    T = x.shape[0]
    tt = np.arange(T) + s
    i0 = np.floor(tt).astype(np.int64)
    f = (tt - i0).reshape(-1, *([1] * (x.ndim - 1)))
    inside = (i0 >= 0) & ((i0 + 1 < T) | ((i0 == T - 1) & (f.ravel() == 0)))
    a = np.clip(i0, 0, T - 1)
    b = np.clip(i0 + 1, 0, T - 1)
    y = x[a] * (1 - f) + x[b] * f
    y[~inside] = np.nan
    return y


def _median_error(cameras: list[Camera], uv: np.ndarray, conf: np.ndarray, offsets: np.ndarray,
                  frames: slice, joints: np.ndarray) -> float:
    u = np.stack([shifted(uv[k], s) for k, s in enumerate(offsets)])[:, frames][:, :, joints]
    c = np.nan_to_num(np.stack([shifted(conf[k], s) for k, s in enumerate(offsets)])[:, frames][:, :, joints])
    err = triangulate_frames(cameras, u, c).error_px
    return float(np.nanmedian(err)) if np.isfinite(err).any() else np.inf


def estimate_offsets(cameras: list[Camera], uv: np.ndarray, conf: np.ndarray, joints: np.ndarray, *,
                     max_shift: int = 6, stride: int = 2, rounds: int = 3) -> tuple[np.ndarray, float, float]:
    """Offsets [C] in frames (camera 0: 0; camera k's frame t + offset[k] shows the instant of the
    reference's frame t) from detections uv [C, T, N, 2], conf [C, T, N] over ``joints``, every
    ``stride``-th frame away from the clip's ends; and the median reprojection error before and
    after, px."""
    C, T = conf.shape[:2]
    frames = slice(max_shift + 1, T - max_shift - 1, stride)
    off = np.zeros(C)
    before = _median_error(cameras, uv, conf, off, frames, joints)
    for k in range(1, C):                               # whole frames, one camera at a time
        errs = [_median_error(cameras, uv, conf, np.r_[off[:k], s, off[k + 1:]], frames, joints)
                for s in range(-max_shift, max_shift + 1)]
        off[k] = -max_shift + int(np.argmin(errs))
    best = _median_error(cameras, uv, conf, off, frames, joints)
    for _ in range(rounds):                             # then half frames around them, camera by camera
        moved = False
        for k in range(1, C):
            for s in off[k] + np.array([-1.5, -1.0, -0.5, 0.5, 1.0, 1.5]):
                e = _median_error(cameras, uv, conf, np.r_[off[:k], s, off[k + 1:]], frames, joints)
                if e < best - 1e-9:
                    best, off[k], moved = e, s, True
        if not moved:
            break
    return off, before, best
