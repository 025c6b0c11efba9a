"""Batched weighted Kabsch against known rotations."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.kinematics.solving.rigid import fit_rigid, gather_limb_markers


def _clusters(rng, t, l, k):
    ref = rng.normal(scale=0.05, size=(l, k, 3))
    rot = Rotation.random(t * l, random_state=rng).as_matrix().reshape(t, l, 3, 3)
    trans = rng.normal(size=(t, l, 3))
    cur = np.einsum("tlij,lkj->tlki", rot, ref) + trans[:, :, None, :]
    return ref, rot, trans, cur


def test_recovers_rotation_and_translation_batched():
    rng = np.random.default_rng(0)
    ref, rot, trans, cur = _clusters(rng, 50, 7, 4)
    fit = fit_rigid(ref, cur)
    assert fit.valid.all()
    np.testing.assert_allclose(fit.rotation, rot, atol=1e-10)
    np.testing.assert_allclose(fit.translation, trans, atol=1e-10)
    assert np.nanmax(fit.rms) < 1e-10
    np.testing.assert_allclose(np.linalg.det(fit.rotation), 1.0, atol=1e-12)


def test_occluded_markers_are_ignored_and_too_few_flagged():
    rng = np.random.default_rng(1)
    ref, rot, trans, cur = _clusters(rng, 10, 3, 4)
    cur = cur.copy()
    cur[:, 0, 1] = np.nan            # limb 0: 3 of 4 visible, still exact
    cur[:, 1, :2] = np.nan           # limb 1: 2 of 4 visible, must be flagged
    cur[5, 2, 0] = [1e3, 1e3, 1e3]   # garbage marker with zero weight must not matter
    w = np.ones((10, 3, 4))
    w[5, 2, 0] = 0.0
    fit = fit_rigid(ref, cur, w)
    np.testing.assert_allclose(fit.rotation[:, 0], rot[:, 0], atol=1e-10)
    assert (fit.n_visible[:, 0] == 3).all() and (fit.n_visible[:, 1] == 2).all()
    assert not fit.valid[:, 1].any() and np.isnan(fit.rotation[:, 1]).all()
    assert np.isnan(fit.rms[:, 1]).all()
    np.testing.assert_allclose(fit.rotation[5, 2], rot[5, 2], atol=1e-10)


def test_reflection_is_corrected_for_planar_clusters():
    # Three markers are always coplanar: a naive U V^T may give det -1 with noise.
    rng = np.random.default_rng(2)
    ref, rot, trans, cur = _clusters(rng, 200, 1, 3)
    cur = cur + rng.normal(scale=1e-3, size=cur.shape)
    fit = fit_rigid(ref, cur)
    np.testing.assert_allclose(np.linalg.det(fit.rotation), 1.0, atol=1e-9)
    ang = Rotation.from_matrix(fit.rotation[:, 0] @ np.swapaxes(rot[:, 0], -1, -2)).magnitude()
    assert np.median(ang) < np.radians(3)


def test_collinear_markers_are_invalid():
    ref = np.array([[[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0]]], float)
    fit = fit_rigid(ref, ref[None] + 1.0)
    assert not fit.valid.any()


def test_all_nan_frame_does_not_crash():
    ref = np.random.default_rng(3).normal(size=(2, 4, 3))
    fit = fit_rigid(ref, np.full((1, 2, 4, 3), np.nan))
    assert not fit.valid.any() and (fit.n_visible == 0).all()


def test_gather_pads_with_nan():
    markers = np.arange(15, dtype=float).reshape(5, 3)
    out = gather_limb_markers(markers, np.array([[0, 2, -1], [4, 3, 1]]))
    assert np.isnan(out[0, 2]).all()
    np.testing.assert_array_equal(out[1, 0], markers[4])
