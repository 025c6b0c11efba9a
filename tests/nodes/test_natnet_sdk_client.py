"""OptiTrack's own NatNet client (natnetsdk, its own process) against our NatNet server over real
sockets: it connects through our command channel (server info -> its NatNet version), receives the
unicast frames, and decodes every one to the values our decoder reads from the same bytes."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mocapgraph.formats import natnet_encode as ne
from mocapgraph.testing.natnet_server import ActorStream, NatNetServer
from tests.natnet_sdk import our_frame

pytestmark = pytest.mark.slow
CLIENT = Path(__file__).resolve().parents[1] / "natnet_sdk_client.py"


@pytest.mark.parametrize("version", [(3, 0), (4, 1), (4, 2)], ids=lambda v: "%d.%d" % v)
def test_natnetsdk_client_reads_our_server_as_we_do(version, tmp_path) -> None:
    pytest.importorskip("natnetsdk")
    stream = ActorStream("plug_in_gait", rate_hz=240.0, n_bodies=5, dropout_rate_hz=0.5, seed=4)
    server = NatNetServer(ne.server_info(stream.server_info(version)), ne.model_defs(stream.model_defs(), version),
                          command_port=0, rate_hz=240.0)
    tap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tap.bind(("127.0.0.1", 0))
    tap.settimeout(2.0)
    server.targets.append(tap.getsockname())
    out = tmp_path / "sdk.json"
    proc = subprocess.Popen([sys.executable, str(CLIENT), str(server.command_port), "40", str(out), "20"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + 20
        while not server.clients and time.monotonic() < end:
            server.serve()
            time.sleep(0.005)
        assert server.clients, "natnetsdk never sent NAT_CONNECT"
        time.sleep(0.1)
        server.serve()
        sent = []
        for f in stream.frames(2000, 40):
            packet = ne.frame(f, version)
            server.send(packet)
            sent.append(tap.recv(65536))
            server.serve()
            time.sleep(1 / 240)
        assert proc.wait(30) == 0, proc.stderr.read()
    finally:
        proc.kill()
        tap.close()
        server.close()
    got = json.loads(out.read_text())
    assert got["connected"] and got["app"] == "Motive" and got["version"][:2] == list(version)
    assert server.requests.get(10, 0) >= 1                # it keeps the unicast stream alive
    assert len(got["frames"]) == 40
    ours = [json.loads(json.dumps(our_frame(p, version))) for p in sent]  # tuples -> lists, as JSON has them
    for mine, theirs in zip(ours, got["frames"]):
        assert mine == theirs
    print(f"\nnatnetsdk {'.'.join(map(str, version))}: 40 frames, {sum(len(f['labelled']) for f in ours)} labelled "
          f"markers, {sum(len(f['bodies']) for f in ours)} rigid bodies read identically")
