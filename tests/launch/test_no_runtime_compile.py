"""Running graphs never compile a kernel: every signature their nodes use is warmed by setup.

numba compiles once per argument-type signature; a signature the kernel modules' ``warm()`` misses
(a read-only decoded array, an int32 index) compiles on a node's first frame and stalls it for
seconds. ``mocapgraph.jit`` logs every such compile; these graphs run every compiled path (both
solver fits with gaps, retargeting with foot planting, bone checks, the physics tracker with a
posture database, the Kinect source) and must log none, while producing output.
"""
from __future__ import annotations

import time
from pathlib import Path

import pytest

from mocapgraph.bag.reader import BagReader
from mocapgraph.kinematics.calibration import calibrate
from mocapgraph.kinematics.model import save_model
from mocapgraph.kinematics.synthetic_actor import SyntheticActor

RUN_S = 6.0

OPTICAL = """
nodes:
  - name: reader
    type: synthetic_actor
    params: {{layout: kiip_full_body, rate_hz: 120.0, noise_mm: 1.0, dropout_rate_hz: 0.5, loop: true}}
  - name: calibration
    type: calibration
    params: {{model_file: "{model}"}}
  - name: solver
    type: frame_solver
    params: {{fit: global}}
  - name: solver_segment
    type: frame_solver
    params: {{fit: segment, actor: segment}}
    remap: {{actor_pose: actor_pose_segment}}
  - name: retargeter
    type: retargeter
    params: {{source: actor, character: standard_20, foot_planting: true}}
  - name: physics
    type: physics_tracker
    params: {{stage: claro_pole, posture_db: "synthetic:kick"}}
  - name: rec
    type: bag_recorder
    params: {{path: "{bag}", topics: [actor_pose, actor_pose_segment, character_pose, physics_state]}}
"""

KINECT = """
include:
  - file: {graphs}/kinect_physics.yaml
    args: {{recording: "{recording}", viewer: false, posture_db: "synthetic:kick"}}
nodes:
  - name: rec
    type: bag_recorder
    params: {{path: "{bag}", topics: [character_pose, physics_state]}}
"""

GRAPHS = Path(__file__).resolve().parents[2] / "graph_configs"


def _run(launch_graph, text: str, bag: Path) -> dict[str, int]:
    g = launch_graph(text)
    g.wait_ready()
    time.sleep(RUN_S)
    g.stop()
    compiled = [line for line in g.lines if "jit: compiled" in line]
    assert not compiled, "kernels compiled while the graph ran:\n" + "\n".join(compiled)
    with BagReader(bag) as r:
        return {topic: sum(1 for _ in r.decoded(topic)) for topic in r.topic_infos()}


def test_the_optical_pipeline_runs_on_warmed_kernels_only(launch_graph, tmp_path):
    cap = SyntheticActor("kiip_full_body", rate=120.0).capture(0, int(120 * 18))
    model = calibrate(cap.skeleton, cap.markers[: cap.phases["gym"][1]], rate_hz=cap.rate, source="synthetic")
    save_model(model, tmp_path / "model.json")
    bag = tmp_path / "optical.mcap"
    counts = _run(launch_graph, OPTICAL.format(model=tmp_path / "model.json", bag=bag), bag)
    for topic in ("actor_pose", "actor_pose_segment", "character_pose", "physics_state"):
        assert counts.get(topic, 0) >= 60, (topic, counts)


def test_the_kinect_pipeline_runs_on_warmed_kernels_only(launch_graph, tmp_path, shared_data):
    recording = shared_data / "kinect2" / "Ges01_wavehand.csv"
    if not recording.exists():
        pytest.skip(f"{recording} not present")
    bag = tmp_path / "kinect.mcap"
    counts = _run(launch_graph, KINECT.format(graphs=GRAPHS, recording=recording, bag=bag), bag)
    for topic in ("character_pose", "physics_state"):
        assert counts.get(topic, 0) >= 30, (topic, counts)
