"""Rest offsets of a skeleton without a rest pose: one rule (observed_rest_offsets) for the live sources,
the bag converter and the retarget command, checked on the Kinect captures and small fixtures."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.bag.convert import file_to_bag
from mocapgraph.bag.reader import BagReader
from mocapgraph.bag.trial_frames import read_trial_frames as read_source
from mocapgraph.formats.kinect_csv import read_kinect_csv
from mocapgraph.formats.retarget_setup import source_from_skeleton_info
from mocapgraph.kinematics.rest_offsets import observed_rest_offsets
from mocapgraph.retarget.source import observed_bone_lengths

KINECT = ["Ges01_wavehand.csv", "Ges03_drawlines.csv", "Ges05_demopoint.csv"]


def _mean_directions(positions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """[J, 3] the normalised mean of each bone's unit vectors over the frames that see it (roots: 0)."""
    out = np.zeros((len(parents), 3))
    for j, p in enumerate(parents):
        if p < 0:
            continue
        v = positions[:, j] - positions[:, p]
        n = np.linalg.norm(v, axis=1)
        ok = np.isfinite(n) & (n > 1e-9)
        if ok.any():
            s = (v[ok] / n[ok, None]).sum(axis=0)
            out[j] = s / np.linalg.norm(s)
    return out


@pytest.mark.parametrize("name", KINECT)
def test_kinect_offsets_are_median_lengths_along_mean_directions(shared_data, name) -> None:
    tr = read_kinect_csv(shared_data / "kinect2" / name)
    offs = observed_rest_offsets(tr.positions, tr.parents)
    child = tr.parents >= 0
    np.testing.assert_allclose(np.linalg.norm(offs[child], axis=1),
                               observed_bone_lengths(tr.positions, tr.parents)[child], atol=1e-12)
    unit = offs[child] / np.linalg.norm(offs[child], axis=1, keepdims=True)
    np.testing.assert_allclose(unit, _mean_directions(tr.positions, tr.parents)[child], atol=1e-12)
    root = np.flatnonzero(~child)
    np.testing.assert_allclose(offs[root], np.nanmedian(tr.positions[:, root], axis=0))


def test_the_bag_converter_writes_the_offsets_the_live_source_publishes(shared_data, tmp_path) -> None:
    src = shared_data / "kinect2" / "Ges01_wavehand.csv"
    file_to_bag(src, tmp_path / "k.mcap")
    with BagReader(tmp_path / "k.mcap") as r:
        info = [m for _env, m in r.decoded("skeleton_info")][-1]
    tr = read_kinect_csv(src)
    np.testing.assert_allclose(info.rest_offsets, observed_rest_offsets(tr.positions, tr.parents))
    # the converter's former rule, the per-axis median of the offsets, is no bone's median length:
    child = tr.parents >= 0
    d = tr.positions[:, child] - tr.positions[:, tr.parents[child]]
    per_axis = np.linalg.norm(np.nanmedian(d, axis=0), axis=1)
    lengths = observed_bone_lengths(tr.positions, tr.parents)[child]
    np.testing.assert_allclose(np.linalg.norm(info.rest_offsets[child], axis=1), lengths, atol=1e-12)
    assert np.abs(per_axis - lengths).max() > 0.01


def test_the_retarget_command_keeps_its_tracked_only_bone_lengths(shared_data) -> None:
    path = shared_data / "kinect2" / "Ges02_balancinghands.csv"
    frames = read_source(str(path), None, None)
    tr = read_kinect_csv(path, ground="feet")
    tracked = np.where((tr.tracking_state == 2)[..., None], tr.positions, np.nan)
    old = np.zeros((tr.n_joints, 3))
    old[:, 2] = np.nan_to_num(observed_bone_lengths(tracked, tr.parents))   # the former lengths laid on z
    want = source_from_skeleton_info(tr.names, tr.parents, old, has_orientations=False)
    got = frames.source
    assert got.point_names == want.point_names and got.kinect_like == want.kinect_like == "kinect_v2"
    np.testing.assert_allclose(got.rest_points, want.rest_points, atol=1e-12)
    np.testing.assert_array_equal(got.point_parents, want.point_parents)


def test_small_chain_with_gaps_zero_lengths_and_a_bone_never_seen() -> None:
    parents = np.array([-1, 0, 1, 1, -1])
    T = 9
    P = np.full((T, 5, 3), np.nan)
    P[:, 0] = [[0.0, 0.0, 1.0 + 0.01 * t] for t in range(T)]             # root rising 1 cm a frame
    P[:, 1] = P[:, 0] + [0.0, 0.0, 0.3]                                     # 0.3 m straight up
    lengths2 = np.array([0.2, 0.2, 0.25, 0.2, 0.2, 0.0, 0.0, 0.2, 0.5])     # two zero-length frames
    P[:, 2] = P[:, 1] + lengths2[:, None] * [1.0, 0.0, 0.0]
    P[3:5, 2] = np.nan                                                       # joint 2 missing twice
    # joint 3 is never seen; root 4 neither
    offs = observed_rest_offsets(P, parents)
    np.testing.assert_allclose(offs[0], [0.0, 0.0, 1.04])
    np.testing.assert_allclose(offs[1], [0.0, 0.0, 0.3])
    # frames 0, 1, 2, 7, 8 count (missing and zero-length frames do not): median 0.2 along +x
    np.testing.assert_allclose(offs[2], [0.2, 0.0, 0.0])
    np.testing.assert_array_equal(offs[3], 0.0)
    np.testing.assert_array_equal(offs[4], 0.0)
    assert observed_rest_offsets(np.zeros((0, 5, 3)), parents).shape == (5, 3)
