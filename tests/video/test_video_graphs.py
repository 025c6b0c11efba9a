"""The video graphs: the Kinect skeleton graph with another reader, and a broken video stopping only
its reader (one line, the rest of the graph running)."""
from __future__ import annotations

import json
from pathlib import Path

from mocapgraph.launch.check import check_graph
from mocapgraph.launch.graph import load_graph

CONFIGS = Path(__file__).resolve().parents[2] / "graph_configs"


def _rest(name: str):
    g = check_graph(load_graph(CONFIGS / f"{name}.yaml"), check_files=False)
    reader = g.node("reader")
    rest = sorted((n.name, n.spec.type, json.dumps(n.params, sort_keys=True)) for n in g.nodes if n.name != "reader")
    return reader, rest


def test_video_graphs_differ_from_kinect_playback_in_the_reader_only() -> None:
    kinect_reader, kinect = _rest("kinect_playback")
    for name, node_type in (("video_playback", "video_pose_reader"), ("multiview_playback", "multiview_pose")):
        reader, rest = _rest(name)
        assert reader.spec.type == node_type and rest == kinect
        assert set(reader.outputs.values()) == set(kinect_reader.outputs.values())


def test_a_broken_video_is_one_line_and_the_rest_of_the_graph_keeps_running(launch_graph, tmp_path,
                                                                              shared_data) -> None:
    import pytest
    pytest.importorskip("mediapipe")         # without the extra the reader's one line names the extra instead
    from graph_helpers import pid_alive, read_jsonl
    from mocapgraph.bus.manifest import fetch_manifest
    import time
    broken = tmp_path / "broken.mp4"
    broken.write_bytes((shared_data / "video" / "pose2sim_demo" / "cam01.mp4").read_bytes()[:5000])
    g = launch_graph(CONFIGS / "video_playback.yaml", f"recording:={broken}", "viewer:=false",
                     f"session_log:={tmp_path / 's.jsonl'}")
    g.wait_ready(60)
    line = g.wait_for("broken.mp4:")
    assert "[reader] ERROR broken.mp4: cannot be opened as a video" in line
    g.wait_for("node reader exited with code 1")
    pids = {n["name"]: n["pid"] for n in fetch_manifest(g.master)["nodes"]}
    time.sleep(0.3)
    assert g.proc.poll() is None and pid_alive(pids["session_log"])
    status = [r for r in read_jsonl(tmp_path / "s.jsonl") if r["topic"] == "reader_status"]
    assert status and status[-1]["msg"]["state"] == "error"
    assert "Traceback" not in g.output and g.output.count("broken.mp4") <= 3
    assert g.stop() == 0
