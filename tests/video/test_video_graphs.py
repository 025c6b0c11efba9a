"""The video graphs are the Kinect skeleton graph with another reader (wiring only: no estimator)."""
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
