"""Kinect v2 girdle geometry over the kinect2 recordings: where the hips and shoulders sit, as fractions of height.

Prints, over every frame of every ../shared/data/kinect2 recording with the joints involved all
Tracked (state 2):

- pelvis frame at SpineBase (up: SpineBase->SpineMid; left: HipRight->HipLeft made orthogonal to
  up; forward = left x up): HipLeft and HipRight relative to SpineBase, in m and in fractions of H;
- chest frame at SpineShoulder (up: SpineShoulder->Head, the character's ShoulderCenter->Head bone;
  left: ShoulderRight->ShoulderLeft made orthogonal): ShoulderLeft/Right and Neck relative to
  SpineShoulder, same units; and the angle between SpineShoulder->Neck and SpineShoulder->Head;
- H, the performer's standing height, estimated as the Kinect leg length (hip to ankle, median
  over tracked frames) over Winter's 0.491 H (hip 0.530 H minus ankle 0.039 H, as standard_20),
  beside the estimates from the upper arm (0.186 H) and forearm (0.146 H) for comparison;
- per coordinate the mean, the std over frames, and the spread of the per-recording means.

standard_20's girdle offsets (retarget/character.py) are these means, left/right symmetrised.

Then, every recording onto standard_20 with the shipped mapping: per girdle bone (HipCenter and
ShoulderCenter to their children) the angle to the Kinect's bone over the frames with both ends
Tracked (mean, p95, max), with the girdle joints' source rotations from the best fit over their
child bones (the rule) beside the TRIAD of two directions (the rule before), and the frames flagged
estimated; and the one-frame (live) cost of a Kinect frame: the rotations from its points alone
(the compiled kernel, rotations_from_points_frame, beside the numpy rotations_from_points) and the
whole Retargeter.process (with the kernel, and with the numpy derivation swapped in), best fit +
bone check against TRIAD without the check, CPU (process_time) and wall per frame and frames/s,
measured in the same run, with the load average; and the bone check alone, kernel beside numpy.
Usage: python benchmarks/kinect_girdle.py [--frames 2000]
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from _context import print_context

REPO = Path(__file__).resolve().parents[1]
SHARED = (REPO / ".." / "shared" / "data").resolve()
RECORDINGS = ["Ges01_wavehand", "Ges02_balancinghands", "Ges03_drawlines", "Ges04_comehere", "Ges05_demopoint"]


def _frame(up: np.ndarray, left: np.ndarray) -> np.ndarray:
    """Rows (forward, left, up) [F, 3, 3] of a body frame from up and a rough left [F, 3]."""
    up = up / np.linalg.norm(up, axis=1, keepdims=True)
    left = left - np.sum(left * up, 1, keepdims=True) * up
    left = left / np.linalg.norm(left, axis=1, keepdims=True)
    return np.stack([np.cross(left, up), left, up], axis=1)


def girdle_geometry(path: Path) -> dict[str, np.ndarray]:
    """Per tracked frame: hip, shoulder and neck offsets [F, 3] (m) in the pelvis / chest frames, the
    leg length, upper arm and forearm [F] (m), and the Neck-vs-Head angle (deg)."""
    from mocapgraph.formats.kinect_csv import read_kinect_csv
    t = read_kinect_csv(path)
    n = t.names.index
    P, S = t.positions, t.tracking_state

    def ok(*names):
        return (S[:, [n(x) for x in names]] == 2).all(1)

    out: dict[str, np.ndarray] = {}
    m = ok("SpineBase", "SpineMid", "HipLeft", "HipRight")
    fr = _frame(P[m, n("SpineMid")] - P[m, n("SpineBase")], P[m, n("HipLeft")] - P[m, n("HipRight")])
    for side in ("Left", "Right"):
        out[f"Hip{side}"] = np.einsum("fij,fj->fi", fr, P[m, n(f"Hip{side}")] - P[m, n("SpineBase")])
    m = ok("SpineShoulder", "Neck", "Head", "ShoulderLeft", "ShoulderRight")
    fr = _frame(P[m, n("Head")] - P[m, n("SpineShoulder")], P[m, n("ShoulderLeft")] - P[m, n("ShoulderRight")])
    for j in ("ShoulderLeft", "ShoulderRight", "Neck"):
        out[j] = np.einsum("fij,fj->fi", fr, P[m, n(j)] - P[m, n("SpineShoulder")])
    a, b = P[m, n("Neck")] - P[m, n("SpineShoulder")], P[m, n("Head")] - P[m, n("SpineShoulder")]
    cos = np.sum(a * b, 1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    out["neck_vs_head_deg"] = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    legs = []
    for side in ("Left", "Right"):
        m = ok(f"Hip{side}", f"Knee{side}", f"Ankle{side}")
        legs.append(np.linalg.norm(P[m, n(f"Knee{side}")] - P[m, n(f"Hip{side}")], axis=1)
                    + np.linalg.norm(P[m, n(f"Ankle{side}")] - P[m, n(f"Knee{side}")], axis=1))
    out["leg"] = np.concatenate(legs)
    for name, (a_, b_) in {"upper_arm": ("Shoulder", "Elbow"), "forearm": ("Elbow", "Wrist")}.items():
        segs = []
        for side in ("Left", "Right"):
            m = ok(f"{a_}{side}", f"{b_}{side}")
            segs.append(np.linalg.norm(P[m, n(f"{b_}{side}")] - P[m, n(f"{a_}{side}")], axis=1))
        out[name] = np.concatenate(segs)
    return out


def main() -> int:
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000, help="live frames timed per variant")
    frames = ap.parse_args().frames
    per = {r: girdle_geometry(SHARED / "kinect2" / f"{r}.csv") for r in RECORDINGS if (SHARED / "kinect2" / f"{r}.csv").exists()}
    if not per:
        print(f"no Kinect v2 recordings in {SHARED / 'kinect2'}")
        return 1
    print_context(None, f"real Kinect v2 recordings {SHARED / 'kinect2'}/{{{','.join(per)}}}.csv",
                  "every frame with the joints involved all Tracked (state 2); the retargeting below: every frame",
                  section="geometry, retargeted")
    allf = {k: np.concatenate([p[k] for p in per.values()]) for k in next(iter(per.values()))}
    H = float(np.median(allf["leg"])) / 0.491
    print(f"Kinect v2 girdle geometry over {len(per)} recordings (load average {os.getloadavg()[0]:.2f})")
    print(f"height H from the leg (hip-ankle {np.median(allf['leg']):.3f} m / 0.491): {H:.3f} m; "
          f"from the upper arm {np.median(allf['upper_arm']) / 0.186:.3f} m, forearm {np.median(allf['forearm']) / 0.146:.3f} m")
    print("offset (forward, left, up) relative to SpineBase (hips, pelvis frame) / SpineShoulder (chest frame):")
    for j in ("HipLeft", "HipRight", "ShoulderLeft", "ShoulderRight", "Neck"):
        v = allf[j]
        rec = np.array([p[j].mean(0) for p in per.values()])
        print(f"  {j:<14} {len(v):5d} frames  mean {np.round(v.mean(0), 4)} m = {np.round(v.mean(0) / H, 4)} H"
              f"  std {np.round(v.std(0), 4)} m  per-recording means spread {np.round(rec.max(0) - rec.min(0), 4)} m")
    nh = allf["neck_vs_head_deg"]
    print(f"  SpineShoulder->Neck vs ->Head: mean {nh.mean():.1f} deg, p95 {np.percentile(nh, 95):.1f}, max {nh.max():.1f}")
    hip = (allf["HipLeft"].mean(0) * (1, 1, 1) + allf["HipRight"].mean(0) * (1, -1, 1)) / 2 / H
    sh = (allf["ShoulderLeft"].mean(0) * (1, 1, 1) + allf["ShoulderRight"].mean(0) * (1, -1, 1)) / 2 / H
    print(f"symmetrised, fractions of H: hip (fwd, +-left, up) {np.round(hip, 4)}; shoulder {np.round(sh, 4)}")
    retargeted(list(per))
    live_cost(frames)
    return 0


def _retargeter(trial, best_fit: bool, tolerance):
    from mocapgraph.formats.mapping_file import load_mapping
    from mocapgraph.retarget.character import standard_20
    from mocapgraph.retarget.retargeter import RetargetOptions, Retargeter
    from mocapgraph.retarget.source import kinect_source, plan_point_rotations
    src = kinect_source(trial.names, trial.parents)
    ch = standard_20(1.75)
    rt = Retargeter(ch, load_mapping("kinect_v2_standard_20"), src, RetargetOptions(follow_tolerance_deg=tolerance))
    if not best_fit:    # the baseline rule; the live path reads the same plan
        rt.plan.point_plan = plan_point_rotations(src, best_fit=False)
    return rt, ch


def retargeted(names: list[str]) -> None:
    """Girdle bone angles to the Kinect's over every recording: best fit beside TRIAD."""
    from mocapgraph.formats.kinect_csv import read_kinect_csv
    trials = [read_kinect_csv(SHARED / "kinect2" / f"{r}.csv", ground="feet") for r in names]
    print("\ngirdle bones of standard_20 vs the Kinect's, all recordings, deg (mean / p95 / max):")
    rows: dict[str, list[str]] = {}
    flagged = {}
    for best_fit in (True, False):
        angles: dict[str, list[np.ndarray]] = {}
        n_flag = 0
        for t in trials:
            rt, ch = _retargeter(t, best_fit, 10.0)
            res = rt.process(t.positions, t.tracking_state == 2)
            n_flag += int((res.joint_quality[:, [ch.index("HipCenter"), ch.index("ShoulderCenter")]] == 1).any(1).sum())
            by = {e.joint: e for e in rt.mapping.joints}
            for j in (ch.index("HipCenter"), ch.index("ShoulderCenter")):
                for k in ch.children(j):
                    a, b = t.names.index(by[ch.joint_names[j]].position), t.names.index(by[ch.joint_names[k]].position)
                    ok = (t.tracking_state[:, a] == 2) & (t.tracking_state[:, b] == 2)
                    u, v = res.joint_positions[ok, k] - res.joint_positions[ok, j], t.positions[ok, b] - t.positions[ok, a]
                    cos = np.sum(u * v, 1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
                    angles.setdefault(f"{ch.joint_names[j]} -> {ch.joint_names[k]}", []).append(
                        np.degrees(np.arccos(np.clip(cos, -1, 1))))
        for bone, parts in angles.items():
            x = np.concatenate(parts)
            rows.setdefault(bone, []).append(f"{x.mean():5.1f} / {np.percentile(x, 95):5.1f} / {x.max():5.1f}")
        flagged[best_fit] = n_flag
    print(f"  {'bone':<32} {'best fit (the rule)':>22} {'TRIAD (before)':>22}")
    for bone, r in rows.items():
        print(f"  {bone:<32} {r[0]:>22} {r[1]:>22}")
    total = sum(len(t.positions) for t in trials)
    print(f"  frames with a girdle joint estimated (its bone beyond 10 deg, or a source point held): best fit {flagged[True]}, "
          f"TRIAD {flagged[False]} of {total}")


def live_cost(frames: int) -> None:
    """One-frame cost of a Kinect v2 frame onto standard_20, CPU and wall per frame: the rotation
    derivation alone (compiled kernel beside the numpy reference) and the whole Retargeter.process,
    with the kernel (the live path) and with the numpy derivation swapped in (the baseline)."""
    import time
    from mocapgraph.formats.kinect_csv import read_kinect_csv
    from mocapgraph.retarget import live as retarget_live
    from mocapgraph.retarget.source import rotations_from_points, rotations_from_points_frame
    t = read_kinect_csv(SHARED / "kinect2" / "Ges03_drawlines.csv", ground="feet")
    good = np.flatnonzero(np.isfinite(t.positions).all((1, 2)))
    print_context(None, f"real Kinect v2 recording {SHARED / 'kinect2' / 'Ges03_drawlines.csv'}",
                  f"its {len(good)} frames with every joint finite, cycled to {frames} frames per variant "
                  "(the first 50 also run once untimed, to warm up)", section="live cost")
    pts = t.positions[good]
    ok = t.tracking_state[good] == 2
    idx = np.arange(frames) % len(pts)
    kernel_frame = retarget_live.rotations_from_points_frame

    def numpy_frame(plan, p):
        return rotations_from_points(plan, p[None])[0]

    def timed(call) -> tuple[float, float]:
        """(CPU us, wall us) per frame of call(i) over the frames."""
        c0, w0 = time.process_time(), time.perf_counter()
        for i in idx:
            call(i)
        return 1e6 * (time.process_time() - c0) / frames, 1e6 * (time.perf_counter() - w0) / frames

    print(f"\none Kinect v2 frame onto standard_20 (live path, {frames} frames, load average before "
          f"{os.getloadavg()[0]:.2f}); CPU us (wall us), frames/s from CPU:")
    for label, best_fit, tol in (("best fit + bone check (the rule)", True, 10.0), ("TRIAD, no check (before)", False, None)):
        rt, _ = _retargeter(t, best_fit, tol)
        for i in idx[:50]:
            rt.process(pts[i:i + 1], ok[i:i + 1])
            rotations_from_points_frame(rt.plan.point_plan, pts[i])
        d_np = timed(lambda i: numpy_frame(rt.plan.point_plan, pts[i]))
        d_k = timed(lambda i: rotations_from_points_frame(rt.plan.point_plan, pts[i]))
        whole_k = timed(lambda i: rt.process(pts[i:i + 1], ok[i:i + 1]))
        retarget_live.rotations_from_points_frame = numpy_frame      # the baseline: numpy derivation
        try:
            whole_np = timed(lambda i: rt.process(pts[i:i + 1], ok[i:i + 1]))
        finally:
            retarget_live.rotations_from_points_frame = kernel_frame
        print(f"  {label}:\n"
              f"    rotations from points: kernel {d_k[0]:7.1f} ({d_k[1]:7.1f}), numpy {d_np[0]:7.1f} ({d_np[1]:7.1f}): "
              f"{d_np[0] / max(d_k[0], 1e-9):.0f}x\n"
              f"    whole Retargeter.process: kernel {whole_k[0]:7.1f} ({whole_k[1]:7.1f}) = {1e6 / whole_k[0]:6.0f} frames/s, "
              f"numpy derivation {whole_np[0]:7.1f} ({whole_np[1]:7.1f}) = {1e6 / whole_np[0]:6.0f} frames/s; "
              f"load average {os.getloadavg()[0]:.2f}")
    # the bone check alone: the compiled one-frame kernel beside the numpy reference on one frame
    from mocapgraph.retarget.bone_follow import unfollowed
    from mocapgraph.retarget.kernels import flag_unfollowed
    rt, ch = _retargeter(t, True, 10.0)
    c = rt.plan.checks
    res = rt.process(pts, ok)
    q = np.full(ch.n_joints, 2, np.int8)
    c0, w0 = time.process_time(), time.perf_counter()
    for i in idx:
        unfollowed(c, res.joint_positions[i:i + 1], pts[i:i + 1])
    c1, w1 = time.process_time(), time.perf_counter()
    for i in idx:
        flag_unfollowed(res.joint_positions[i], pts[i], c.joint, c.child, c.a, c.b, c.A, c.cos_limit, q)
    c2, w2 = time.process_time(), time.perf_counter()
    print(f"  bone check ({c.joint.size} bones) one frame: numpy {1e6 * (c1 - c0) / frames:6.1f} us CPU "
          f"({1e6 * (w1 - w0) / frames:6.1f} wall), compiled kernel {1e6 * (c2 - c1) / frames:6.2f} us CPU "
          f"({1e6 * (w2 - w1) / frames:6.2f} wall): {(c1 - c0) / max(c2 - c1, 1e-9):.0f}x")
    print(f"  load average after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    raise SystemExit(main())
