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
from mocapgraph.kinematics.calibration.calibrate import calibrate
from mocapgraph.kinematics.model import save_model
from mocapgraph.kinematics.synthetic.actor import SyntheticActor

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
SHARED_DATA = (Path(__file__).resolve().parents[2] / ".." / "shared" / "data").resolve()  # as conftest's


@pytest.fixture(scope="module")
def pipelines(launch_module_graph, tmp_path_factory) -> dict[str, object]:
    """Both pipelines launched side by side and run RUN_S together (one wait instead of two: a
    compile depends on the signatures a node meets, not on how busy the machine is), then stopped:
    name -> (its `jit: compiled` lines, message counts per topic of its bag), or the reason the
    Kinect recording is absent."""
    tmp = tmp_path_factory.mktemp("no_compile")
    graphs, bags, out = {}, {}, {}
    recording = SHARED_DATA / "kinect2" / "Ges01_wavehand.csv"
    if recording.exists():
        bags["kinect"] = tmp / "kinect.mcap"
        graphs["kinect"] = launch_module_graph(KINECT.format(graphs=GRAPHS, recording=recording, bag=bags["kinect"]))
    else:
        out["kinect"] = f"{recording} not present"
    # the model is calibrated here while the Kinect graph starts up
    cap = SyntheticActor("kiip_full_body", rate=120.0).capture(0, int(120 * 18))
    model = calibrate(cap.skeleton, cap.markers[: cap.phases["gym"][1]], rate_hz=cap.rate, source="synthetic")
    save_model(model, tmp / "model.json")
    bags["optical"] = tmp / "optical.mcap"
    graphs["optical"] = launch_module_graph(OPTICAL.format(model=tmp / "model.json", bag=bags["optical"]))
    for g in graphs.values():
        g.wait_ready()
    time.sleep(RUN_S)
    for g in graphs.values():
        g.stop()
    for name, g in graphs.items():
        compiled = [line for line in g.lines if "jit: compiled" in line]
        with BagReader(bags[name]) as r:
            out[name] = compiled, {topic: sum(1 for _ in r.decoded(topic)) for topic in r.topic_infos()}
    return out


def _counts(result) -> dict[str, int]:
    compiled, counts = result
    assert not compiled, "kernels compiled while the graph ran:\n" + "\n".join(compiled)
    return counts


def test_the_optical_pipeline_runs_on_warmed_kernels_only(pipelines):
    counts = _counts(pipelines["optical"])
    for topic in ("actor_pose", "actor_pose_segment", "character_pose", "physics_state"):
        assert counts.get(topic, 0) >= 60, (topic, counts)


def test_the_kinect_pipeline_runs_on_warmed_kernels_only(pipelines):
    if isinstance(pipelines["kinect"], str):
        pytest.skip(pipelines["kinect"])
    counts = _counts(pipelines["kinect"])
    for topic in ("character_pose", "physics_state"):
        assert counts.get(topic, 0) >= 30, (topic, counts)
