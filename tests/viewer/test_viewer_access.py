"""The viewer refuses strangers (no token, a foreign Origin or Host), checks command arguments,
limits command rate; the bag player answers bad commands with an error and plays on."""
from __future__ import annotations

import asyncio
import json
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
import zmq

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "viewer"))
from viewer_support import BusTap, free_port, run_async, viewer_url, wait_until, ws_url  # noqa: E402

from mocapgraph.messages import NodeCommand  # noqa: E402
from mocapgraph.messages.codec import encode  # noqa: E402

websockets_client = pytest.importorskip("websockets.asyncio.client")
from websockets.exceptions import InvalidStatus  # noqa: E402


def _small_bag(path: Path) -> None:
    import numpy as np

    from mocapgraph.bag.writer import BagWriter
    from mocapgraph.messages import MarkerFrame

    with BagWriter(str(path)) as w:
        for i in range(240):
            w.write("markers", MarkerFrame(frame_number=i, rate_hz=120.0, positions=np.zeros((4, 3)),
                                           valid=np.ones(4, bool), residual=np.zeros(4, np.float32)),
                    seq=i + 1, capture_ns=int(i * 1e9 / 120))


def _status(code_or_exc) -> int:
    return code_or_exc.response.status_code if isinstance(code_or_exc, InvalidStatus) else -1


def test_strangers_are_refused_and_bad_commands_answered(launch_graph, tmp_path) -> None:
    bag = tmp_path / "b.mcap"
    _small_bag(bag)
    port = free_port()
    cmd_ep = f"ipc://{tmp_path / 'cmd'}"
    cmd_pub = zmq.Context.instance().socket(zmq.PUB)
    cmd_pub.bind(cmd_ep)
    g = launch_graph(f"""
external:
  - {{topic: player_command, type: NodeCommand, endpoint: "{cmd_ep}"}}
nodes:
  - name: player
    type: bag_player
    params: {{file: "{bag}", loop: true}}
  - name: viz
    type: visualizer
    params: {{port: {port}}}
""")
    g.wait_ready()
    url = viewer_url(g)
    assert "token=" in url
    base = f"ws://127.0.0.1:{port}/ws"
    tap = BusTap(g.master, ["player_status", "markers"])

    async def refused(uri: str, **headers) -> int:
        try:
            async with websockets_client.connect(uri, additional_headers=headers or None):
                return 101
        except InvalidStatus as exc:
            return _status(exc)

    async def run() -> dict:
        out = {
            "no_token": await refused(base),
            "wrong_token": await refused(base + "?token=guess"),
            "foreign_origin": await refused(ws_url(url), Origin="http://evil.example"),
            "rebound_host": await refused(ws_url(url), Host=f"evil.example:{port}"),
            "same_origin": await refused(ws_url(url), Origin=f"http://127.0.0.1:{port}"),
        }
        async with websockets_client.connect(ws_url(url)) as ws:
            await ws.recv()  # hello
            bad = [{"channel": "player", "command": "seek", "args": {}},
                   {"channel": "player", "command": "seek", "args": {"position_s": 1e308}},
                   {"channel": "player", "command": "seek", "args": {"position_s": "NaN"}},
                   {"channel": "player", "command": "play", "args": {"position_s": 1}},
                   {"channel": "calibration", "command": "capture_gym", "args": {"seconds": 1e308}}]
            for i, req in enumerate(bad):
                await ws.send(json.dumps({"type": "command", "id": i, **req}))
            for i in range(len(bad), len(bad) + 40):  # a burst: the rate limit drops the excess
                await ws.send(json.dumps({"type": "command", "id": i, "channel": "player", "command": "play"}))
            replies = {}
            t_end = time.monotonic() + 10
            while len(replies) < len(bad) + 40 and time.monotonic() < t_end:
                msg = await asyncio.wait_for(ws.recv(), 5)
                if isinstance(msg, str):
                    r = json.loads(msg)
                    replies[r["id"]] = r
                else:
                    await ws.send("a")
            out["replies"] = replies
        return out

    try:
        wait_until(lambda: tap.of("markers"), what="the player playing")
        out = run_async(run)
        assert out["no_token"] == 403 and out["wrong_token"] == 403
        assert out["foreign_origin"] == 403 and out["rebound_host"] == 403
        assert out["same_origin"] == 101
        replies = out["replies"]
        assert all(not replies[i]["ok"] for i in range(5)), replies
        assert "needs 'position_s'" in replies[0]["error"] and "finite" in replies[1]["error"]
        assert "takes no argument" in replies[3]["error"] and "takes no argument" in replies[4]["error"]
        burst = [replies[i] for i in range(5, 45)]
        limited = [r for r in burst if not r["ok"] and "too many commands" in r["error"]]
        assert 10 <= len(limited) <= 30, burst  # the burst allowance passes, the rest is dropped
        # /stats needs the token too; the page's own files do not (they hold no secret)
        with pytest.raises(urllib.error.HTTPError) as exc:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/stats", timeout=5)
        assert exc.value.code == 403
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5) as r:
            assert r.status == 200
        # DNS rebinding: the right token, but the page came from a name that is not this viewer
        import http.client

        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
        conn.putrequest("GET", "/stats?" + url.partition("?")[2], skip_host=True)
        conn.putheader("Host", f"evil.example:{port}")
        conn.endheaders()
        assert conn.getresponse().status == 403
        conn.close()

        # Straight onto the bus (no viewer checks in the way): the player answers and plays on.
        n0 = len(tap.of("markers"))
        status_before = len(tap.of("player_status"))
        for seq, args in enumerate(({}, {"position_s": 1e308}, {"position_s": "x"}, [1]), start=1):
            cmd = NodeCommand(target="player", command="seek", args_json=json.dumps(args))
            cmd_pub.send_multipart(encode("player_command", cmd, seq, time.time_ns(), "tester"))
        time.sleep(1.5)
        assert len(tap.of("markers")) - n0 > 60, "the player stopped playing"
        assert g.proc.poll() is None and "Traceback" not in g.output
        errors = [json.loads(m.data_json).get("error") for _, m in tap.of("player_status")[status_before:]]
        refused = {e for e in errors if e and "seek" in e}
        assert len(refused) >= 3, errors
        assert all(m.state == "playing" for _, m in tap.of("player_status")[status_before:])
    finally:
        tap.close()
        cmd_pub.close(0)
