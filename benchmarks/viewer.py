"""Viewer benchmark: a 240 Hz, 60-marker graph feeding the visualizer, drawn in headless Chromium.

Prints frames drawn per second in the page, WebSocket bundles (messages) per second delivered
and the records they carried, and the bus-side cost of the visualizer node as CPU % of one core
(target under 15 %), beside the same node with no browser attached (its idle cost).

Usage: python benchmarks/viewer.py [--seconds 10]  (needs Debian's chromium and playwright)
"""
from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
        "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process, from /proc."""
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    a = ap.parse_args()
    from playwright.sync_api import sync_playwright

    from mocapgraph.launch.manifest import fetch_manifest

    tmp = Path(tempfile.mkdtemp())
    port = free_port()
    graph = tmp / "viewer_bench.yaml"
    graph.write_text(f"""
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 240.0, n_markers: 60, missing_every: 10}}
  - name: viz
    type: visualizer
    params: {{port: {port}}}
""")
    master = f"ipc://{tmp / 'master'}"
    env = dict(os.environ, MOCAPGRAPH_MASTER=master)
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "launch", str(graph)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    try:
        for _ in range(200):
            try:
                m = fetch_manifest(master, 0.2)
                if all(n["pid"] for n in m["nodes"]):
                    break
            except Exception:  # noqa: BLE001 - not up yet
                time.sleep(0.05)
        time.sleep(1.5)
        viz = next(n["pid"] for n in m["nodes"] if n["name"] == "viz")
        c0, t0 = cpu_s(viz), time.monotonic()
        time.sleep(a.seconds / 2)
        idle = (cpu_s(viz) - c0) / (time.monotonic() - t0) * 100
        print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}; graph: 240 Hz, 60 markers")
        print(f"visualizer node, no browser:   {idle:5.1f} % of one core (receiving 240 msg/s + diagnostics)")
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
            page = browser.new_page(viewport={"width": 1280, "height": 760})
            page.goto(f"http://127.0.0.1:{port}/")
            page.wait_for_function("() => window.mocapgraphStats && window.mocapgraphStats.framesDrawn > 10",
                                   timeout=20000)
            s0 = page.evaluate("() => ({...window.mocapgraphStats})")
            c0, t0 = cpu_s(viz), time.monotonic()
            time.sleep(a.seconds)
            s1 = page.evaluate("() => ({...window.mocapgraphStats})")
            dt = time.monotonic() - t0
            busy = (cpu_s(viz) - c0) / dt * 100
            browser.close()
        fps = (s1["framesDrawn"] - s0["framesDrawn"]) / dt
        bundles = (s1["bundles"] - s0["bundles"]) / dt
        records = (s1["records"] - s0["records"]) / dt
        mbps = (s1["bytes"] - s0["bytes"]) / dt / 1e6
        print(f"headless Chromium (SwiftShader): {fps:5.1f} frames drawn/s")
        print(f"WebSocket: {bundles:5.1f} bundles/s delivered ({records:.0f} records/s, {mbps:.2f} MB/s; "
              f"the node sends the newest state at the browser's pace, at most 60/s)")
        print(f"visualizer node with the page:  {busy:5.1f} % of one core (target < 15 %): "
              f"{'OK' if busy < 15 else 'OVER'}")
    finally:
        proc.send_signal(2)
        proc.wait(20)


if __name__ == "__main__":
    main()
