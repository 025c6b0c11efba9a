"""The osc_outlet node in a real graph, received by a real python-osc server: per-joint addresses,
positions equal to the ActorPose a topic_logger saw for the same frame, unit rotations, quality
codes, missing joints left out; characters on their own addresses."""
from __future__ import annotations

import threading

import numpy as np
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import ThreadingOSCUDPServer

from graph_helpers import read_jsonl, wait_until
from eco_support import JOINT_NAMES, STAGE_PERFORMER


class Receiver:
    """A python-osc UDP server on a free loopback port, keeping every message it handles, in order."""

    def __init__(self) -> None:
        self.messages: list[tuple[str, tuple]] = []
        disp = Dispatcher()
        disp.set_default_handler(lambda address, *args: self.messages.append((address, args)))
        # not threading: one handler thread keeps each bundle's messages together and in order
        from pythonosc.osc_server import BlockingOSCUDPServer
        self.server = BlockingOSCUDPServer(("127.0.0.1", 0), disp)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def _bundles(msgs, base):
    """Frames of one stream: {frame number: {joint address suffix: args}} (a bundle starts at /frame)."""
    out, cur = {}, None
    for addr, args in msgs:
        if addr == f"{base}/frame":
            cur = out.setdefault(args[0], {})
        elif addr.startswith(base + "/") and cur is not None:
            cur[addr[len(base) + 1:]] = args
        elif not addr.startswith(base + "/"):
            cur = None
    return out


def test_joint_messages_reach_a_real_osc_server(launch_graph, tmp_path):
    rx = Receiver()
    log = tmp_path / "poses.jsonl"
    try:
        g = launch_graph(f"""
nodes:
  - name: performer
    type: {STAGE_PERFORMER}
    params: {{actor: ann, rate_hz: 60.0, publish: [actor, character], nan_joint: 6}}
  - name: osc
    type: osc_outlet
    params: {{port: {rx.port}, prefix: lab}}
  - name: log
    type: topic_logger
    params: {{path: "{log}", topics: [actor_pose]}}
""")
        g.wait_ready()
        # 2.5 s: joint 6 (l_wrist) is NaN on odd seconds, so both cases are seen
        # (both streams: the character's bundle of a frame may come after the actor's)
        wait_until(lambda: min(sum(a == f"/lab/{k}/ann/frame" for a, _ in rx.messages) for k in ("actor", "character"))
                   >= 150, 20, "OSC frames of the actor and the character", g)
        g.stop()
    finally:
        rx.close()
    msgs = list(rx.messages)
    actor = _bundles(msgs, "/lab/actor/ann")
    character = _bundles(msgs, "/lab/character/ann")
    assert len(actor) >= 150 and len(character) >= 150
    for frame in list(actor.values())[:5]:
        for j in JOINT_NAMES:
            assert f"{j}/quality" in frame
    logged = {r["msg"]["frame_number"]: r["msg"] for r in read_jsonl(log, "actor_pose")}
    checked = missing_seen = 0
    for n, frame in actor.items():
        rec = logged.get(n)
        if rec is None:
            continue
        q = [frame[f"{j}/quality"][0] for j in JOINT_NAMES]
        assert q == rec["joint_quality"]
        for j, name in enumerate(JOINT_NAMES):
            want = rec["joint_positions"][j]
            # missing (the log writes NaN): flagged 0, never sent as a position (no 0,0,0, no NaN)
            if want[0] is None or want[0] != want[0]:
                assert q[j] == 0 and f"{name}/position" not in frame and f"{name}/rotation" not in frame
                missing_seen += 1
            else:
                np.testing.assert_allclose(frame[f"{name}/position"], want, atol=1e-5)  # float32 on the wire
                rot = frame.get(f"{name}/rotation")  # left out where the limb's rotation is unknown
                assert rot is None or abs(np.linalg.norm(rot) - 1) < 1e-5
        checked += 1
    print(f"\nOSC: {len(msgs)} messages; {checked} actor frames equal to the logged ActorPose, "
          f"{missing_seen} missing joints left out; {len(character)} character frames")
    assert checked >= 100 and missing_seen > 0
    for c in character.values():  # a character joint is good where it has a position, missing where not
        for j in JOINT_NAMES:
            assert c[f"{j}/quality"] == ((2,) if f"{j}/position" in c else (0,)) and len(c[f"{j}/rotation"]) == 4
    assert any("l_wrist/position" not in c for c in character.values())
