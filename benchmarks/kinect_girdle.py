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

standard_20's girdle offsets (kinematics/character.py) are these means, left/right symmetrised.
Usage: python benchmarks/kinect_girdle.py
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

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
    per = {r: girdle_geometry(SHARED / "kinect2" / f"{r}.csv") for r in RECORDINGS if (SHARED / "kinect2" / f"{r}.csv").exists()}
    if not per:
        print(f"no Kinect v2 recordings in {SHARED / 'kinect2'}")
        return 1
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
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
