"""Per-frame cost of the outputs to other tools, each beside the straightforward way in the same run.

Prints: a marker frame as a foxglove.SceneUpdate, our vectorised protobuf records against the
official SDK's message objects (one SpherePrimitive per marker); an actor frame as an OSC bundle,
our python-osc template filled with numpy against building every message with python-osc's
builders; a bag exported to Foxglove, frames per second; and a launched graph (test pattern at
240 Hz -> foxglove_bridge) seen by a WebSocket client: frames received, capture-to-client latency,
and the bridge's CPU with the client subscribed beside without one. Compare ratios, not times.
Run: .venv/bin/python benchmarks/outlets.py [--markers 40 100] [--joints 16 60] [--graph-seconds 10]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from mocapgraph.bag.foxglove_scene import SEEN, UNSEEN, SceneBuilder
from mocapgraph.formats.osc_frames import JointBundle
from mocapgraph.messages import MarkerFrame
from mocapgraph.messages.codec import Envelope

from _context import print_context


def _per_call(fn, n: int) -> float:
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for i in range(n):
            fn(i)
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def scene(n_markers: int) -> None:
    import foxglove.messages as fm

    rng = np.random.default_rng(0)
    p = rng.normal(size=(n_markers, 3))
    valid = rng.random(n_markers) > 0.1
    msg = MarkerFrame(frame_number=1, rate_hz=240.0, positions=p, valid=valid, residual=np.zeros(n_markers, "f4"))
    env = Envelope("markers", "MarkerFrame", 1, 1, 10**18, 10**18, "bench", False)
    b = SceneBuilder()
    ours = _per_call(lambda i: b.feed(env, msg), 2000)

    def sdk(i: int) -> bytes:
        sp = [fm.SpherePrimitive(pose=fm.Pose(position=fm.Vector3(x=x, y=y, z=z), orientation=fm.Quaternion(w=1.0)),
                                 size=fm.Vector3(x=0.018, y=0.018, z=0.018),
                                 color=fm.Color(r=c[0], g=c[1], b=c[2], a=c[3]))
              for (x, y, z), c in zip(p.tolist(), [SEEN if v else UNSEEN for v in valid])]
        return fm.SceneUpdate(entities=[fm.SceneEntity(id="markers", frame_id="world", spheres=sp)]).encode()

    theirs = _per_call(sdk, 300)
    print(f"SceneUpdate, {n_markers:3d} markers: ours {ours * 1e6:7.1f} us/frame, SDK objects "
          f"{theirs * 1e6:7.1f} us/frame  -> {theirs / ours:5.1f}x; at 240 Hz ours is "
          f"{100 * ours * 240:.2f} % of a core")


def osc(n_joints: int) -> None:
    from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
    from pythonosc.osc_message_builder import OscMessageBuilder

    names = [f"joint{j}" for j in range(n_joints)]
    rng = np.random.default_rng(1)
    pos, rot, q = rng.normal(size=(n_joints, 3)), rng.normal(size=(n_joints, 4)), np.full(n_joints, 2)
    bundle = JointBundle("mocap", "actor", "ann", names)
    ours = _per_call(lambda i: bundle.encode(i, pos, rot, q, 1.0), 2000)

    def plain(i: int) -> bytes:
        bb = OscBundleBuilder(IMMEDIATELY)
        m = OscMessageBuilder("/mocap/actor/ann/frame")
        m.add_arg(i)
        bb.add_content(m.build())
        for j, n in enumerate(names):
            for kind, vals in (("position", pos[j]), ("rotation", rot[j])):
                m = OscMessageBuilder(f"/mocap/actor/ann/{n}/{kind}")
                for v in vals.tolist():
                    m.add_arg(v, "f")
                bb.add_content(m.build())
            m = OscMessageBuilder(f"/mocap/actor/ann/{n}/quality")
            m.add_arg(int(q[j]))
            bb.add_content(m.build())
        return bb.build().dgram

    theirs = _per_call(plain, 200)
    print(f"OSC bundle, {n_joints:3d} joints: ours {ours * 1e6:7.1f} us/frame, python-osc builders "
          f"{theirs * 1e6:7.1f} us/frame  -> {theirs / ours:5.1f}x")


def export(frames: int) -> None:
    from mocapgraph.bag.foxglove_export import export_foxglove
    from mocapgraph.bag.writer import BagWriter

    with tempfile.TemporaryDirectory() as d:
        src = Path(d) / "b.mcap"
        rng = np.random.default_rng(2)
        with BagWriter(src) as w:
            for t in range(frames):
                w.write("markers", MarkerFrame(frame_number=t, rate_hz=240.0, positions=rng.normal(size=(60, 3)),
                                               valid=np.ones(60, bool), residual=np.zeros(60, "f4")),
                        seq=t + 1, capture_ns=10**9 + t * 4_166_667)
        t0 = time.perf_counter()
        export_foxglove(src, Path(d) / "f.mcap")
        dt = time.perf_counter() - t0
    print(f"export-foxglove: {frames} frames of 60 markers in {dt:.2f} s = {frames / dt:,.0f} frames/s "
          f"({frames / dt / 240:.0f}x a 240 Hz capture)")


BRIDGE_GRAPH = """\
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 240.0, n_markers: {n}}}
  - name: fox
    type: foxglove_bridge
    params: {{port: 0, token: bench}}
"""


def bridge(seconds: float, n_markers: int = 60) -> None:
    """Frames and latency a Foxglove client sees, and the bridge's CPU with and without it."""
    import asyncio
    import json
    import os
    import re
    import signal
    import struct
    import subprocess
    import sys

    import websockets

    with tempfile.TemporaryDirectory() as tmp:
        graph = Path(tmp) / "graph.yaml"
        graph.write_text(BRIDGE_GRAPH.format(n=n_markers))
        proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "launch", str(graph)],
                                env=dict(os.environ, MOCAPGRAPH_MASTER=f"ipc://{tmp}/master", PYTHONUNBUFFERED="1"),
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
        try:
            url = None
            for line in proc.stdout:
                m = re.search(r"foxglove bridge at (ws://\S+)", line)
                if m:
                    url = m.group(1)
                    break
            if url is None:
                raise SystemExit("the bridge did not start")

            async def run() -> tuple[list[float], list[float], list[float], int]:
                async with websockets.connect(url, subprotocols=["foxglove.websocket.v1"], max_size=None) as ws:
                    channels: dict[str, int] = {}
                    while not {"/markers", "/diagnostics/fox"} <= set(channels):
                        msg = json.loads(await ws.recv())
                        if msg["op"] == "advertise":
                            channels.update({c["topic"]: c["id"] for c in msg["channels"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": 2, "channelId": channels["/diagnostics/fox"]}]}))
                    cpu: list[float] = []   # bridge CPU % per diagnostics window

                    async def gather(with_markers: bool, until: float) -> tuple[list[float], int]:
                        lat, frames, last = [], 0, None
                        while time.monotonic() < until:
                            m = await ws.recv()
                            if isinstance(m, str):
                                continue
                            sub, stamp = struct.unpack_from("<IQ", m, 1)
                            if sub == 2:
                                d = json.loads(m[13:])
                                if last is not None and d["uptime_s"] > last[0]:
                                    cpu.append(100 * (d["cpu_s"] - last[1]) / (d["uptime_s"] - last[0]))
                                last = (d["uptime_s"], d["cpu_s"])
                            else:
                                frames += 1
                                lat.append((time.time_ns() - stamp) / 1e6)
                        return lat, frames

                    await gather(False, time.monotonic() + min(seconds, 4.0))
                    idle = list(cpu)
                    cpu.clear()
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": 1, "channelId": channels["/markers"]}]}))
                    await gather(True, time.monotonic() + 1.0)  # warm-up
                    cpu.clear()
                    lat, frames = await gather(True, time.monotonic() + seconds)
                    return idle, cpu, lat, frames

            idle, busy, lat, frames = asyncio.run(run())
        finally:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(10)
    lat_a = np.asarray(lat)
    print(f"foxglove_bridge, 240 Hz x {n_markers} markers, {seconds:g} s: {frames} scenes at the client "
          f"({frames / seconds:.0f}/s); capture -> client median {np.median(lat_a):.2f} ms, "
          f"p99 {np.percentile(lat_a, 99):.2f} ms")
    print(f"  bridge CPU: {np.median(idle):.1f} % of a core with nobody subscribed to /markers, "
          f"{np.median(busy):.1f} % with a client  ->  {np.median(busy) / max(np.median(idle), 1e-3):.1f}x")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--markers", type=int, nargs="+", default=[40, 100])
    ap.add_argument("--joints", type=int, nargs="+", default=[16, 60])
    ap.add_argument("--export-frames", type=int, default=10000)
    ap.add_argument("--graph-seconds", type=float, default=10.0, help="launched bridge run, s (0 skips it)")
    a = ap.parse_args()
    print_context("0 (np.random.default_rng: positions N(0, 1), about 10 % of markers invalid)",
                  f"one generated MarkerFrame per size ({', '.join(map(str, a.markers))} markers)",
                  "the same frame every call; best of 3 x 2000 calls (SDK: 3 x 300)", section="SceneUpdate")
    for n in a.markers:
        scene(n)
    print_context("1 (np.random.default_rng: positions and rotations N(0, 1))",
                  f"one generated actor frame per size ({', '.join(map(str, a.joints))} joints)",
                  "the same frame every call; best of 3 x 2000 calls (python-osc: 3 x 200)", section="OSC")
    for n in a.joints:
        osc(n)
    print_context("2 (np.random.default_rng: positions N(0, 1))",
                  f"a generated bag of {a.export_frames} MarkerFrames of 60 markers at 240 Hz", "every frame, once",
                  section="export-foxglove")
    export(a.export_frames)
    if a.graph_seconds > 0:
        print_context(None, "the marker_test_pattern node (deterministic circles), 240 Hz x 60 markers",
                      f"diagnostics windows for up to 4 s unsubscribed, 1 s warm-up, then {a.graph_seconds:g} s "
                      "of scenes", section="foxglove_bridge")
        bridge(a.graph_seconds)


if __name__ == "__main__":
    main()
