"""Markerless capture speed: the pose estimator per camera, and triangulating four cameras.

On ONE core (the process pinned to CPU 0), on the Pose2Sim demo (../shared/data/video/pose2sim_demo):

1. decoding (OpenCV/FFmpeg) and the estimator (mediapipe 0.10.14, full model, tracking between
   frames) per frame at the demo resolution (1088x1920 portrait, 60 fps) for each camera:
   frames/s and the real-time factor for a 30 fps and a 60 fps camera;
2. the estimator alone at 640x480 (each demo frame scaled to 480 rows and centred on a 640x480
   canvas, so the person is in it as a webcam would see them; a live camera hands over decoded
   frames): can one core keep up with a live 30 fps camera?
3. triangulation of the four cameras' 33 landmarks: per frame one call (the live path) and per
   frame of a whole-clip batch (the node's load path), in microseconds;
4. first, on every core: four live cameras (graph_configs/multiview_live.yaml, four
   ``video_camera_reader`` processes streaming the demo as if live, ``multiview_live``
   triangulating), at 30 fps (every second frame, real time) and at a quarter of that: per camera
   frames estimated / skipped and the estimator's cost, the frame groups with a skeleton.

Usage: ``python benchmarks/video.py [--frames 60] [--no-live]``. Needs the ``video`` extra and ../shared/data.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from _context import print_context

ROOT = Path(__file__).resolve().parents[1]
DEMO = (ROOT / ".." / "shared" / "data" / "video" / "pose2sim_demo").resolve()
CAMS = ("cam01", "cam02", "cam03", "cam04")


def _frames(path: Path, n: int, size: tuple[int, int] | None):
    from mocapgraph.video.frames import VideoFrames, cv2_module
    cv2 = cv2_module()
    out, t0 = [], time.perf_counter()
    with VideoFrames(path) as vf:
        for i, _, f in vf:
            out.append(f)
            if i + 1 >= n:
                break
    decode_ms = 1000 * (time.perf_counter() - t0) / len(out)
    if size:
        w, h = size
        boxed = []
        for f in out:
            s = h / f.shape[0]
            small = cv2.resize(f, (int(round(f.shape[1] * s)), h), interpolation=cv2.INTER_AREA)
            canvas = np.zeros((h, w, 3), np.uint8)
            x0 = (w - small.shape[1]) // 2
            canvas[:, x0:x0 + small.shape[1]] = small
            boxed.append(canvas)
        out = boxed
    return out, decode_ms


def estimator_rate(frames, model: str = "full") -> tuple[float, int]:
    from mocapgraph.video.estimator import PoseEstimator
    est = PoseEstimator(model=model)
    est.process(frames[0])                      # graph start and first detection outside the timing
    found, t0 = 0, time.perf_counter()
    for f in frames[1:]:
        found += est.process(f) is not None
    ms = 1000 * (time.perf_counter() - t0) / (len(frames) - 1)
    est.close()
    return ms, found


def triangulation_cost(reps: int = 200) -> None:
    from mocapgraph.video.capture import cameras_for
    from mocapgraph.video.multiview import triangulate
    cams = cameras_for(DEMO / "Calib.qca.txt", [DEMO / f"{c}.mp4" for c in CAMS])
    rng = np.random.default_rng(0)
    X = rng.normal([0.0, 0.0, 1.0], [0.3, 0.3, 0.5], (33, 3))
    from mocapgraph.video.multiview import project
    uv = np.stack([project(c, X) for c in cams]) + rng.normal(0, 3.0, (4, 33, 2))
    conf = np.full((4, 33), 0.9)
    triangulate(cams, uv, conf)
    t0 = time.perf_counter()
    for _ in range(reps):
        triangulate(cams, uv, conf)
    one = 1e6 * (time.perf_counter() - t0) / reps
    T = 600
    uvT, confT = np.repeat(uv[:, None], T, axis=1), np.repeat(conf[:, None], T, axis=1)
    from mocapgraph.video.multiview import triangulate_frames
    t0 = time.perf_counter()
    triangulate_frames(cams, uvT, confT)
    batch = 1e6 * (time.perf_counter() - t0) / T
    print(f"triangulation, 4 cameras x 33 landmarks (6 camera pairs + the consensus solve): "
          f"{one:.0f} us per frame called alone, {batch:.0f} us per frame in a {T}-frame batch")


def live_cameras(rate_scale: float, every: int) -> None:
    """The four demo videos as four live cameras (real processes), grouped and triangulated."""
    import json
    import signal
    import subprocess
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        log = tmp / "status.jsonl"
        start = np.ceil(time.time()) + 15.0                    # after the launch and the estimators' warm-up
        topics = ["reader_status"] + [f"{c}_status" for c in CAMS]
        (tmp / "g.yaml").write_text(f"""
include:
  - file: {ROOT / "graph_configs" / "multiview_live.yaml"}
    args: {{viewer: false, session_log: {tmp / "s.jsonl"}, rate_scale: {rate_scale}, every: {every}, start_at: {start}}}
nodes:
  - {{name: status_log, type: topic_logger, params: {{path: {log}, topics: {topics}}}}}
""")
        proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "launch", str(tmp / "g.yaml")], cwd=tmp,
                                env=dict(os.environ, MOCAPGRAPH_MASTER=f"ipc://{tmp}/master"),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            last: dict[str, dict] = {}
            t_end = time.time() + 120
            while time.time() < t_end:
                time.sleep(1.0)
                if log.exists():
                    for line in log.read_text().splitlines():
                        r = json.loads(line)
                        last[r["topic"]] = r["msg"]
                done = [last.get(f"{c}_status", {}).get("state") in ("finished", "error") for c in CAMS]
                if all(done) and time.time() > start + 100 / 60 / rate_scale + 2.5:
                    break
        finally:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    fps = 60.0 * rate_scale / every
    print(f"four live cameras at {fps:g} fps (the demo's every {every}. frame at {rate_scale:g} x its speed), "
          f"4 estimator processes + the triangulating node on {os.cpu_count()} cores (load {os.getloadavg()[0]:.1f}):")
    for c in CAMS:
        d = json.loads(last.get(f"{c}_status", {}).get("data_json", "{}"))
        print(f"  {c}: {d.get('read', 0)} frames, {d.get('estimated', 0)} estimated, {d.get('skipped', 0)} skipped, "
              f"estimator {d.get('estimator_ms', float('nan'))} ms, keeps up {d.get('keeps_up', 'n/a')}")
    r = json.loads(last.get("reader_status", {}).get("data_json", "{}"))
    groups = r.get("groups", 0)
    print(f"  multiview_live: {groups} frame groups, {r.get('triangulated', 0)} with a skeleton "
          f"({r.get('triangulated', 0) / max(groups, 1):.0%}), triangulation {r.get('triangulate_ms', float('nan'))} ms "
          f"a group; per camera grouped / missed / lagging: "
          + ", ".join(f"{n} {v['grouped']}/{v['missed']}/{v['lagging']}" for n, v in r.get("cameras", {}).items()))


def heavy_against_full(n: int) -> None:
    """The heavy model's cost beside the full one's, same frames, same run (cam01 at the demo's size)."""
    from mocapgraph.video.pose_models import installed
    if not installed("heavy"):
        print("heavy model: not installed (scripts/setup.sh installs it from npm); not measured")
        return
    frames, _ = _frames(DEMO / f"{CAMS[0]}.mp4", n, None)
    full, _ = estimator_rate(frames, "full")
    heavy, found = estimator_rate(frames, "heavy")
    print(f"heavy model, {CAMS[0]} 1088x1920: estimator {heavy:.1f} ms a frame against the full model's {full:.1f} ms "
          f"in the same run (x{heavy / full:.2f}; person in {found}/{len(frames) - 1}): {1000 / heavy:.1f} fps on one core")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60, help="frames per camera (default 60)")
    ap.add_argument("--no-live", action="store_true", help="leave out the four live cameras")
    a = ap.parse_args()
    if not DEMO.is_dir():
        print(f"skipped: {DEMO} is absent")
        return 0
    try:
        import mediapipe  # noqa: F401
    except ImportError:
        print("skipped: the video extra (mediapipe) is not installed")
        return 0
    print_context(None, f"shared/data/video/pose2sim_demo ({', '.join(CAMS)})", f"first {a.frames} frames")
    if not a.no_live:             # before pinning this process (its children would inherit one core)
        for rate_scale in (1.0, 0.25):
            live_cameras(rate_scale, every=2)
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    print(f"one core ({len(os.sched_getaffinity(0))} CPU in the affinity mask)")
    for label, size in (("1088x1920 (demo)", None), ("640x480", (640, 480))):
        rates = []
        for cam in CAMS:
            frames, dec = _frames(DEMO / f"{cam}.mp4", a.frames, size)
            if size:
                dec = 0.0          # a live camera hands over decoded frames (the demo's decode is not a webcam's)
            ms, found = estimator_rate(frames)
            rates.append(1000.0 / (ms + dec))
            print(f"{label} {cam}: decode {dec:.1f} ms + estimator {ms:.1f} ms a frame = {rates[-1]:.1f} fps "
                  f"(person in {found}/{len(frames) - 1}); real-time factor {rates[-1] / 30:.2f} at 30 fps, "
                  f"{rates[-1] / 60:.2f} at 60 fps")
        worst = min(rates)
        verdict = "keeps up with" if worst >= 30 else f"reaches {worst / 30:.0%} of"
        print(f"{label}: slowest camera {worst:.1f} fps: one core {verdict} a live 30 fps camera")
    heavy_against_full(a.frames)
    triangulation_cost()
    return 0


if __name__ == "__main__":
    sys.exit(main())
