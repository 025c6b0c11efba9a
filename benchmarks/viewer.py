"""Viewer benchmark: a 240 Hz, 60-marker graph feeding the visualizer, drawn in headless Chromium.

Prints frames drawn per second by the page (the three.js stage), WebSocket bundles per second
delivered (page and server side), and the bus-side cost of the visualizer node in CPU % of one
core, with no browser and with one browser connected (target under 15 %), beside the figures of the
hand-written WebGL page it replaced (PREVIOUS); then the same with a character added to the graph
(a 60 Hz CharacterPose drawn as a skinned avatar). Also compares the wire encodings (binary bundle
vs JSON of ``to_dict``) for one marker frame.

    .venv/bin/python benchmarks/viewer.py [--seconds 10] [--rate 240] [--markers 60] [--no-avatar]

Needs Debian's chromium (/usr/bin/chromium) and Playwright for Python.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
import uuid
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _context import print_context  # noqa: E402

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"]


PERFORMER = "mocapgraph.testing.viewer_nodes:StagePerformer"
CHARACTER = f"""  - name: carol
    type: {PERFORMER}
    params: {{actor: carol, rate_hz: 60.0, publish: [character], center: [-1.0, 1.0], radius: 0.8}}
"""
#: the hand-written WebGL page (before three.js), this benchmark's figures then (issue 29): fps, CPU %
PREVIOUS = (49.0, 6.8)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def cpu_percent(pid: int, seconds: float) -> float:
    c0, t0 = cpu_seconds(pid), time.monotonic()
    time.sleep(seconds)
    return 100 * (cpu_seconds(pid) - c0) / (time.monotonic() - t0)


def encoding_figures(n_markers: int) -> None:
    from mocapgraph.messages import Envelope, MarkerFrame
    from mocapgraph.viewer.wire import build_bundle, encode_record

    rng = np.random.default_rng(0)
    pos = rng.normal(size=(n_markers, 3))
    pos[::11] = np.nan
    msg = MarkerFrame(frame_number=1, rate_hz=240.0, positions=pos, valid=np.isfinite(pos[:, 0]),
                      residual=np.full(n_markers, 0.001, np.float32))
    env = Envelope("markers", "MarkerFrame", 1, 1, time.time_ns(), time.time_ns(), "pattern", False)
    reps = 2000
    t0 = time.perf_counter()
    for _ in range(reps):
        binary = build_bundle([encode_record("markers", "k", env, msg)], 0.0)
    t_bin = (time.perf_counter() - t0) / reps
    t0 = time.perf_counter()
    for _ in range(reps):
        text = json.dumps(msg.to_dict()).encode()  # NaN is not even valid JSON for a browser
    t_json = (time.perf_counter() - t0) / reps
    print(f"wire, one {n_markers}-marker frame: binary bundle {len(binary)} B in {t_bin * 1e6:.0f} us; "
          f"JSON of to_dict {len(text)} B in {t_json * 1e6:.0f} us")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="measuring time per phase, s")
    ap.add_argument("--rate", type=float, default=240.0, help="marker rate, Hz")
    ap.add_argument("--markers", type=int, default=60, help="markers per frame")
    ap.add_argument("--no-avatar", action="store_true", help="skip the run with a character drawn as an avatar")
    args = ap.parse_args()
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        print("needs Playwright for Python (pip install playwright)", file=sys.stderr)
        return 2
    if not Path(CHROMIUM).exists():
        print(f"needs Debian's chromium at {CHROMIUM}", file=sys.stderr)
        return 2

    print_context("0 (np.random.default_rng: positions N(0, 1), every 11th marker NaN)",
                  f"one generated {args.markers}-marker MarkerFrame", "the same frame, 2000 encodings each way",
                  section="wire encoding")
    encoding_figures(args.markers)
    code = measure(args, avatar=False)
    if code == 0 and not args.no_avatar:
        code = measure(args, avatar=True)
    return code


def measure(args: argparse.Namespace, avatar: bool) -> int:
    """One graph (with a character drawn as an avatar or not), 10 s without and with a browser."""
    from playwright.sync_api import sync_playwright

    tmp = Path(tempfile.mkdtemp(prefix="viewer-bench-"))
    port = free_port()
    graph = tmp / "graph.yaml"
    graph.write_text(f"""
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: {args.rate}, n_markers: {args.markers}, missing_every: 10}}
{CHARACTER if avatar else ""}  - name: viz
    type: visualizer
    params: {{port: {port}}}
""")
    env = dict(os.environ, MOCAPGRAPH_MASTER=f"ipc://{tmp / ('master-' + uuid.uuid4().hex[:6])}", PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "launch", str(graph)], env=env, cwd=tmp,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True).start()
    try:
        t_end = time.monotonic() + 30
        while not any("nodes ready" in x for x in lines):
            if time.monotonic() > t_end or proc.poll() is not None:
                print("".join(lines), file=sys.stderr)
                return 1
            time.sleep(0.05)
        from mocapgraph.bus.manifest import fetch_manifest

        pid = next(n["pid"] for n in fetch_manifest(env["MOCAPGRAPH_MASTER"])["nodes"] if n["name"] == "viz")
        url = next(x.split("viewer at ", 1)[1].split()[0] for x in lines if "viewer at " in x)  # carries the token
        stats_url = url.replace("/?", "/stats?")
        time.sleep(1.0)
        print_context(None, f"the marker_test_pattern node (deterministic circles), {args.markers} markers at "
                      f"{args.rate:g} Hz, marker 0 missing every 10th frame", f"{args.seconds:g} s without a browser, "
                      f"then {args.seconds:g} s with one (after its first drawn frame + 2 s)"
                      + ("; plus a 60 Hz character (StagePerformer) drawn as a skinned avatar" if avatar else ""),
                      section="graph with an avatar" if avatar else "graph")
        time.sleep(1.0)
        idle = cpu_percent(pid, args.seconds)
        print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}; graph: {args.markers} markers at "
              f"{args.rate:.0f} Hz; visualizer node pid {pid}")
        print(f"visualizer CPU, no browser:  {idle:5.1f} % of one core")

        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1280, "height": 720})
            page.goto(url)
            page.wait_for_function("() => window.mocapgraphStats && window.mocapgraphStats.markersDrawn > 0"
                                   + (" && window.mocapgraphStats.avatarsDrawn > 0" if avatar else ""), timeout=30000)
            time.sleep(2.0)

            def sample():
                s = page.evaluate("() => ({f: mocapgraphStats.framesDrawn, b: mocapgraphStats.bundles, "
                                  "r: mocapgraphStats.records})")
                with urllib.request.urlopen(stats_url) as r:
                    c = json.loads(r.read())["clients"][0]
                return s["f"], s["b"], s["r"], c["bundles"], c["bytes"], time.monotonic()

            f0, b0, r0, sb0, by0, t0 = sample()
            busy = cpu_percent(pid, args.seconds)
            f1, b1, r1, sb1, by1, t1 = sample()
            dt = t1 - t0
            renderer = page.evaluate("mocapgraphStats.webgl")
            revision = page.evaluate("mocapgraphStats.three")
            browser.close()
        what = "markers + a character as a skinned avatar" if avatar else "markers only"
        print(f"visualizer CPU, one browser: {busy:5.1f} % of one core (target < 15 %): "
              f"{'OK' if busy < 15 else 'OVER'}  [{what}]")
        print(f"page frames drawn: {(f1 - f0) / dt:6.1f} /s  (three.js r{revision}, {renderer})")
        if not avatar:
            print(f"previous page (hand-written WebGL, same graph): {PREVIOUS[0]:.0f} frames/s, visualizer "
                  f"{PREVIOUS[1]:.1f} % CPU with one browser")
        print(f"WebSocket bundles: {(b1 - b0) / dt:6.1f} /s received by the page, {(sb1 - sb0) / dt:6.1f} /s sent, "
              f"{(r1 - r0) / dt:.0f} records/s, {(by1 - by0) / dt / 1024:6.1f} KiB/s (newest state at the browser's "
              "pace, at most max_rate_hz)")
        return 0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)


if __name__ == "__main__":
    sys.exit(main())
