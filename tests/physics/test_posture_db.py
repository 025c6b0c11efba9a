"""Shum & Ho's posture database (section 5): building, matching, and filling hidden joints."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from mocapgraph.physics.posture_db import PostureDB, PostureDBError, normalise
from mocapgraph.physics.reference import match
from mocapgraph.physics.synthetic_targets import synthetic_targets
from mocapgraph.physics.tracker import TargetConditioner
from mocapgraph.physics.world import PhysicsWorld

HIDDEN = ("HandRight", "ElbowLeft", "KneeRight")


@pytest.fixture(scope="module")
def db():
    # other clips than the test clip (the first walk): the gym, reach, turns and kick, and not the
    # walk back either (the same gait mirrored)
    parts = [synthetic_targets(a, b) for a, b in ((1, 17), (22, 27.5), (32.5, 37.5))]
    ch = parts[0].character
    return PostureDB.build(ch.joint_names, ch.parents, np.concatenate([p.positions for p in parts]),
                           np.concatenate([p.local_rotations for p in parts]), min_ssd=0.005)


@pytest.fixture(scope="module")
def walk():
    return synthetic_targets(17.0, 20.5)


def test_build_normalises_dedupes_and_round_trips(db, tmp_path):
    assert 100 < len(db) < 3180          # near-duplicates dropped
    flat = db.positions.reshape(len(db), -1)
    d2 = ((flat[:, None] - flat[None]) ** 2).sum(-1) + np.eye(len(db)) * 1e9
    assert d2.min() >= 0.005              # no two kept postures closer than the threshold
    assert np.abs(db.positions[:, db.frame.root]).max() < 1e-9   # root at the origin
    yaw, _, _ = db.frame.yaw_and_origin(db.positions)[:3]
    assert np.abs(yaw).max() < 1e-9       # heading removed
    db.save(tmp_path / "db.npz")
    again = PostureDB.load(tmp_path / "db.npz")
    np.testing.assert_array_equal(again.positions, db.positions)
    assert again.k == 7 and again.joint_names == db.joint_names
    (tmp_path / "bad.npz").write_bytes(b"not a database")
    with pytest.raises(PostureDBError, match="bad.npz"):
        PostureDB.load(tmp_path / "bad.npz")


def test_match_is_yaw_and_translation_free_and_searches_agree(db, walk):
    p = walk.positions[100]
    i, yaw, origin, ok = match(db, p)
    c, s = np.cos(1.0), np.sin(1.0)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    j, yaw2, origin2, _ = match(db, p @ R.T + [3.0, -2.0, 0.0])
    assert ok and i == j and yaw2 == pytest.approx(yaw + 1.0)
    q = db.project(normalise(db.frame, walk.positions[::7])[0].reshape(-1, 3 * len(db.joint_names)))
    np.testing.assert_array_equal(db.nearest(q, "brute"), db.nearest(q, "kdtree"))
    one = np.array([db.nearest(q[k:k + 1], "brute")[0] for k in range(len(q))])
    np.testing.assert_array_equal(one, db.nearest(q, "brute"))


def test_missing_joint_takes_the_database_mean_before_projection(db, walk):
    p = walk.positions[50].copy()
    p[walk.character.index("HandRight")] = np.nan
    norm, *_ = normalise(db.frame, p[None])
    flat = norm.reshape(1, -1)
    expect = (np.where(np.isfinite(flat), flat, db.mean) - db.mean) @ db.components[:db.k].T
    np.testing.assert_allclose(db.project(flat), expect)


def test_hidden_hand_elbow_knee_database_beats_holding(db, walk):
    ch = walk.character
    hid = [ch.index(n) for n in HIDDEN]
    a, b = 60, 60 + 240                    # 2 s hidden at 120 Hz
    cond = TargetConditioner(ch, db)
    e_db, e_hold, e_rel = [], [], []
    for i in range(a, b):
        p = walk.positions[i].copy()
        r = walk.local_rotations[i].copy()
        p[hid] = np.nan
        r[hid] = np.nan
        c = cond.condition(p, r, walk.root[i])
        assert c.filled[hid].all() and np.isfinite(c.positions).all()
        true = walk.positions[i, hid]
        e_db.append(np.linalg.norm(c.positions[hid] - true, axis=1))
        e_hold.append(np.linalg.norm(walk.positions[a - 1, hid] - true, axis=1))
        rel = walk.positions[a - 1, hid] - walk.positions[a - 1, ch.root] + walk.positions[i, ch.root]
        e_rel.append(np.linalg.norm(rel - true, axis=1))
    e_db, e_hold, e_rel = (1000 * np.mean(x, 0) for x in (e_db, e_hold, e_rel))
    print(f"\nhidden 2 s during the walk ({', '.join(HIDDEN)}), database of {len(db)} postures from other clips:")
    for name, e in (("database", e_db), ("hold last (world)", e_hold), ("hold last (root-relative)", e_rel)):
        print(f"  {name:26s} " + "  ".join(f"{v:6.1f}" for v in e) + " mm")
    assert (e_db < e_rel).all() and (e_db < e_hold).all()


def test_tracked_character_with_hidden_joints(db, walk):
    """Through the physics: the simulated hidden joints stay nearer the truth with the database."""
    ch = walk.character
    hid = [ch.index(n) for n in HIDDEN]
    a, b = 60, 300
    out = {}
    for mode in ("database", "hold"):
        w = PhysicsWorld([ch])
        w.set_pose(0, walk.local_rotations[0], walk.root[0])
        cond = TargetConditioner(ch, db if mode == "database" else None)
        held = None
        err = []
        for i in range(b):
            p = walk.positions[i].copy()
            r = walk.local_rotations[i].copy()
            if i >= a:
                if mode == "hold":
                    held = walk.positions[a - 1] if held is None else held
                    p[hid] = held[hid]
                    r[hid] = walk.local_rotations[a - 1, hid]
                else:
                    p[hid] = np.nan
                    r[hid] = np.nan
            c = cond.condition(p, r, walk.root[i])
            w.set_target(0, c.positions, c.orientations, walk.times[i])
            w.step(1 / 120)
            if i >= a:
                err.append(np.linalg.norm(w.joint_positions(0)[hid] - walk.positions[i, hid], axis=1))
        out[mode] = 1000 * np.mean(err, 0)
    print("\nsimulated hidden joints, mean error: database " + " ".join(f"{v:.1f}" for v in out["database"])
          + " mm; holding " + " ".join(f"{v:.1f}" for v in out["hold"]) + " mm")
    assert out["database"].mean() < out["hold"].mean()


def test_posture_db_build_command(tmp_path):
    from graph_helpers import run_concurrently

    out = tmp_path / "db.npz"
    build = [sys.executable, "-m", "mocapgraph", "posture-db", "build"]
    # the good and the refused build at once (their interpreters' start-up shares the cores; the
    # refused one is pointed at a file of its own so that it cannot race the good one)
    r, bad = run_concurrently([build + ["synthetic:reach,kick", "-o", str(out)],
                               build + ["synthetic:dance", "-o", str(tmp_path / "bad.npz")]], timeout=120)
    assert r.returncode == 0, r.stderr
    assert "postures kept" in r.stdout and PostureDB.load(out).k == 7
    assert bad.returncode == 2 and "dance" in bad.stderr and "Traceback" not in bad.stderr


def test_lean_world_orientations_equal_the_characters_forward_kinematics(walk):
    from mocapgraph.physics.reference import world_orientations
    ch = walk.character
    _, fk = ch.forward_kinematics(walk.local_rotations[40], walk.root[40])
    q = world_orientations(walk.local_rotations[40], ch.rest_rotations, ch.parents, ch._levels)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    np.testing.assert_allclose(q, fk * np.where(fk[:, :1] < 0, -1.0, 1.0), atol=1e-12)


def test_re_ranked_search_finds_the_full_space_nearest_more_often(db, walk):
    # Issue 27 (Shum & Ho's Eq 6 at 7 dimensions): the 8 nearest in the reduced space re-ranked in
    # the full space, as the live completion searches, against the reduced search alone.
    from mocapgraph.physics.reference import rerank

    qn = normalise(db.frame, walk.positions[::4])[0]
    full = db.positions.reshape(len(db), -1)
    flat = qn.reshape(len(qn), -1)
    e = lambda idx: ((flat - full[idx]) ** 2).sum(1)
    e_full = e(np.argmin(((flat[:, None] - full[None]) ** 2).sum(-1), axis=1))
    e_7 = e(db.nearest(db.project(flat)))
    e_re = e(np.array([rerank(db, p) for p in qn]))
    pct7, pct_re = (100 * (x.sum() - e_full.sum()) / e_full.sum() for x in (e_7, e_re))
    print(f"\nEq 6 at 7 dimensions over {len(qn)} walk queries: reduced search {pct7:.2f} %, re-ranked {pct_re:.2f} %")
    assert (e_re <= e_7 + 1e-12).all() and pct_re < pct7
