"""The lab graphs as real multi-process graphs: swapping the reader changes nothing else, a
missing file or a vanishing serial device leaves the rest of the graph running, and every reader
documents its params in `mocapgraph node info`."""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mocapgraph.cli import main as cli_main
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.launch.check import check_graph
from mocapgraph.launch.graph import load_graph
from mocapgraph.bus.manifest import fetch_manifest
from mocapgraph.nodes.registry import NODE_TYPES

from graph_helpers import pid_alive, read_jsonl, wait_until

CONFIGS = Path(__file__).resolve().parents[2] / "graph_configs"
MARKER_LABS = ["lab_synthetic", "lab_c3d", "lab_trc", "lab_serial", "lab_udp", "lab_lsl", "lab_qtm", "lab_natnet"]
SKELETON_LABS = ["kinect_playback", "bvh_playback"]
READERS = ["synthetic_actor", "c3d_reader", "trc_reader", "serial_reader", "udp_reader", "lsl_reader",
           "kinect_reader", "bvh_player", "qtm_reader", "natnet_reader"]


@pytest.mark.parametrize("group", [MARKER_LABS, SKELETON_LABS])
def test_lab_graphs_check_and_differ_only_in_the_reader(group) -> None:
    # wiring only: the capture files (../shared/data) are the other tests' business
    graphs = {name: check_graph(load_graph(CONFIGS / f"{name}.yaml"), check_files=False) for name in group}
    shapes = {}
    for name, g in graphs.items():
        reader = g.node("reader")
        assert reader.spec.type in READERS
        rest = sorted((n.name, n.spec.type, json.dumps(n.params, sort_keys=True)) for n in g.nodes if n.name != "reader")
        shapes[name] = rest
        want = {"markers", "marker_layout"} if group is MARKER_LABS else {"skeleton_pose", "skeleton_info"}
        assert want <= set(reader.outputs.values())
    first = next(iter(shapes.values()))
    assert all(s == first for s in shapes.values()), shapes
    assert len({g.node("reader").spec.type for g in graphs.values()}) == len(group)


def logged_graph(lab: str, tmp_path: Path, *args: str) -> str:
    return f"""\
include:
  - file: {CONFIGS / (lab + '.yaml')}
    args: {{viewer: false, {', '.join(args)}}}
nodes:
  - name: logger
    type: topic_logger
    params: {{path: {tmp_path / (lab + '.jsonl')}, topics: [markers, marker_layout]}}
"""


def test_swapping_the_reader_gives_frames_of_the_same_layout(launch_graph, tmp_path, shared_data) -> None:
    capture = shared_data / "c3d" / "pycgm" / "Movement_trial.c3d"
    graphs = {
        "lab_synthetic": launch_graph(logged_graph("lab_synthetic", tmp_path, "layout: plug_in_gait",
                                                   f"session_log: {tmp_path / 's1.jsonl'}")),
        "lab_c3d": launch_graph(logged_graph("lab_c3d", tmp_path, "layout: plug_in_gait", f"capture: {capture}",
                                             f"session_log: {tmp_path / 's2.jsonl'}")),
    }
    for g in graphs.values():
        g.wait_ready(30)
    logs = {lab: tmp_path / f"{lab}.jsonl" for lab in graphs}
    for lab, log in logs.items():
        wait_until(lambda: sum(r["topic"] == "markers" for r in read_jsonl(log)) >= 30, what=f"frames of {lab}")
    for g in graphs.values():
        assert g.stop() == 0
    layouts, frames = {}, {}
    for lab, log in logs.items():
        recs = read_jsonl(log)
        lay = [r for r in recs if r["topic"] == "marker_layout"]
        assert len(lay) == 1 and lay[0]["type"] == "MarkerLayout" and lay[0]["sender"] == "reader"
        layouts[lab] = lay[0]["msg"]
        frames[lab] = [r for r in recs if r["topic"] == "markers"]
        assert all(r["type"] == "MarkerFrame" for r in frames[lab])
    sk = SkeletonDefinition.from_layout_file("plug_in_gait")
    for key in ("name", "labels", "limb_names", "marker_limb"):
        assert layouts["lab_synthetic"][key] == layouts["lab_c3d"][key]
    assert layouts["lab_c3d"]["labels"] == list(sk.marker_labels)
    for lab, recs in frames.items():
        pos = np.array([r["msg"]["positions"] for r in recs[:30]], dtype=float)
        assert pos.shape == (30, 39, 3)
        assert np.isfinite(pos).all(axis=2).mean() > 0.9            # real data in every slot
        z = np.nanmedian(pos[..., 2], axis=0)
        assert 0.0 < np.nanmin(z) and np.nanmax(z) < 2.5             # metres, Z up, on a human
        head = [lab_i for lab_i, m in enumerate(sk.marker_labels) if m in ("LFHD", "RFHD")]
        toes = [lab_i for lab_i, m in enumerate(sk.marker_labels) if m in ("LTOE", "RTOE")]
        assert z[head].min() > z[toes].max() + 1.0                   # head above toes in both


def test_missing_capture_file_stops_the_launch_before_any_process(launch_graph, tmp_path) -> None:
    g = launch_graph(logged_graph("lab_c3d", tmp_path, f"capture: {tmp_path / 'nope.c3d'}",
                                  f"session_log: {tmp_path / 's.jsonl'}"))
    assert g.proc.wait(30) == 2
    g.stop()
    lines = [ln for ln in g.lines if ln.strip()]
    assert len(lines) == 1, g.output
    # the include's line that sets the param: file:line: key: message
    assert lines[0].startswith(f"mocapgraph: {CONFIGS / 'lab_c3d.yaml'}:")
    assert ": nodes[reader].params.file: " in lines[0] and "nope.c3d: file not found" in lines[0]
    assert not (tmp_path / "s.jsonl").exists()                # nothing ran


def test_broken_capture_file_is_reported_and_the_rest_keeps_running(launch_graph, tmp_path) -> None:
    broken = tmp_path / "broken.c3d"
    broken.write_bytes(bytes([2, 0x50]) + b"\x07" * 2000)     # a header, then garbage
    g = launch_graph(logged_graph("lab_c3d", tmp_path, f"capture: {broken}",
                                  f"session_log: {tmp_path / 's.jsonl'}"))
    g.wait_ready(30)
    line = g.wait_for("broken.c3d:")
    assert "[reader] ERROR" in line
    g.wait_for("node reader exited with code 1")
    pids = {n["name"]: n["pid"] for n in fetch_manifest(g.master)["nodes"]}
    time.sleep(0.3)
    assert g.proc.poll() is None and pid_alive(pids["logger"]) and pid_alive(pids["session_log"])
    status = [r for r in read_jsonl(tmp_path / "s.jsonl") if r["topic"] == "reader_status"]
    assert status and status[-1]["msg"]["state"] == "error"
    assert "Traceback" not in g.output
    assert g.stop() == 0


def test_simulated_serial_device_that_vanishes_keeps_the_graph_running(launch_graph, tmp_path) -> None:
    sim = subprocess.Popen([sys.executable, "-m", "mocapgraph", "device", "simulate", "serial", "--count", "240",
                            "--rate", "120", "--garbage-every", "10"],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        port = sim.stdout.readline().split(" on ")[1].split()[0]
        g = launch_graph(logged_graph("lab_serial", tmp_path, f"port: {port}",
                                      f"session_log: {tmp_path / 's.jsonl'}"))
        g.wait_ready(30)
        log = tmp_path / "lab_serial.jsonl"
        wait_until(lambda: sum(r["topic"] == "markers" for r in read_jsonl(log)) >= 20, what="frames")
        assert sim.wait(10) == 0                                       # the device is gone
        line = g.wait_for("lost " + port)
        assert "WARNING" in line
        status = wait_until(lambda: [r for r in read_jsonl(tmp_path / "s.jsonl") if r["topic"] == "reader_status"
                                     and r["msg"]["state"] == "reconnecting"], what="reconnecting")
        counts = json.loads(status[-1]["msg"]["data_json"])
        assert counts["disconnects"] == 1 and counts["rejected_bytes"] > 0   # line noise counted
        assert "skipped" in g.wait_for("bad byte")
        pids = {n["name"]: n["pid"] for n in fetch_manifest(g.master)["nodes"]}
        assert g.proc.poll() is None and pid_alive(pids["reader"])
        frames = [r for r in read_jsonl(log) if r["topic"] == "markers"]
        # Every frame that arrived whole was published (the device sent 240, noise before 24).
        assert len(frames) >= 200
        lay = [r for r in read_jsonl(log) if r["topic"] == "marker_layout"][0]["msg"]
        assert lay["labels"] == list(SkeletonDefinition.from_layout_file("plug_in_gait").marker_labels)
        assert g.stop() == 0
    finally:
        sim.kill()
        sim.wait()


@pytest.mark.parametrize("node_type", READERS)
def test_node_info_documents_every_param(node_type, capsys) -> None:
    assert node_type in NODE_TYPES
    assert cli_main(["node", "info", node_type]) == 0
    out = capsys.readouterr().out
    params = out.split("params:\n")[1].strip().splitlines()
    assert params
    for line in params:
        name, _, rest = line.strip().partition(": ")
        assert "=" in rest and len(rest.split("  ", 1)[-1]) > 10, f"{node_type}.{name} has no doc"
    assert "'markers' [MarkerFrame]" in out or "'skeleton_pose' [SkeletonPose]" in out
