"""Shum & Ho's Figure 5 reproduced: posture matching error and search time against PCA dimensions.

600 query frames (the synthetic performer's walk and reach on standard_20, 17-22 s of its session)
are matched against a database built from other clips (the gym, turns, walk back and kick, plus
CMU 131_01 retargeted onto standard_20 when ../shared/data is there), at every reduced
dimensionality r = 1..60. Error of a frame (Eq 5): the sum over joints of the squared distance
between the query and the matched posture in the full space; percentage (Eq 6): the summed e_r over
the summed e_60, minus one. Search time per query at each r, brute force and k-d tree. Then the
search time over 10 000 postures at k = 7 (target <= 0.05 ms) and the PNG of the figure
(artifacts/posture_db_figure5.png). Shum & Ho: under 3 % at 7 dimensions, 0.10 ms search.

Why the 7-dimension figure moved between runs (issue 27): the script is deterministic for one
commit and one data folder, but (a) CMU 131_01 joins the database only when ../shared/data is
there (this split: 2.26 % without it, 4.26 % with it), (b) its postures come through the
retargeter, so a change there changes them, and (c) the figure is decided by a handful of frames:
10 of the 600 queries carry 84-97 % of the extra error, and it is not even monotonic in r (6: 1.15,
7: 4.26, 8: 0.52 %). So it is also printed over fixed, stated splits (the session in 8 contiguous
blocks, each held out in turn with 1 s either side left out of its database; with and without CMU)
with its spread. This database is one performer's 37 s (460-830 postures after de-duplication): a
held-out block's turns, kick or walk back have few near neighbours, so a wrong pick among far ones
weighs much against the full-space error (Eq 6 is relative to it); Shum & Ho's matched against a
large library of the same kinds of motion. Re-ranking the 8 nearest at 7 dimensions in the full
space (printed beside; what the live completion does since issue 27: ``PostureDB.rerank``, the
kernels ``nearest_m`` / ``best_full``) brings it under 3 % in 14 of 16 folds (median 0.05 % /
1.34 %); Figure 5's columns stay the paper's reduced search alone.
Our measure is the paper's (Eq 5: the sum over the 20 joints' 60 coordinates of the squared
distance between query and match, in the full space; Eq 6: the r-dimension matches' summed e_r over
the full-space matches' summed e_60, minus one; both postures normalised for root and heading).
What differs is what it is relative to: e_60, the full-space match's own error, is set by how
near the database's nearest posture is. Shum & Ho matched live Kinect postures against ~300
postures (filtered from ~1500) of other performers' optical captures; ours match one performer
against 460-830 of his own. The last section measures both candidate causes over the same folds:
noise on the queries (Kinect-like, 10-30 mm) leaves the figure at 4.4-5.4 %; a sparser database
lowers it (every 4th frame: ~300 postures, 2.7 % median; every 16th: 1.5 %) while the absolute
match error grows (the full-space match 15 -> 28 mm RMS a joint): Eq 6 under 3 % is what a database
of Shum & Ho's size gives here, and it says the reduced search loses little against a far
neighbour, not that the match is near.
Run: .venv/bin/python benchmarks/posture_db.py [--png PATH]
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from mocapgraph.physics.posture_db import PostureDB, normalise
from mocapgraph.physics.synthetic_targets import synthetic_targets

from _context import print_context

ROOT = Path(__file__).resolve().parents[1]
CMU = ROOT / ".." / "shared" / "data" / "bvh" / "cmu" / "131_01.bvh"


def cmu_clip(character):
    if not CMU.exists():
        return None
    from mocapgraph.cli.physics_cmds import bvh_clip
    return bvh_clip(str(CMU), character)


def per_query_ms(db: PostureDB, q: np.ndarray, how: str) -> float:
    """CPU ms per one-query search (process CPU time: the machine is shared, wall time is not ours)."""
    db.nearest(q[:1], how)
    t0 = time.process_time()
    for _ in range(3):
        for i in range(len(q)):
            db.nearest(q[i:i + 1], how)
    return 1e3 * (time.process_time() - t0) / (3 * len(q))


def two_op_ms(db: PostureDB, q: np.ndarray) -> float:
    """In-run baseline: the brute-force search as it was before the one-matmul form
    (``argmin(|r|^2 - 2 q R^T)``: a product, a scale, a subtraction), CPU ms per query."""
    rt = np.ascontiguousarray(db._reduced.T)
    sq = (db._reduced * db._reduced).sum(1)
    t0 = time.process_time()
    for _ in range(3):
        for i in range(len(q)):
            np.array([np.argmin(sq - 2.0 * (q[i] @ rt))])
    return 1e3 * (time.process_time() - t0) / (3 * len(q))


DIMS = (5, 6, 7, 8, 10)
N_FOLDS = 8
GAP_S = 1.0


def match_errors(db: PostureDB, qn: np.ndarray, dims=DIMS) -> dict[int, np.ndarray]:
    """Eq 5 per normalised query qn [N, 3J]: the squared full-space distance to the posture the
    search at r dimensions finds, for each r of ``dims`` and for the full space (its last key)."""
    full = db.positions.reshape(len(db), -1)
    per = {}
    for r in tuple(dims) + (db.components.shape[0],):
        db.set_k(int(r))
        per[r] = ((qn - full[db.nearest(db.project(qn))]) ** 2).sum(1)
    return per


def extra_error(db: PostureDB, qn: np.ndarray, dims=DIMS) -> tuple[dict[int, float], np.ndarray]:
    """Eq 6 at each r of ``dims`` for normalised queries qn [N, 3J] (summed over the queries),
    and each query's share of the extra error at r = 7 (sorted, largest first)."""
    full = db.positions.reshape(len(db), -1)
    per = match_errors(db, qn, dims)
    err = {r: e.sum() for r, e in per.items()}
    top = db.components.shape[0]
    extra7 = np.sort(np.maximum(per[7] - per[top], 0.0))[::-1]
    out = {r: 100.0 * (err[r] - err[top]) / err[top] for r in dims}
    # a remedy, for comparison: the 8 nearest at 7 dimensions re-ranked in the full space
    db.set_k(7)
    cand = db._tree.query(db.project(qn), k=min(8, len(db)))[1]                     # [N, 8]
    d = ((qn[:, None] - full[cand]) ** 2).sum(-1)
    out["7+rerank8"] = 100.0 * (d.min(1).sum() - err[top]) / err[top]
    return out, extra7 / max(extra7.sum(), 1e-300)


def splits(ch, cmu) -> None:
    """Eq 6 over fixed, stated splits: the session 1-37.5 s in N_FOLDS contiguous blocks, each held
    out in turn (queries) with GAP_S either side left out of its database (no neighbouring frame
    of a query in it); the database is the rest, with and without CMU 131_01."""
    rate = 120.0
    sess = synthetic_targets(1.0, 37.5)
    n = len(sess.positions)
    edges = np.linspace(0, n, N_FOLDS + 1).astype(int)
    gap = int(GAP_S * rate)
    blocks = [f"{1 + a / rate:.1f}-{1 + b / rate:.1f} s" for a, b in zip(edges[:-1], edges[1:])]
    print_context("0 (synthetic_targets' performer: SyntheticActor kiip_full_body seed 0)",
                  "the synthetic performer on standard_20 at 120 Hz, 1-37.5 s" + (", and CMU 131_01 retargeted onto "
                                                                                 "standard_20" if cmu is not None else ""),
                  f"{N_FOLDS} folds: each block held out as queries ({', '.join(blocks)}), its database the other "
                  f"blocks less {GAP_S:g} s either side" + ("; with and without all CMU 131_01 frames" if cmu is not None
                                                              else ""), section="fixed splits")
    for label, extra in (("synthetic only", None), ("with CMU 131_01", cmu)):
        if label != "synthetic only" and extra is None:
            continue
        rows = []
        print(f"{label}: fold, queries, extra matching error % at r = {', '.join(map(str, DIMS))}; top 10 queries' "
              "share of it at 7; at 7 with the 8 nearest re-ranked in full space")
        for f, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
            keep = np.ones(n, dtype=bool)
            keep[max(a - gap, 0): b + gap] = False
            pos, rot = [sess.positions[keep]], [sess.local_rotations[keep]]
            if extra is not None:
                pos.append(extra[0])
                rot.append(extra[1])
            db = PostureDB.build(ch.joint_names, ch.parents, np.concatenate(pos), np.concatenate(rot), k=7, min_ssd=0.005)
            qn = normalise(db.frame, sess.positions[a:b])[0].reshape(b - a, -1)
            pct, share = extra_error(db, qn)
            rows.append([pct[r] for r in DIMS] + [pct["7+rerank8"]])
            print(f"  {f} {blocks[f]:>13} {b - a:5d}  " + "  ".join(f"{pct[r]:6.2f}" for r in DIMS)
                  + f"   {100 * share[:10].sum():5.1f} %   {pct['7+rerank8']:6.2f}")
        rows = np.array(rows)
        i7 = DIMS.index(7)
        print(f"  at 7 dimensions over the {N_FOLDS} folds: mean {rows[:, i7].mean():.2f} %, median "
              f"{np.median(rows[:, i7]):.2f} %, std {rows[:, i7].std():.2f}, min {rows[:, i7].min():.2f}, "
              f"max {rows[:, i7].max():.2f} (Shum & Ho: under 3 %); re-ranked: median {np.median(rows[:, -1]):.2f} %, "
              f"max {rows[:, -1].max():.2f}")


NOISE_MM = (0.0, 10.0, 20.0, 30.0)


def paper_conditions(ch, cmu) -> None:
    """Eq 6 at 7 dimensions over the same folds as the query's conditions move towards Shum & Ho's:
    their queries were live Kinect postures (noisy by centimetres) matched against other
    performers' optical captures; ours are one noise-free performer matched against itself. Eq 6
    divides by the full-space match's own error e_60, so how near the nearest posture is decides
    the percentage as much as the reduced search does: printed beside it, per query, as the RMS
    joint distance sqrt(e_60 / J) (mm)."""
    rate = 120.0
    sess = synthetic_targets(1.0, 37.5)
    n = len(sess.positions)
    edges = np.linspace(0, n, N_FOLDS + 1).astype(int)
    gap = int(GAP_S * rate)
    J = len(ch.joint_names)
    print_context("0 (the performer) and 1 (np.random.default_rng: N(0, sigma) on every query joint coordinate)",
                  "as in the fixed splits", f"the same {N_FOLDS} folds; queries noised by sigma per coordinate before "
                  "normalising", section="paper's conditions")
    for label, extra in (("synthetic only", None), ("with CMU 131_01", cmu)):
        if label != "synthetic only" and extra is None:
            continue
        print(f"{label}: query noise sigma mm | Eq 6 at 7 dimensions over the folds: median, min, max % | "
              "full-space match error sqrt(e_60 / J) per query, median mm")
        dbs = []
        for a, b in zip(edges[:-1], edges[1:]):
            keep = np.ones(n, dtype=bool)
            keep[max(a - gap, 0): b + gap] = False
            pos, rot = [sess.positions[keep]], [sess.local_rotations[keep]]
            if extra is not None:
                pos.append(extra[0])
                rot.append(extra[1])
            dbs.append(PostureDB.build(ch.joint_names, ch.parents, np.concatenate(pos), np.concatenate(rot), k=7,
                                       min_ssd=0.005))
        for sigma in NOISE_MM:
            rng = np.random.default_rng(1)
            pct, near = [], []
            for db, (a, b) in zip(dbs, zip(edges[:-1], edges[1:])):
                q = sess.positions[a:b] + rng.normal(0.0, sigma / 1000.0, sess.positions[a:b].shape)
                qn = normalise(db.frame, q)[0].reshape(b - a, -1)
                e = match_errors(db, qn, (7,))
                top = db.components.shape[0]
                pct.append(100.0 * (e[7].sum() - e[top].sum()) / e[top].sum())
                near.append(np.sqrt(e[top] / J))
            pct = np.array(pct)
            print(f"  {sigma:5.0f} | {np.median(pct):6.2f} {pct.min():6.2f} {pct.max():6.2f} | "
                  f"{1000 * np.median(np.concatenate(near)):6.1f}")
    print("database size (synthetic only, noise-free queries): every k-th frame of each fold's database | "
          "postures kept (median) | Eq 6 at 7: median, min, max % | sqrt(e / J) median mm: full space, 7 dimensions")
    for step in (16, 8, 4, 2, 1):
        pct, near, near7, size = [], [], [], []
        for a, b in zip(edges[:-1], edges[1:]):
            keep = np.ones(n, dtype=bool)
            keep[max(a - gap, 0): b + gap] = False
            sel = np.flatnonzero(keep)[::step]
            db = PostureDB.build(ch.joint_names, ch.parents, sess.positions[sel], sess.local_rotations[sel], k=7,
                                 min_ssd=0.005)
            qn = normalise(db.frame, sess.positions[a:b])[0].reshape(b - a, -1)
            e = match_errors(db, qn, (7,))
            top = db.components.shape[0]
            pct.append(100.0 * (e[7].sum() - e[top].sum()) / e[top].sum())
            near.append(np.sqrt(e[top] / J))
            near7.append(np.sqrt(e[7] / J))
            size.append(len(db))
        pct = np.array(pct)
        print(f"  every {step:2d} | {int(np.median(size)):5d} | {np.median(pct):6.2f} {pct.min():6.2f} {pct.max():6.2f} | "
              f"{1000 * np.median(np.concatenate(near)):6.1f} {1000 * np.median(np.concatenate(near7)):6.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--png", default=str(ROOT / "artifacts" / "posture_db_figure5.png"))
    opts = ap.parse_args()
    query = synthetic_targets(17.0, 22.0)                     # 600 frames at 120 Hz
    ch = query.character
    parts = [synthetic_targets(a, b) for a, b in ((1, 17), (25, 37.5))]
    pos = [p.positions for p in parts]
    rot = [p.local_rotations for p in parts]
    cmu = cmu_clip(ch)
    if cmu is not None:
        pos.append(cmu[0])
        rot.append(cmu[1])
    db = PostureDB.build(ch.joint_names, ch.parents, np.concatenate(pos), np.concatenate(rot), k=7, min_ssd=0.005)
    n_raw = sum(len(p) for p in pos)
    print_context("0 (synthetic_targets' performer: SyntheticActor kiip_full_body seed 0)",
                  "the synthetic performer on standard_20 at 120 Hz" + (f", and the real capture {CMU.resolve()} "
                                                                      "retargeted onto standard_20" if cmu is not None else
                                                                      f" (no CMU 131_01: {CMU} absent)"),
                  f"held out: queries 17-22 s (frames 2040-2639, {len(query)} frames); database (train): 1-17 s "
                  "(frames 120-2039) and 25-37.5 s (frames 3000-4499) of the same performer"
                  + (f", plus all {len(cmu[0])} CMU 131_01 frames" if cmu is not None else "")
                  + f"; {n_raw} frames, {len(db)} kept after SSD >= 0.005 m^2; 22-25 s unused; brute/k-d times over "
                  "the first 200 queries", section="figure 5")
    print(f"database: {len(db)} postures of {n_raw} (SSD >= 0.005 m^2; sources: synthetic gym, turns, walk back, kick"
          f"{', CMU 131_01' if cmu is not None else ''}); query: {len(query)} frames of walk and reach")
    qn = normalise(db.frame, query.positions)[0].reshape(len(query), -1)
    full = db.positions.reshape(len(db), -1)
    dims = np.arange(1, db.components.shape[0] + 1)
    dims = dims[dims <= 60]
    err, t_brute, t_tree = [], [], []
    for r in dims:
        db.set_k(int(r))
        red = db.project(qn)
        idx = db.nearest(red)
        err.append(((qn - full[idx]) ** 2).sum(1).sum())                 # Eq 5 summed over frames
        t_brute.append(per_query_ms(db, red[:200], "brute"))
        t_tree.append(per_query_ms(db, red[:200], "kdtree"))
    err = np.array(err)
    pct = (err - err[-1]) / err[-1] * 100.0                               # Eq 6
    print(" r  error %   brute ms   k-d ms")
    for r in (1, 2, 3, 4, 5, 6, 7, 8, 10, 15, 20, 30, 45, 60):
        if r <= dims[-1]:
            i = r - 1
            print(f"{r:2d}  {pct[i]:7.2f}   {t_brute[i]:.4f}    {t_tree[i]:.4f}")
    i7 = 6
    print(f"at 7 dimensions: {pct[i7]:.2f} % extra matching error (Shum & Ho: under 3 %), search "
          f"{min(t_brute[i7], t_tree[i7]):.4f} ms (Shum & Ho 0.10 ms)")
    # 10 000 postures: every clip of the session at 120 Hz, kept whole
    big = [synthetic_targets(a, b) for a, b in ((1, 37.5),)]
    bp = np.concatenate([big[0].positions] * 3)[:10000]
    br = np.concatenate([big[0].local_rotations] * 3)[:10000]
    bp = bp + np.random.default_rng(0).normal(0, 0.005, bp.shape)       # so none are identical
    db10 = PostureDB.build(ch.joint_names, ch.parents, bp, br, k=7, min_ssd=0.0)
    print_context("0 (the performer) and 0 (np.random.default_rng: N(0, 5 mm) on every posture)",
                  "the synthetic performer on standard_20 at 120 Hz, 1-37.5 s (frames 120-4499) three times, cut to "
                  "10 000 postures, plus noise", "queries: the first 300 of the 600 above (their frames are in this "
                  "database, noised: a timing figure, not an error one); 3 interleaved rounds, best of each",
                  section="10 000 postures")
    red = db10.project(qn)
    # interleaved rounds, best of each: the machine is shared and its load comes in bursts
    rounds = [(per_query_ms(db10, red[:300], "brute"), per_query_ms(db10, red[:300], "kdtree"),
               two_op_ms(db10, red[:300])) for _ in range(3)]
    tb, tk, t2 = (min(r[i] for r in rounds) for i in range(3))
    print(f"{len(db10)} postures, k = 7: brute force {tb:.4f} ms, k-d tree {tk:.4f} ms per query "
          f"(target <= 0.05 ms; the faster is chosen at load); load average {os.getloadavg()[0]:.1f}")
    print(f"  in-run baseline, the earlier three-operation brute force: {t2:.4f} ms (one matmul: x{t2 / tb:.2f})")
    splits(ch, cmu)
    paper_conditions(ch, cmu)
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing: no PNG")
        return
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(dims, pct, color="tab:red", label="matching error (Eq 6), %")
    ax.axhline(3.0, color="tab:red", ls=":", lw=0.8)
    ax.axvline(7, color="grey", ls=":", lw=0.8)
    ax.set_xlabel("dimensions")
    ax.set_ylabel("error %", color="tab:red")
    ax.set_ylim(0, max(10.0, min(100.0, pct[:10].max() * 1.05)))
    ax2 = ax.twinx()
    ax2.plot(dims, np.minimum(t_brute, t_tree), color="tab:blue", label="search time, ms")
    ax2.set_ylabel("search ms per query", color="tab:blue")
    ax.set_title(f"Posture matching vs dimensions ({len(db)} postures, {len(query)} queries)")
    fig.tight_layout()
    Path(opts.png).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(opts.png, dpi=110)
    print(f"figure: {opts.png}")


if __name__ == "__main__":
    main()
