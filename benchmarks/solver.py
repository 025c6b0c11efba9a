"""Frame solver and calibration speed on the Kiip full-body layout (synthetic actor, 1 mm noise).

Prints: live single-frame solve rate (FrameSolver.step, one core), batch solve rate over a whole
trial (FrameSolver.solve), and calibration time for 60 s of gym at 120 Hz.
Targets (issue 5): live >= 2000 frames/s, batch >= 20000 frames/s.
Run: .venv/bin/python benchmarks/solver.py
"""
from __future__ import annotations

import time

import numpy as np

from mocapgraph.kinematics.calibration import calibrate
from mocapgraph.kinematics.solver import FrameSolver
from mocapgraph.kinematics.synthetic_actor import CaptureOptions, SyntheticActor


def _rate(fn, n: int, repeat: int = 3) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n / best


def main() -> None:
    actor = SyntheticActor("kiip_full_body", duration_s=120.0, options=CaptureOptions(noise_mm=1.0))
    cap = actor.capture()
    sk = cap.skeleton
    gym = cap.markers[: cap.phases["gym"][1]]
    # 60 s of gym at 120 Hz: the scripted base + gym, repeated.
    gym60 = np.concatenate([gym] * int(np.ceil(7200 / len(gym))))[:7200]
    t0 = time.perf_counter()
    model = calibrate(sk, gym60, rate_hz=cap.rate)
    t_cal = time.perf_counter() - t0
    perf = cap.markers[cap.phase_slice("performance")]
    n_live = min(3000, len(perf))

    def live(**kw):
        s = FrameSolver(model, **kw)
        for i in range(n_live):
            s.step(perf[i])

    print(f"layout {sk.name}: {len(sk.limb_names)} limbs, {len(sk.joint_names)} joints, "
          f"{len(sk.marker_labels)} markers")
    print(f"calibration, 60 s gym @ 120 Hz ({len(gym60)} frames): {t_cal:.2f} s")
    print(f"live step, gap filling on:        {_rate(lambda: live(), n_live):8.0f} frames/s (target 2000)")
    print(f"live step, gap filling off:       {_rate(lambda: live(max_gap_s=0), n_live):8.0f} frames/s")
    print(f"live step, gap filling + one-euro:{_rate(lambda: live(filter='one_euro'), n_live):8.0f} frames/s")
    n = len(perf)
    print(f"batch solve, {n} frames, gaps on: {_rate(lambda: FrameSolver(model).solve(perf), n):8.0f} frames/s (target 20000)")
    print(f"batch solve, {n} frames, gaps off:{_rate(lambda: FrameSolver(model, max_gap_s=0).solve(perf), n):8.0f} frames/s")


if __name__ == "__main__":
    main()
