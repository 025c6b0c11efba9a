"""Frame solver and calibration speed on the Kiip full-body layout (synthetic actor, 1 mm noise).

Prints: live single-frame solve rate (FrameSolver.step, one core), batch solve rate over a whole
trial (FrameSolver.solve), calibration time for 60 s of gym at 120 Hz, and the per-frame latency
through a launched graph (synthetic_actor reader at 240 Hz -> frame_solver node): from the
reader publishing a MarkerFrame to the solver publishing its ActorPose, and on to a subscriber.
Targets (issue 5): live >= 2000 frames/s, batch >= 20000 frames/s. Issue 10: the global fit's
live rate (compiled kernels beside the numpy reference, target >= 2000 frames/s) and batch rate
beside the segment-wise ones (in the same run), its iterations and the point motion left when a
frame stops, each stage's share of a live frame (numpy and compiled), and both accuracies.
Run: .venv/bin/python benchmarks/solver.py [--graph-seconds 20] [--no-graph]
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from _context import print_context
from _launched import launched_graph
from mocapgraph.kinematics.calibration.calibrate import calibrate
from mocapgraph.kinematics.solving.global_fit import GlobalFitOptions
from mocapgraph.kinematics.solving.solver import FrameSolver
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor


def _rate(fn, n: int, repeat: int = 3) -> float:
    return _rates(fn, n, repeat)[1]


def _rates(fn, n: int, repeat: int = 3) -> tuple[float, float]:
    """(CPU-time, wall-time) frames/s, best of ``repeat`` runs (CPU time is this process's, so
    other load on the machine shows in the wall figure only)."""
    cpu = wall = np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return n / cpu, n / wall


def _load() -> str:
    return "load average " + " ".join(f"{v:.1f}" for v in os.getloadavg())


GRAPH = """\
nodes:
  - name: reader
    type: synthetic_actor
    params: {{rate_hz: 240.0, noise_mm: 1.0, duration_s: {duration}, loop: false}}
  - name: solver
    type: frame_solver
    params: {{model_file: {model}}}
"""


def graph_latency(seconds: float) -> None:
    """Launch reader -> solver at 240 Hz and time every frame from the reader's publish stamp."""
    from mocapgraph.kinematics.model import save_model
    from mocapgraph.bus.manifest import subscribe
    from mocapgraph.messages import decode_envelope

    # The solver loads a model calibrated here on the same synthetic actor (seed 0) as the reader.
    cap = SyntheticActor("kiip_full_body", rate=240.0, options=CaptureOptions(noise_mm=1.0)).capture(0, 4080)
    model = calibrate(cap.skeleton, cap.markers[::4], rate_hz=60.0)
    print_context("0 (SyntheticActor kiip_full_body seed 0 for the model; the synthetic_actor node's default seed 0)",
                  f"the synthetic_actor node (kiip_full_body) at 240 Hz, 1 mm noise, {seconds + 5.0:g} s; the model calibrated on its "
                  "frames 0-4079 at 240 Hz, every 4th", f"frames matched on both topics from 1 s after the subscription, "
                  f"for {seconds:g} s", section="launched graph")
    with tempfile.TemporaryDirectory() as tmp:
        save_model(model, Path(tmp) / "model.json")
        graph = GRAPH.format(duration=seconds + 5.0, model=Path(tmp) / "model.json")
        with launched_graph(graph, "actor_pose", Path(tmp)) as manifest:
            sock = subscribe(manifest, ["markers", "actor_pose"])
            sent: dict[int, int] = {}                 # capture stamp -> reader publish ns
            solved: dict[int, tuple[int, int]] = {}   # capture stamp -> (solver publish, receive) ns
            rows = []  # (reader publish, solver publish, receive) ns
            t_stop = time.monotonic() + 1.0 + seconds
            t_warm = time.monotonic() + 1.0
            while time.monotonic() < t_stop:
                if not sock.poll(200):
                    continue
                frames = sock.recv_multipart()
                now = time.time_ns()
                env = decode_envelope(frames)
                # The solver stamps a pose with its markers' capture stamp: match on it. The two
                # publishers reach this socket independently, so either may come first.
                if env.topic == "markers":
                    sent[env.capture_ns] = env.publish_ns
                else:
                    solved[env.capture_ns] = (env.publish_ns, now)
                key = env.capture_ns
                if key in sent and key in solved:
                    pub, (done, got) = sent.pop(key), solved.pop(key)
                    if time.monotonic() > t_warm:
                        rows.append((pub, done, got))
            sock.close(0)
    a = np.asarray(rows, dtype=np.float64)
    solve_ms = (a[:, 1] - a[:, 0]) / 1e6
    recv_ms = (a[:, 2] - a[:, 0]) / 1e6
    print(f"launched graph, synthetic_actor 240 Hz -> frame_solver, {len(a)} frames over {seconds:g} s "
          f"({len(a) / seconds:.0f} poses/s; {len(sent)} marker frames left unmatched):")
    for name, v in (("reader publish -> solver publish", solve_ms), ("reader publish -> subscriber", recv_ms)):
        print(f"  {name:<34} median {np.median(v):6.2f} ms  p99 {np.percentile(v, 99):6.2f} ms  "
              f"max {v.max():6.2f} ms")


def live_global_stages(model, frames: np.ndarray) -> None:
    """Where one live global-fit frame's time goes (numpy tracker): each stage of
    GlobalTracker.track and FrameSolver.step timed separately (CPU time, us per frame)."""
    from scipy.linalg.lapack import dpotrs

    from mocapgraph.kinematics.solving.global_track_numpy import _cayley_neg

    solver = FrameSolver(model, fit="global", compiled=False)
    solver.step(frames[0])          # the first frame comes from the batch path and seeds the tracker
    tr = solver._tracker
    L, LK = tr.L, tr._LK
    spent: dict[str, float] = {}
    iters: list[int] = []
    clock = time.thread_time

    def tick(name: str, t0: float) -> float:
        t1 = clock()
        spent[name] = spent.get(name, 0.0) + t1 - t0
        return t1

    n = 0
    for f in frames[1:]:
        if tr._R is None:               # declined: let the solver restart the tracker
            solver.step(f)
            continue
        n += 1
        t = clock()
        y = f[tr._idx0]
        seen = np.isfinite(y).all(-1) & tr._pad
        tr._Y[:3 * LK] = np.where(seen[..., None], y, 0.0).reshape(-1)
        key = seen.tobytes()
        if key != tr._code:
            tr._code = key
            u = tr._wm0 * seen.reshape(LK)
            tr._W[:3 * LK] = np.repeat(u, 3)
            tr._new_markers(seen, u)
            tr._refresh(tr._R)
        t = tick("marker gather, NaN masking", t)
        R, c = tr._R, tr._c
        X = np.empty((L, 12))
        last, it = np.inf, 0
        while True:
            it += 1
            X[:, :9] = R.reshape(L, 9)
            X[:, 9:] = c
            res = tr._M @ X.reshape(-1) - tr._Y
            t = tick("residuals", t)
            gX = (tr._MT @ (tr._W * res)).reshape(L, 12)
            a = np.swapaxes(gX[:, :9].reshape(L, 3, 3), -1, -2) @ R
            G = np.concatenate([a.reshape(L, 9) @ tr._V, (gX[:, None, 9:] @ R)[:, 0]], 1)
            t = tick("Jacobian^T residual (gradient)", t)
            x = dpotrs(tr._chol, G.reshape(-1), lower=False)[0].reshape(L, 6)
            t = tick("solve (Cholesky factor reused)", t)
            c = c - (R @ x[:, 3:, None])[..., 0]
            sq = np.sqrt((x * x).reshape(L, 2, 3).sum(-1))
            R = R @ _cayley_neg(x[:, :3], sq[:, 0])
            step = float((sq * tr._lever).sum(1).max())
            rate = step / last
            t = tick("pose update on SO(3), convergence test", t)
            if step <= tr.tolerance or 0.0 < rate < 1.0 and rate * step <= (1.0 - rate) * tr.tolerance \
                    or it >= tr.max_iterations:
                break
            last = step
            tr._refresh(R)
            t = tick("normal equations + Cholesky factor", t)
        iters.append(it)
        rms = tr._own_rms(y, seen)
        tr._R, tr._c = R, c
        trans = c - (R @ tr._c0[..., None])[..., 0]
        t = tick("limb fit RMS (quality)", t)
        solver._global.remember(R, c)
        res = solver._joints_from_limbs(f[None], R[None], trans[None], tr._all_valid[None], rms[None],
                                        tr._own[2][None], tr._own[2][None])[0]
        t = tick("joint centres, qualities, bone lengths", t)
        solver._temporal(res.joints, res.joint_quality, solver._time(None))
        solver._frame += 1
        tick("gap filling", t)
    total = sum(spent.values())
    print(f"live global frame, stage by stage (numpy tracker, {n} frames, {np.mean(iters):.2f} "
          f"iterations a frame, CPU time) [{_load()}]:")
    for name, s in spent.items():
        print(f"  {name:<42} {1e6 * s / n:7.1f} us  {100 * s / total:4.0f} %")
    print(f"  {'total':<42} {1e6 * total / n:7.1f} us  ({n / total:.0f} frames/s)")


def live_global_convergence(model, frames: np.ndarray) -> None:
    """Iterations and the point motion left when each live global frame stopped (compiled)."""
    solver = FrameSolver(model, fit="global")
    tr, gf = solver._tracker, solver._global
    track, its, left, marker_rms, joint_gap = tr.track, [], [], [], []

    def spy(markers):
        out = track(markers)
        its.append(0 if out is None else out.iterations)
        if out is not None:
            left.append(tr.buffers.work.info.copy())
            # The optimum reached: markers' distance to their fitted places, joints' two sides apart.
            lay = tr.buffers.lay
            y = markers[lay.idx0]
            seen = np.isfinite(y).all(-1) & (lay.pad > 0)
            d = np.linalg.norm(lay.a @ np.swapaxes(out.rot, -1, -2) + out.centroid[:, None] - y, axis=-1)
            marker_rms.append(np.sqrt(np.mean(d[seen] ** 2)))
            qa = (out.rot[gf._ja] @ gf._p_a[..., None])[..., 0] + out.centroid[gf._ja]
            qb = (out.rot[gf._jb] @ gf._p_b[..., None])[..., 0] + out.centroid[gf._jb]
            joint_gap.append(np.linalg.norm(qa - qb, axis=-1).max())
        return out

    tr.track = spy
    for f in frames:
        solver.step(f)
    its_a, info = np.array(its), np.array(left)
    hist = ", ".join(f"{k}: {v}" for k, v in enumerate(np.bincount(its_a)) if k and v)
    print(f"live global fit, {len(its_a)} frames: {np.count_nonzero(its_a == 0)} from the batch fit "
          f"(tracker declined or not started), iterations {hist}; last step's point motion median "
          f"{1e6 * np.median(info[:, 0]):.2f} um (max {1e6 * info[:, 0].max():.2f}), estimated distance "
          f"to the optimum median {1e6 * np.median(info[:, 1]):.3f} um (max {1e6 * info[:, 1].max():.2f}; "
          f"tolerance {1e6 * tr.tolerance:.0f} um)")
    print(f"  at the optimum: marker residual RMS median {1000 * np.median(marker_rms):.3f} mm, joints' two "
          f"sides apart at most {1000 * np.median(joint_gap):.3f} mm a frame (median; max {1000 * np.max(joint_gap):.3f})")


def live_compiled_stages(model, frames: np.ndarray) -> None:
    """Where a compiled live global frame's time goes (CPU time, us per frame)."""
    solver = FrameSolver(model, fit="global")
    clock = time.thread_time
    spent = {"global fit kernel (track_frame) + result": 0.0, "joint centres (joint kernel) + result": 0.0,
             "gap filling": 0.0}
    wrapped = []
    for obj, attr, name in ((solver._tracker, "track", "global fit kernel (track_frame) + result"),
                            (solver, "_joints_from_limbs", "joint centres (joint kernel) + result"),
                            (solver, "_temporal", "gap filling")):
        fn = getattr(obj, attr)

        def timed(*a, _fn=fn, _name=name):
            t0 = clock()
            out = _fn(*a)
            spent[_name] += clock() - t0
            return out

        setattr(obj, attr, timed)
        wrapped.append((obj, attr))
    solver.step(frames[0])
    for k in spent:
        spent[k] = 0.0
    t0 = clock()
    for f in frames[1:]:
        solver.step(f)
    total = clock() - t0
    n = len(frames) - 1
    spent["rest of FrameSolver.step (Python)"] = total - sum(spent.values())
    print(f"live global frame, stage by stage (compiled, {n} frames, CPU time) [{_load()}]:")
    for name, s_ in spent.items():
        print(f"  {name:<42} {1e6 * s_ / n:7.1f} us  {100 * s_ / total:4.0f} %")
    print(f"  {'total':<42} {1e6 * total / n:7.1f} us  ({n / total:.0f} frames/s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graph-seconds", type=float, default=20.0, help="length of the launched-graph run, s")
    ap.add_argument("--no-graph", action="store_true", help="skip the launched-graph latency")
    opts = ap.parse_args()
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
    ps = cap.phase_slice("performance")
    print_context("0 (SyntheticActor kiip_full_body seed 0, 1 mm noise)",
                  f"the synthetic actor ({sk.name}, {cap.rate:g} Hz, 120 s session)",
                  f"calibration: the base and gym (frames 0-{len(gym) - 1}) repeated to 7200 frames; live rates and "
                  f"stage timings: the first {n_live} performance frames (frames {ps.start}-{ps.start + n_live - 1}); "
                  f"live convergence, batch and accuracy: every performance frame ({ps.start}-{ps.stop - 1}, "
                  f"{len(perf)} frames)", section="solver, calibration")

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
    # The global fit beside the segment-wise one, measured in the same run (ratio = cost of the fit).
    print(f"live step, CPU time and wall time, best of 3 x {n_live} frames [{_load()}]:")
    rates = {}
    for name, kw in (("segment-wise, numpy", dict(compiled=False)), ("segment-wise, compiled", {}),
                     ("global, numpy reference", dict(fit="global", compiled=False)),
                     ("global, compiled kernels", dict(fit="global"))):
        rates[name] = cpu, wall = _rates(lambda: live(**kw), n_live)
        print(f"  {name:<26} {cpu:7.0f} frames/s CPU, {wall:7.0f} wall  [{_load()}]")
    g, gn, sg = rates["global, compiled kernels"][0], rates["global, numpy reference"][0], rates["segment-wise, compiled"][0]
    print(f"  global compiled: {g / gn:.2f}x its numpy reference, {g / sg:.2f}x the segment-wise fit (target 2000 frames/s)")
    live_global_convergence(model, perf)
    live_compiled_stages(model, perf[:n_live])
    live_global_stages(model, perf[:n_live])
    seg_b = _rate(lambda: FrameSolver(model).solve(perf), n)
    glob_b = _rate(lambda: FrameSolver(model, fit="global").solve(perf), n)
    print(f"batch solve, global fit:          {glob_b:8.0f} frames/s (segment-wise {seg_b:.0f}, ratio {glob_b / seg_b:.2f})")
    truth = cap.joint_centres[cap.phase_slice("performance")]
    one_step = GlobalFitOptions(iterations=1)
    for name, solver, how in (("segment", FrameSolver(model), "batch"),
                              ("global", FrameSolver(model, fit="global"), "batch, converged"),
                              ("global", FrameSolver(model, fit="global", global_options=one_step),
                               "batch, one step from the segment-wise fit (the first version)"),
                              ("global", FrameSolver(model, fit="global"), "live, tracked from the last frame, compiled"),
                              ("global", FrameSolver(model, fit="global", compiled=False),
                               "live, tracked from the last frame, numpy reference")):
        if how.startswith("live"):
            joints = np.array([solver.step(f).joints for f in perf])
        else:
            joints = solver.solve(perf).joints
        e = np.linalg.norm(joints - truth, axis=-1)
        print(f"accuracy, {name:<8} fit vs ground truth: mean {1000 * e.mean():.2f} mm, max {1000 * e.max():.2f} mm ({how})")
    if not opts.no_graph:
        graph_latency(opts.graph_seconds)


if __name__ == "__main__":
    main()
