"""The lsl_outlet node in a real graph, read by a real pylsl inlet in another process: the marker
stream's labels and units, every 240 Hz frame for 10 s in order, joint and character streams."""
from __future__ import annotations

import json
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from graph_helpers import wait_until
from eco_support import JOINT_NAMES, STAGE_PERFORMER, pattern_positions

HERE = Path(__file__).resolve().parent
RATE = 240.0
N_MARKERS = 12


def _inlet(name: str, n: int, tmp: Path) -> tuple[subprocess.Popen, Path, Path]:
    out, ready = tmp / f"{name}.npz", tmp / f"{name}.ready"
    p = subprocess.Popen([sys.executable, str(HERE / "lsl_inlet_proc.py"), name, str(n), str(out), str(ready)],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return p, out, ready


def _result(p: subprocess.Popen, out: Path, timeout: float = 60):
    text, _ = p.communicate(timeout=timeout)
    assert p.returncode == 0, text
    d = np.load(out)
    return d["samples"], d["stamps"], json.loads(str(d["meta"]))


@pytest.mark.timing
def test_markers_at_240_hz_for_10_s_in_order_without_loss(launch_graph, tmp_path):
    prefix = f"t{uuid.uuid4().hex[:6]}"
    g = launch_graph(f"""
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: {RATE}, n_markers: {N_MARKERS}}}
  - name: lsl
    type: lsl_outlet
    params: {{prefix: {prefix}}}
""")
    g.wait_ready()
    n = int(RATE * 10)
    p, out, ready = _inlet(f"{prefix}Markers", n, tmp_path)
    samples, stamps, meta = _result(p, out)
    g.stop()
    assert meta["type"] == "Mocap" and meta["rate"] == RATE and meta["format"] == pylsl_double()
    labels = [c["label"] for c in meta["channels"]]
    assert labels == [f"P{i}_{a}" for i in range(N_MARKERS) for a in "XYZ"]
    assert {c["unit"] for c in meta["channels"]} == {"meters"}
    assert [c["type"] for c in meta["channels"][:3]] == ["PositionX", "PositionY", "PositionZ"]
    assert meta["channels"][4]["marker"] == "P1" and meta["frame"].startswith("world")
    assert samples.shape == (n, 3 * N_MARKERS)
    # Which pattern frame is the first sample? The pattern is exact, so the match is too.
    first = samples[0].reshape(N_MARKERS, 3)
    k0 = next(k for k in range(20000) if np.allclose(pattern_positions(k, N_MARKERS, RATE), first, atol=1e-12))
    expect = np.stack([pattern_positions(k0 + i, N_MARKERS, RATE).ravel() for i in range(n)])
    np.testing.assert_allclose(samples, expect, atol=1e-12)  # every frame, in order, none lost
    dt = np.diff(stamps)
    print(f"\nLSL inlet: {n} samples from frame {k0}, stamp step median {1e3 * np.median(dt):.3f} ms "
          f"(nominal {1e3 / RATE:.3f}), max {1e3 * dt.max():.2f} ms")
    assert (dt > 0).all()  # capture stamps, in order (their spacing is the source's timer, not ours)
    # stamps are on the LSL clock the inlet shares with the other devices (capture time, not arrival)
    assert 0 <= meta["clock_now"] - stamps[-1] < 2.0


def pylsl_double() -> int:
    import pylsl

    return pylsl.cf_double64


def test_joint_and_character_streams_are_described(launch_graph, tmp_path):
    prefix = f"t{uuid.uuid4().hex[:6]}"
    g = launch_graph(f"""
nodes:
  - name: performer
    type: {STAGE_PERFORMER}
    params: {{actor: ann, rate_hz: 60.0, publish: [actor, character], nan_joint: 6}}
  - name: lsl
    type: lsl_outlet
    params: {{prefix: {prefix}, rate_hz: 60.0}}
""")
    g.wait_ready()
    pj, oj, _ = _inlet(f"{prefix}Joints_ann", 120, tmp_path)
    pc, oc, _ = _inlet(f"{prefix}Character_ann", 60, tmp_path)
    js, jt, jm = _result(pj, oj)
    cs, ct, cm = _result(pc, oc)
    g.stop()
    J = len(JOINT_NAMES)
    assert [c["label"] for c in jm["channels"][:4]] == ["pelvis_X", "pelvis_Y", "pelvis_Z", "pelvis_Quality"]
    assert jm["channels"][3]["type"] == "Quality" and jm["channels"][3]["unit"].startswith("0 missing")
    assert js.shape == (120, 4 * J)
    q = js.reshape(120, J, 4)[..., 3]
    assert set(np.unique(q)) <= {0.0, 1.0, 2.0}
    pos = js.reshape(120, J, 4)[..., :3]
    assert (np.isnan(pos).all(-1) == (q == 0)).all()  # missing is NaN and flagged 0, never 0,0,0
    assert [c["label"] for c in cm["channels"][3:7]] == ["pelvis_QW", "pelvis_QX", "pelvis_QY", "pelvis_QZ"]
    assert cs.shape == (60, 8 * J) and cm["rate"] == 60.0
    assert cm["channels"][7]["label"] == "pelvis_Quality"
    quat = cs.reshape(60, J, 8)[..., 3:7]
    np.testing.assert_allclose(np.linalg.norm(quat, axis=-1), 1.0, atol=1e-9)
