"""Per-frame joint uncertainty: the calibrated centre's standard error with this frame's marker noise.

Each joint is seen from its limbs (``R (c0 + o) + t``); marker noise sigma moves such an estimate
by a 3-D variance ``sigma^2 (3 / K + o^T (tr I^-1 - I^-1) o)`` (the centroid of K markers, and
the cluster's rotation noise ``sigma^2 I^-1`` from its inertia I times the lever o). The estimates
of a joint combine by inverse variance; the calibrated centre's variance (its standard error
squared) adds. sigma is the model's marker noise, or this frame's own fit residual when that is
worse (a marker sliding). Metres; NaN where the model has no standard errors.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # for hints only
    from ..model import ActorModel


class JointUncertainty:
    """Callable: (valid bool[T,L], rms float[T,L] m, fitted markers int[T,L]) -> float[T,J] m."""

    def __init__(self, model: ActorModel, ref: np.ndarray, w0: np.ndarray, labs: np.ndarray,
                 points: np.ndarray, has: np.ndarray, noise_scale: float = 1.0) -> None:
        """ref [L,K,3] base-pose markers, w0 [L,K] weights, labs [2J] limb of each estimate,
        points [2J,3] the estimates' base-pose points, has [2J] which estimates exist;
        noise_scale: this input's marker noise as a fraction of the model's (filtered markers)."""
        J = len(model.joint_names)
        d = np.where((w0 > 0)[..., None], ref - model.limb_centroid[:, None], 0.0)
        inertia = (d * d).sum((1, 2))[:, None, None] * np.eye(3) - np.einsum("lki,lkj->lij", d, d)
        ok = np.linalg.eigvalsh(inertia)[:, 0] > 1e-12
        inv = np.linalg.inv(np.where(ok[:, None, None], inertia, np.eye(3)))
        k = np.maximum(w0.sum(1), 1)
        o = points - model.limb_centroid[labs]
        rot = np.trace(inv, axis1=1, axis2=2)[labs] * (o * o).sum(-1) - np.einsum("ei,eij,ej->e", o, inv[labs], o)
        self._k_est = np.where(has & ok[labs], 3.0 / k[labs] + rot, np.inf)     # [2J]
        self._k = k[labs]
        self._labs, self._has, self._J = labs, has, J
        se = np.asarray(model.quality.centre_se, dtype=float).reshape(-1)
        self._centre_var = se * se if se.shape == (J,) else np.full(J, np.nan)
        noise = float(getattr(model, "marker_noise", np.nan)) * float(noise_scale)
        self._noise2 = noise * noise if np.isfinite(noise) else np.nan

    def __call__(self, valid: np.ndarray, rms: np.ndarray, nfit: np.ndarray) -> np.ndarray:
        lab, k = self._labs, self._k
        n = nfit[:, lab]
        # This frame's noise from its own fit (K markers leave 3K - 6 degrees of freedom).
        frame = np.where(n >= 3, np.nan_to_num(rms[:, lab]) ** 2 * n / np.maximum(3 * n - 6, 1), 0.0)
        # A fit clearly worse than the calibration's noise (a marker sliding) counts with its own.
        sig2 = np.where(np.isnan(self._noise2) | (frame > 4.0 * np.nan_to_num(self._noise2)), frame, self._noise2)
        var = sig2 * self._k_est * (k / np.maximum(n, 1))
        w = np.where(valid[:, lab] & self._has, 1.0 / var, 0.0).reshape(-1, 2, self._J).sum(1)
        with np.errstate(divide="ignore"):
            return np.sqrt(self._centre_var + 1.0 / w)
