"""A Foxglove layout for our scene and diagnostics topics, built with the foxglove-sdk's own layout types.

The layout holds a 3D panel showing the scene topics (world frame ``world``, Z up, a 10 m floor
grid) beside two Plot panels fed by ``/diagnostics/<node>``: incoming rates (Hz) and latencies
(ms) of the named edges. Import it in Foxglove (Layouts > Import from file) after connecting to
a ``foxglove_bridge`` or opening a bag written by ``bag export-foxglove``.
The shipped file (``graph_configs/foxglove/outlets_layout.json``) is `outlets_layout` for
``graph_configs/examples/outlets.yaml``; regenerate it with
``python -m mocapgraph.bag.foxglove_layout -o graph_configs/foxglove/outlets_layout.json``.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Sequence

from .foxglove_scene import FRAME_ID

#: every scene channel the bridge and the export can advertise (foxglove.SceneUpdate)
SCENE_TOPICS = ("/markers", "/actor_pose", "/skeleton_pose", "/character_pose", "/physics_state")
LAYOUT_FILE = Path(__file__).resolve().parents[2] / "graph_configs" / "foxglove" / "outlets_layout.json"


def build_layout(plots: Sequence[tuple[str, str]], scene_topics: Sequence[str] = SCENE_TOPICS) -> str:
    """Layout JSON: the 3D panel on ``scene_topics``; rate and latency plots of each ``(node, topic)``
    edge (``/diagnostics/<node>.rate_hz.<topic>`` and ``.latency_ms.<topic>``)."""
    import foxglove.layouts as fl

    def series(field: str) -> list:
        return [fl.PlotSeries(value=f"/diagnostics/{node}.{field}.{topic}", label=f"{node} {topic}",
                              timestamp_method="receiveTime") for node, topic in plots]

    scene = fl.ThreeDeePanel(title="stage", config=fl.ThreeDeeConfig(
        follow_tf=FRAME_ID, follow_mode="follow-none",
        camera_state=fl.ThreeDeeCameraState(distance=6.0, perspective=True, phi=65.0, target=(0.0, 0.0, 1.0)),
        layers={"grid": fl.BaseRendererGridLayerSettings(frame_id=FRAME_ID, size=10.0, divisions=10.0)},
        topics={t: fl.BaseRendererSceneUpdateTopicSettings(visible=True) for t in scene_topics}))
    rates = fl.PlotPanel(title="rates (Hz)", config=fl.PlotConfig(paths=series("rate_hz"), show_legend=True))
    latency = fl.PlotPanel(title="latency (ms)", config=fl.PlotConfig(paths=series("latency_ms"), show_legend=True))
    layout = fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=2, content=scene),
        fl.SplitItem(proportion=1, content=fl.SplitContainer(direction="column", items=[
            fl.SplitItem(content=rates), fl.SplitItem(content=latency)]))]))
    # indented and key-stable, so the shipped file diffs cleanly when regenerated
    return json.dumps(json.loads(layout.to_json()), indent=2) + "\n"


def outlets_layout() -> str:
    """The layout for ``graph_configs/examples/outlets.yaml`` (bridge ``foxglove``, viewer ``viewer``)."""
    drawn = ("markers", "actor_pose", "character_pose", "physics_state")  # what its performer publishes
    return build_layout([("foxglove", t) for t in drawn] + [("viewer", "markers")], [f"/{t}" for t in drawn])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="example: python -m mocapgraph.bag.foxglove_layout -o layout.json")
    ap.add_argument("-o", "--output", type=Path, default=LAYOUT_FILE, help="layout file to write")
    args = ap.parse_args(argv)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(outlets_layout())
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
