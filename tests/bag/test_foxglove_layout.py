"""The shipped Foxglove layout (graph_configs/foxglove/outlets_layout.json) names only what the
bridge really serves: its 3D topics are advertised SceneUpdate channels of the example graph and
every plot path leads to a number in a diagnostics message received from the bridge."""
from __future__ import annotations

import asyncio
import json
import re
import socket
import sys
from pathlib import Path

from mocapgraph.bag.foxglove_layout import LAYOUT_FILE, outlets_layout
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "nodes"))
from test_foxglove_bridge import _session  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[2] / "graph_configs" / "examples" / "outlets.yaml"


def _panels(node: dict) -> list[dict]:
    if node.get("type") == "panel":
        return [node]
    return [p for item in node.get("items", []) for p in _panels(item["content"])]


def _named(layout: dict) -> tuple[set[str], list[tuple[str, list[str]]]]:
    """3D topics and plot series (topic, field path) the layout names."""
    panels = _panels(layout["content"])
    scene = {t for p in panels if p["panelType"] == "ThreeDee" for t in p["config"]["topics"]}
    plots = []
    for p in panels:
        if p["panelType"] == "Plot":
            for s in p["config"]["paths"]:
                topic, *path = s["value"].split(".")
                plots.append((topic, path))
    return scene, plots


def test_the_shipped_layout_is_the_generated_one():
    layout = json.loads(LAYOUT_FILE.read_text())
    assert LAYOUT_FILE.read_text() == outlets_layout(), "regenerate: python -m mocapgraph.bag.foxglove_layout"
    kinds = sorted(p["panelType"] for p in _panels(layout["content"]))
    assert kinds == ["Plot", "Plot", "ThreeDee"]


def test_every_topic_the_layout_names_is_served_by_the_example_graph(launch_graph):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a UDP port nobody listens on for OSC
        s.bind(("127.0.0.1", 0))
        osc_port = s.getsockname()[1]
    g = launch_graph(EXAMPLE, "foxglove_port:=0", "viewer_port:=0", f"osc_port:={osc_port}")
    g.wait_ready()
    url = re.search(r"(ws://\S+)", g.wait_for("foxglove bridge at ")).group(1)
    scene, plots = _named(json.loads(LAYOUT_FILE.read_text()))
    assert scene and plots
    diag_topics = {t for t, _ in plots}
    _, channels, got = asyncio.run(_session(url, {t: 1 for t in scene | diag_topics}))
    for t in scene:
        assert channels[t]["schemaName"] == "foxglove.SceneUpdate", t
    for topic, path in plots:
        assert channels[topic]["encoding"] == "json"
        value = json.loads(got[topic][-1][1])
        for key in path:
            value = value[key]  # KeyError: the plot would stay empty in Foxglove
        assert value is None or isinstance(value, (int, float)), (topic, path, value)  # null: NaN so far
