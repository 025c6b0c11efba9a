"""A page sending commands steadily faster than the limit gets the burst plus COMMAND_RATE_HZ a second through.

The burst alone is checked in test_viewer_access; here the refill is: a steady flood at ~30/s for ~2 s
against a real viewer's WebSocket, every command answered, the accepted ones counted; and the
same counts exactly on the server's bucket with the clock stepped by the test (the fast subset).
"""
from __future__ import annotations

import asyncio
import json
import time

import pytest
from viewer_support import free_port, run_async, viewer_url, ws_url

from mocapgraph.viewer import server
from mocapgraph.viewer.server import COMMAND_BURST, COMMAND_RATE_HZ

websockets_client = pytest.importorskip("websockets.asyncio.client")

SEND_HZ, SEND_S = 30.0, 2.0


@pytest.mark.timing
def test_a_steady_command_flood_gets_burst_plus_rate_through(launch_graph) -> None:
    assert SEND_HZ > 2 * COMMAND_RATE_HZ  # the flood must outrun the limit for the count to say anything
    port = free_port()
    g = launch_graph(f"""
nodes:
  - name: viz
    type: visualizer
    params: {{port: {port}}}
""")
    g.wait_ready()
    url = viewer_url(g)
    n = int(SEND_HZ * SEND_S)

    async def run() -> tuple[dict, float]:
        async with websockets_client.connect(ws_url(url)) as ws:
            assert json.loads(await ws.recv())["type"] == "hello"
            replies: dict = {}
            done = asyncio.Event()

            async def read() -> None:
                while len(replies) < n:
                    msg = await ws.recv()
                    if isinstance(msg, str):
                        r = json.loads(msg)
                        if r.get("type") == "command_result":
                            replies[r["id"]] = (r, time.monotonic())
                    else:
                        await ws.send("a")
                done.set()

            reader = asyncio.create_task(read())
            t0 = time.monotonic()
            for i in range(n):  # paced by deadlines: a late start is caught up, not stretched
                delay = t0 + i / SEND_HZ - time.monotonic()
                if delay > 0:
                    await asyncio.sleep(delay)
                await ws.send(json.dumps({"type": "command", "id": i, "channel": "player", "command": "play"}))
            await asyncio.wait_for(done.wait(), 20)
            await reader
            # Every command was taken by the server between the first send and the last reply.
            return replies, max(t for _, t in replies.values()) - t0

    replies, span_s = run_async(run)
    assert sorted(replies) == list(range(n))
    accepted = [i for i, (r, _) in replies.items() if r["ok"]]
    refused = [r for r, _ in replies.values() if not r["ok"]]
    assert all("too many commands" in r["error"] for r in refused), refused[:3]
    # The first COMMAND_BURST go through at once, whatever the pace.
    assert accepted[:COMMAND_BURST] == list(range(COMMAND_BURST)), accepted
    # Then the bucket refills at COMMAND_RATE_HZ: at most that many more per second of the whole
    # exchange (a loaded machine only stretches span_s, which loosens this bound, never breaks it) ...
    most = COMMAND_BURST + COMMAND_RATE_HZ * span_s + 2
    assert len(accepted) <= most, (f"{len(accepted)} of {n} commands accepted in {span_s:.2f} s; "
                                   f"the limit allows at most {most:.0f}")
    # ... and it does refill: a steady sender is slowed down, not shut out after the burst.
    assert len(accepted) >= COMMAND_BURST + 5, (len(accepted), span_s)
    assert g.proc.poll() is None and "Traceback" not in g.output


def test_the_command_bucket_refills_at_the_rate_on_a_stepped_clock(monkeypatch) -> None:
    now = [1000.0]
    monkeypatch.setattr(server.time, "monotonic", lambda: now[0])   # the clock, not our code
    bucket = server._Bucket(COMMAND_RATE_HZ, COMMAND_BURST)
    took = []
    for _ in range(int(SEND_HZ * SEND_S)):   # the flood above, at exact 1/30 s steps
        took.append(bucket.take())
        now[0] += 1.0 / SEND_HZ
    assert took[:COMMAND_BURST] == [True] * COMMAND_BURST
    # 2 s of refill at 10/s: 20 more (the last may fall on either side of a whole token)
    assert abs(sum(took) - (COMMAND_BURST + COMMAND_RATE_HZ * SEND_S)) <= 1, sum(took)
    # once the burst is spent (after ~30: it refills while it drains), one in three at 30/s
    steady = took[40:]
    assert 5 <= sum(steady) <= 7 and not any(a and b for a, b in zip(steady, steady[1:])), took
    # an idle second gives COMMAND_RATE_HZ commands back; a long idle no more than the burst
    while bucket.take():
        pass
    now[0] += 1.0
    assert sum(bucket.take() for _ in range(100)) == COMMAND_RATE_HZ
    now[0] += 3600.0
    assert sum(bucket.take() for _ in range(100)) == COMMAND_BURST
