"""Per-marker rigid-fit residuals of a capture against a calibrated model, every frame at once.

Each limb's base-pose markers are fitted (batched Kabsch, :func:`~.rigid.fit_rigid`) onto the
frame's markers; a marker's residual is the distance from where its limb's fit puts it to where
it was seen, m. Large values show a marker sliding on the skin or a swapped label.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..solving.rigid import fit_rigid, gather_limb_markers

if TYPE_CHECKING:  # for hints only: nothing of the model module is needed at run time
    from ..model import ActorModel


def marker_residuals(model: ActorModel, markers: np.ndarray) -> np.ndarray:
    """float[T,M] m for markers float[T,M,3] in the model's marker order; NaN where unseen or unfitted."""
    markers = np.asarray(markers, dtype=float)
    idx = np.asarray(model.limb_markers)
    has = idx >= 0
    ref = gather_limb_markers(model.base_markers, idx)                    # [L,K,3]
    cur = gather_limb_markers(markers, idx)                               # [T,L,K,3]
    fit = fit_rigid(ref, cur, has.astype(float))
    pred = np.einsum("tlij,lkj->tlki", fit.rotation, ref) + fit.translation[:, :, None, :]
    dist = np.linalg.norm(pred - cur, axis=-1)                            # [T,L,K]
    out = np.full(markers.shape[:2], np.nan)
    out[:, idx[has]] = dist[:, has]
    return out
