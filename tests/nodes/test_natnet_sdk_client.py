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

import numpy as np
import pytest

from mocapgraph.formats import natnet_encode as ne
from mocapgraph.testing.natnet_server import ActorStream, NatNetServer
from tests.natnet_sdk import our_frame

pytestmark = pytest.mark.slow
CLIENT = Path(__file__).resolve().parents[1] / "natnet_sdk_client.py"


@pytest.mark.parametrize("version,source", [((3, 0), "actor"), ((4, 1), "actor"), ((4, 2), "actor"), ((4, 1), "c3d")],
                         ids=lambda v: "%d.%d" % v if isinstance(v, tuple) else v)
def test_natnetsdk_client_reads_our_server_as_we_do(version, source, tmp_path) -> None:
    pytest.importorskip("natnetsdk")
    if source == "c3d":                  # the simulator serving a C3D file (written here by ezc3d)
        pytest.importorskip("ezc3d")
        from tests.lab_fixtures import PERSON_LABELS, person_frames, write_points_c3d

        truth = person_frames(30)
        truth[3:6, 1] = np.nan
        stream = ActorStream(source=str(write_points_c3d(tmp_path / "walk.c3d", PERSON_LABELS, truth)))
    else:
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
    if source == "c3d":                  # and those values are the file's, in Motive's axes
        want = stream.dev.points_from_world(np.nan_to_num(truth[np.arange(2000, 2040) % 30])).astype(np.float32)
        seen = ~np.isnan(truth[np.arange(2000, 2040) % 30]).any(axis=2)
        lab = np.array([[m[1] for m in f["labelled"][:4]] for f in got["frames"]], np.float32)
        np.testing.assert_array_equal(lab[seen], want[seen])
        assert not seen.all()
    print(f"\nnatnetsdk {'.'.join(map(str, version))}: 40 frames, {sum(len(f['labelled']) for f in ours)} labelled "
          f"markers, {sum(len(f['bodies']) for f in ours)} rigid bodies read identically")
