"""A character offset of 1e300 is refused where it is written, in one line (issue 30, item 11).

It is finite, so it passed every check and surfaced as a raw MuJoCo error. Now the character
file names its line at load and in ``graph check``; the retargeter's ``offset`` and the physics
tracker's ``stage_offset`` params are refused by the check; and a CharacterInfo carrying it,
sent over the bus by an ``external:`` publisher to a real physics tracker, is refused in one line
while the tracker goes on with the good character.
"""
from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest
import zmq

from graph_helpers import wait_until
from mocapgraph.formats.character_file import CharacterFileError, load_character
from mocapgraph.messages import CharacterInfo, encode
from mocapgraph.messages.codec import topic_frame

CHAR = """name: far
units: m
joints:
  - {name: Hips, offset: [0, 0, 0.95]}
  - {name: Spine, parent: Hips, offset: [0, 0, 1e300]}
  - {name: Head, parent: Spine, offset: [0, 0, 0.3]}
"""


def _check(tmp_path, name: str, node: str) -> subprocess.CompletedProcess:
    g = tmp_path / f"{name}.yaml"
    g.write_text(f"nodes:\n{node}")
    return subprocess.run([sys.executable, "-m", "mocapgraph", "graph", "check", str(g)], capture_output=True,
                          text=True, timeout=120)


def test_a_character_file_with_a_1e300_offset_is_refused_at_load_and_by_the_check(tmp_path):
    f = tmp_path / "far.yaml"
    f.write_text(CHAR)
    with pytest.raises(CharacterFileError, match=rf"{f}:5: joints\[1\] \(Spine\)\.offset: 1e\+300 m is beyond 1000 m"):
        load_character(f)
    reader = "  - {name: src, type: synthetic_actor}\n  - {name: cal, type: calibration}\n  - {name: solver, type: frame_solver}\n"
    runs = {
        "file": _check(tmp_path, "g_file", reader + f"  - name: rt\n    type: retargeter\n    params: {{character: {f}}}\n"),
        "offset": _check(tmp_path, "g_offset", reader + "  - name: rt\n    type: retargeter\n    params: {offset: [1e300, 0, 0]}\n"),
        "stage": _check(tmp_path, "g_stage", "  - {name: src, type: synthetic_character}\n"
                        "  - name: tr\n    type: physics_tracker\n    params: {stage_offset: [0, .inf, 0]}\n"),
    }
    for key, r in runs.items():
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.returncode != 0 and len(lines) == 1 and "Traceback" not in r.stderr, (key, r.stderr)
    assert f"{f}:5: joints[1] (Spine).offset" in runs["file"].stderr and "g_file.yaml:" in runs["file"].stderr
    assert "params.offset" in runs["offset"].stderr and "within 1000 m" in runs["offset"].stderr
    assert "params.stage_offset" in runs["stage"].stderr


def test_a_forged_character_info_with_a_1e300_offset_is_refused_by_a_running_tracker(launch_graph, tmp_path):
    pub = zmq.Context.instance().socket(zmq.XPUB)
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    g = launch_graph(f"""\
external:
  - {{topic: forged_info, type: CharacterInfo, endpoint: "tcp://127.0.0.1:{port}"}}
nodes:
  - name: src
    type: synthetic_character
    params: {{rate_hz: 60.0}}
  - name: tracker
    type: physics_tracker
    params: {{stage: balls}}
    remap: {{character_info: forged_info}}
""")
    g.wait_ready(timeout=120)
    assert pub.poll(60000) and pub.recv() == b"\x01" + topic_frame("forged_info")
    info = CharacterInfo(character="far", joint_names=["Hips", "Spine", "Head"],
                         joint_parent=np.array([-1, 0, 1], np.int32),
                         rest_offsets=np.array([[0, 0, 0.95], [0, 0, 1e300], [0, 0, 0.3]]),
                         rest_rotations=np.tile([1.0, 0, 0, 0], (3, 1)))
    pub.send_multipart([bytes(f) for f in encode("forged_info", info, 1, time.time_ns(), "probe", latched=True)])
    line = g.wait_for("character far refused", timeout=30)
    assert "beyond 1000 m" in line and "Spine" in line
    time.sleep(1.0)
    assert g.proc.poll() is None
    assert "Traceback" not in g.output and "cannot build the physics world" not in g.output, g.output
    g.stop()
    pub.close(0)
