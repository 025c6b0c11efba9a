"""The compiled one-frame rigid fit against the numpy Kabsch reference (rigid.fit_rigid):
rotations, translations, RMS, visibility counts and validity, with occlusions, three-marker
(planar) clusters, collinear and too-few markers."""
from __future__ import annotations

import numpy as np

from mocapgraph.kinematics.solving.rigid import MIN_MARKERS, fit_rigid, gather_limb_markers
from mocapgraph.kinematics.solving.rigid_kernels import fit_frame, limbs_of, scratch


def test_compiled_frame_fit_is_the_numpy_kabsch_fit():
    rng = np.random.default_rng(11)
    L, K = 40, 5
    ref = rng.normal(scale=0.05, size=(L, K, 3)) + rng.normal(scale=0.5, size=(L, 1, 3))
    ref[:10, 3:] = np.nan                                   # three-marker limbs (padding)
    ref[10, :, 1:] = 0.0                                    # collinear: invalid
    q = rng.normal(size=(L, 4))
    from scipy.spatial.transform import Rotation
    rot = Rotation.from_quat(q / np.linalg.norm(q, axis=1, keepdims=True)).as_matrix()
    cur = ref @ np.swapaxes(rot, -1, -2) + rng.normal(scale=1.5, size=(L, 1, 3))
    cur += rng.normal(scale=0.001, size=cur.shape)
    idx = np.arange(L * K).reshape(L, K)
    idx[:10, 3:] = -1
    markers = cur.reshape(-1, 3).copy()
    markers[idx[20, :3]] = np.nan                           # two left: invalid
    markers[idx[21, 0]] = np.nan                            # four left: valid
    weights = (idx >= 0).astype(float)
    ref_fit = fit_rigid(ref, gather_limb_markers(markers, idx), weights)
    out = (np.empty((L, 3, 3)), np.empty((L, 3)), np.empty(L), np.empty(L, dtype=np.int64), np.empty(L, dtype=np.int64))
    fit_frame(markers, limbs_of(ref, np.where(idx >= 0, idx, 0), weights, MIN_MARKERS), out, scratch())
    r, t, rms, nvis, valid = out
    assert (valid.astype(bool) == ref_fit.valid).all() and not valid[[10, 20]].any() and valid[21]
    assert (nvis == ref_fit.n_visible).all()
    ok = ref_fit.valid
    assert np.isnan(r[~ok]).all() and np.isnan(t[~ok]).all() and np.isnan(rms[~ok]).all()
    assert np.abs(r[ok] - ref_fit.rotation[ok]).max() < 1e-12
    assert np.abs(t[ok] - ref_fit.translation[ok]).max() < 1e-12
    assert np.abs(rms[ok] - ref_fit.rms[ok]).max() < 1e-12
    assert np.allclose(np.linalg.det(r[ok]), 1.0, atol=1e-14)
