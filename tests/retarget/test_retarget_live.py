"""The one-frame path (live), compiled (numba kernels) and in numpy, gives the batched path's
output on real clips and on the synthetic actor, frame by frame."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mocapgraph.formats.character_file import load_character
from mocapgraph.formats.kinect_csv import read_kinect_csv
from mocapgraph.formats.mapping_file import load_mapping
from mocapgraph.retarget.character import standard_20
from mocapgraph.retarget.live import CompiledFrame
from mocapgraph.retarget.live_numpy import NumpyFrame
from mocapgraph.retarget.retargeter import RetargetOptions, RetargetResult, Retargeter
from mocapgraph.retarget.mapping import derive_mapping
from mocapgraph.retarget.source import kinect_source, optical_points, optical_source

from retarget_support import bvh_source, solved_synthetic_actor

FIELDS = ("local_rotations", "root_positions", "joint_positions", "joint_quality", "contact")


def _compare(ch, mapping, src, opts, pts, pok, rot, t, rok=None):
    """(batched result, {path: {field: largest |one-frame - batched|}}) for the compiled and numpy paths."""
    batch = Retargeter(ch, mapping, src, opts, live=False).process(pts, pok, rot, rok, t)
    out = {}
    for compiled in (True, False):
        live = Retargeter(ch, mapping, src, opts, frame_path=CompiledFrame if compiled else NumpyFrame)
        assert isinstance(live.frame_path, CompiledFrame if compiled else NumpyFrame)
        frames = [live.process(pts[f:f + 1], None if pok is None else pok[f:f + 1],
                               None if rot is None else rot[f:f + 1], None if rok is None else rok[f:f + 1],
                               t[f:f + 1]) for f in range(len(pts))]
        worst = {}
        for k in FIELDS:
            got = np.concatenate([getattr(r, k) for r in frames]).astype(float)
            worst[k] = float(np.abs(got - getattr(batch, k).astype(float)).max())
        assert np.isfinite(np.concatenate([r.local_rotations for r in frames])).all()   # never NaN rotations
        out["compiled" if compiled else "numpy"] = worst
    return batch, out


def _check(what, worst):
    for path, w in worst.items():
        print(f"\n{what}, {path} one-frame path - batch max: " + ", ".join(f"{k} {v:.1e}" for k, v in w.items()))
        for k, v in w.items():
            assert v < 1e-12 if k not in ("joint_quality", "contact") else v == 0, (path, k, v)


@pytest.mark.parametrize("planting", [False, True])
def test_live_equals_batch_cmu_onto_mixamo_with_gaps(shared_data, planting):
    motion, trial, src = bvh_source(shared_data / "bvh/cmu/131_01.bvh")
    n = 400
    pts, rot = trial.positions[:n].copy(), trial.orientations[:n].copy()
    # gaps: a wrist point and a forearm rotation vanish for a while, a bad quaternion once
    pts[100:140, 20] = np.nan
    rot[150:170, 18] = np.nan
    rot[200, 5] *= 1.5
    mix = load_character("mixamo")
    opts = RetargetOptions(foot_planting=planting)
    batch, worst = _compare(mix, derive_mapping(mix, src), src, opts, pts, None, rot, np.arange(n) / motion.rate_hz)
    assert (batch.joint_quality < 2).any()          # the gaps did reach the comparison
    assert batch.contact.any() == planting          # and the plants, with planting on
    _check(f"CMU 131_01 onto Mixamo, planting {planting}", worst)


def test_live_equals_batch_kinect_positions_only_with_dependencies(shared_data):
    trial = read_kinect_csv(shared_data / "kinect2" / "Ges03_drawlines.csv", ground="feet")
    src = kinect_source(trial.names, trial.parents)
    n = 300
    pok = trial.tracking_state[:n] == 2
    ch = standard_20(1.75)
    mapping = load_mapping("kinect_v2_standard_20")
    # Claro's dependency form, source rotations multiplied after Q_k (two levels on one joint)
    deps = {"ShoulderCenter": ("SpineMid", "SpineBase"), "Head": ("SpineShoulder",)}
    mapping = replace(mapping, joints=tuple(replace(e, D=deps[e.joint]) if e.joint in deps else e
                                            for e in mapping.joints))
    batch, worst = _compare(ch, mapping, src, RetargetOptions(), trial.positions[:n], pok, None, np.arange(n) / 30.0)
    assert not pok.all()
    _check("Kinect v2 onto standard_20", worst)


@pytest.fixture(scope="module")
def solved_actor():
    """The synthetic actor (1 mm marker noise) calibrated and solved: source, points, limb rotations, times."""
    cap, model, res = solved_synthetic_actor()
    perf = cap.phase_slice("performance")
    src = optical_source(model.joint_names, model.joint_parent, model.joint_limbs, model.limb_names, model.joint_base)
    return src, optical_points(res.joints, model.joint_names), res.limb_rotation, res.limb_quality > 0, cap.times[perf]


@pytest.mark.parametrize("planting", [False, True])
def test_live_equals_batch_synthetic_actor_onto_standard_20(solved_actor, planting):
    """The node's case: solved limb rotations and joints onto standard_20 (spread spine, clavicles),
    with a limb lost for a while, a joint gone, a non-unit quaternion and the feet planted."""
    src, pts, rot, rok, t = solved_actor
    n = 500
    pts, rot, rok = pts[:n].copy(), rot[:n].copy(), rok[:n].copy()
    pts[60:90, 7] = np.nan
    rok[120:150, 3] = False
    rot[200, 2] *= 1.01
    ch = standard_20(1.75)
    # the optical root point is the mid-hip, standard_20's hips stand in front of HipCenter: the mid-hip rule is on
    assert Retargeter(ch, derive_mapping(ch, src), src, live=False).plan.root_s is not None
    batch, worst = _compare(ch, derive_mapping(ch, src), src, RetargetOptions(foot_planting=planting),
                            pts, None, rot, t[:n], rok)
    assert (batch.joint_quality < 2).any()
    assert batch.contact.any() == planting
    _check(f"synthetic actor onto standard_20, planting {planting}", worst)


def test_live_and_batched_calls_share_one_state(solved_actor):
    """Frames one at a time, then a batch, then one at a time again on the same retargeter give what
    one batch gives: held values and plants pass between the compiled and the batched path."""
    src, pts, rot, rok, t = solved_actor
    ch = standard_20(1.75)
    m = derive_mapping(ch, src)
    opts = RetargetOptions(foot_planting=True)
    whole = Retargeter(ch, m, src, opts, live=False).process(pts[:300], None, rot[:300], rok[:300], t[:300])
    rt = Retargeter(ch, m, src, opts)
    parts = [rt.process(pts[f:f + 1], None, rot[f:f + 1], rok[f:f + 1], t[f:f + 1]) for f in range(100)]
    parts.append(rt.process(pts[100:200], None, rot[100:200], rok[100:200], t[100:200]))
    parts += [rt.process(pts[f:f + 1], None, rot[f:f + 1], rok[f:f + 1], t[f:f + 1]) for f in range(200, 300)]
    got = np.concatenate([r.joint_positions for r in parts])
    assert whole.contact.any()
    assert np.abs(got - whole.joint_positions).max() < 1e-12
    assert (np.concatenate([r.contact for r in parts]) == whole.contact).all()


def test_the_nodes_point_layout_is_optical_points():
    """The node's precomputed per-frame layout gives optical_points' pelvis (mean of the hips) and
    masks from the joint quality, NaN joints included."""
    from mocapgraph.retarget.source import OpticalFrames, optical_points
    names = ["pelvis_top", "hip_l", "knee_l", "hip_r", "knee_r"]
    rng = np.random.default_rng(3)
    p = rng.normal(size=(5, 3))
    q = np.array([2, 2, 1, 0, 2], np.int8)
    p[3] = np.nan
    pts, ok = OpticalFrames(names).frame(p, q)
    want = optical_points(p[None], names)
    np.testing.assert_array_equal(np.isnan(pts), np.isnan(want))
    np.testing.assert_allclose(pts[np.isfinite(want)], want[np.isfinite(want)], rtol=0, atol=0)
    assert ok.tolist() == [[True, True, True, False, True, False]]


def test_the_actor_frame_is_the_layout_then_one_frame():
    """process_actor (the node's one compiled call: point layout, limb masks, retargeting, bone-follow
    flags) gives what the batched path gives on optical_points of the same frames, with joints lost,
    limbs of quality 0 and a NaN joint; read-only inputs (decoded messages) and writable ones alike;
    the numpy path's process_actor too."""
    cap, model, res = solved_synthetic_actor()
    src = optical_source(model.joint_names, model.joint_parent, model.joint_limbs, model.limb_names, model.joint_base)
    n = 300
    jp, jq = res.joints[:n].copy(), res.joint_quality[:n].astype(np.int8)
    lr, lq = res.limb_rotation[:n].copy(), res.limb_quality[:n].astype(np.int8)
    jq[40:70, 5] = 0
    jp[80:90, 2] = np.nan
    lq[100:130, 3] = 0
    t = cap.times[cap.phase_slice("performance")][:n]
    ch = standard_20(1.75)
    m = derive_mapping(ch, src)
    opts = RetargetOptions(foot_planting=True)
    pts = optical_points(np.where(jq[..., None] >= 1, jp, np.nan), model.joint_names)
    batch = Retargeter(ch, m, src, opts, live=False).process(pts, None, lr, lq >= 1, t)
    assert (batch.joint_quality < 2).any() and batch.contact.any()
    # a 5 kHz stream: the 0.05 s speed window outgrows the compiled path's first buffers (64) twice
    t_fast = np.arange(n) / 5000.0
    fast = Retargeter(ch, m, src, opts, live=False).process(pts, None, lr, lq >= 1, t_fast)
    rt = Retargeter(ch, m, src, opts)
    got = np.concatenate([rt.process_actor(jp[f], jq[f], lr[f], lq[f], t_fast[f]).joint_positions for f in range(n)])
    assert len(rt.frame_path.ht) >= 256
    assert np.abs(got - fast.joint_positions).max() < 1e-12
    for compiled, read_only, into in ((True, True, False), (True, False, False), (False, True, False),
                                      (True, True, True), (False, True, True)):
        rt = Retargeter(ch, m, src, opts, frame_path=CompiledFrame if compiled else NumpyFrame)
        assert isinstance(rt.frame_path, CompiledFrame) == compiled
        out = rt.actor_buffers() if into else None   # the node's way: one frame's arrays, rewritten each frame
        assert (out is not None) == (compiled and into)
        frames = []
        for f in range(n):
            arrays = [a[f].copy() for a in (jp, jq, lr, lq)]
            for a in arrays:
                a.flags.writeable = not read_only
            r = rt.process_actor(*arrays, t[f], out)
            if out is not None:
                assert r is out
                r = RetargetResult(**{k: getattr(r, k).copy() for k in FIELDS})
            frames.append(r)
        for k in FIELDS:
            got = np.concatenate([getattr(r, k) for r in frames]).astype(float)
            worst = float(np.abs(got - getattr(batch, k).astype(float)).max())
            print(f"\nactor frame (compiled {compiled}, read-only {read_only}, into buffers {into}) - batch max {k}: "
                  f"{worst:.1e}")
            assert worst < 1e-12 if k not in ("joint_quality", "contact") else worst == 0, (compiled, read_only, k)
    with pytest.raises(ValueError, match="actor frame"):
        Retargeter(ch, m, src, opts).process_actor(jp[0, :-1], jq[0, :-1], lr[0], lq[0], 0.0)
    rt = Retargeter(ch, m, src, opts)   # buffers that do not fit are refused (the kernel checks no bounds)
    for field, bad in (("joint_positions", np.empty((1, 5, 3))), ("joint_quality", np.empty((1, ch.n_joints))),
                       ("local_rotations", np.empty((1, ch.n_joints, 4))[:, ::-1])):
        out = rt.actor_buffers()
        setattr(out, field, bad)
        with pytest.raises(ValueError, match="come from buffers"):
            rt.process_actor(jp[0], jq[0], lr[0], lq[0], 0.0, out)
