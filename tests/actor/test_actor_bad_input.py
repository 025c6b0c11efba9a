"""Bad input to the live actor nodes: each fault is reported in one clear line naming it, and the
nodes keep running (the solver marks joints missing, never publishes garbage)."""
from __future__ import annotations

import numpy as np
import yaml

from actor_support import ACTOR_SOURCE, joints, poses, quick_model, statuses, wait_until
from mocapgraph.kinematics.layout import layout_path
from mocapgraph.kinematics.model import save_model


def _layouts(tmp_path):
    kiip = yaml.safe_load(layout_path("kiip_full_body").read_text())
    kiip["name"] = "kiip_plus"
    kiip["limbs"][0]["markers"].append("XTRA")
    extra = tmp_path / "kiip_plus.yaml"
    extra.write_text(yaml.safe_dump(kiip))
    arm = yaml.safe_load(layout_path("one_arm").read_text())
    arm["limbs"][1]["markers"] = arm["limbs"][1]["markers"][:2]
    few = tmp_path / "arm_two_markers.yaml"
    few.write_text(yaml.safe_dump(arm))
    return extra, few


def test_bad_inputs_are_named_and_the_nodes_keep_running(launch_graph, tmp_path):
    extra, few = _layouts(tmp_path)
    arm_model, kiip_model = tmp_path / "arm.json", tmp_path / "kiip.json"
    save_model(quick_model("one_arm"), arm_model)
    save_model(quick_model("kiip_full_body", seed=0), kiip_model)
    log = tmp_path / "log.jsonl"
    solver = "type: frame_solver\n    remap: {{skeleton_model: no_model, actor_pose: {}}}\n    params: "
    g = launch_graph(f"""\
nodes:
  - name: src
    type: {ACTOR_SOURCE}
    params: {{duration_s: 6.0, speed: 4.0, seed: 0, nan_every: 10}}
  - name: still
    type: {ACTOR_SOURCE}
    params: {{duration_s: 5.0, speed: 4.0, gym_scale: 0.02}}
    remap: {{markers: still_markers, marker_layout: still_layout, ground_truth: still_truth}}
  - name: hidden
    type: {ACTOR_SOURCE}
    params: {{duration_s: 3.0, speed: 4.0, hide: [LKNE, RFIN]}}
    remap: {{markers: hidden_markers, marker_layout: hidden_layout, ground_truth: hidden_truth}}
  - name: cal_hidden
    type: calibration
    params: {{auto: true, base_pose_timeout_s: 1.5}}
    remap: {{markers: hidden_markers, marker_layout: hidden_layout, skeleton_model: hidden_model}}
  - name: cal_extra
    type: calibration
    params: {{layout: {extra}, auto: true}}
  - name: cal_few
    type: calibration
    params: {{layout: {few}, auto: true}}
  - name: cal_other
    type: calibration
    params: {{layout: kiip_full_body, model_file: {arm_model}}}
  - name: cal_still
    type: calibration
    params: {{auto: true, gym_seconds: 3.0}}
    remap: {{markers: still_markers, marker_layout: still_layout, skeleton_model: still_model}}
  - name: solver_other
    {solver.format("pose_other")}{{model_file: {arm_model}}}
  - name: solver_nan
    {solver.format("pose_nan")}{{model_file: {kiip_model}, max_gap_s: 0.0}}
  - name: solver_gap
    {solver.format("pose_gap")}{{model_file: {kiip_model}}}
  - name: solver_filter
    {solver.format("pose_filter")}{{model_file: {kiip_model}, filter: constant_velocity}}
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [calibration_status, pose_other, pose_nan, pose_gap, pose_filter, ground_truth]}}
""")
    g.wait_ready(timeout=30)
    g.wait_for("node src exited with code 0", timeout=30)

    def error_of(node: str) -> str:
        def err():
            st = [m for m in statuses(log, node) if m["state"] == "error"]
            return st[-1]["detail"] if st else ""
        return wait_until(err, what=f"an error from {node}", graph=g)

    # Markers that never appear: no base pose, named, after the timeout (in capture time).
    assert error_of("cal_hidden") == "no base pose in 1.5 s of capture: markers never visible: RFIN, LKNE"  # layout order
    # A layout naming a marker the stream lacks.
    assert error_of("cal_extra") == ("layout 'kiip_plus' names markers the marker stream ('kiip_full_body') "
                                     "lacks: XTRA")
    # A limb with fewer than 3 markers.
    msg = error_of("cal_few")
    assert "arm_two_markers.yaml" in msg and "limb `upper_arm_r` has 2 marker(s)" in msg and ">= 3" in msg
    # A model file from another layout, in the calibration node and in the solver.
    assert error_of("cal_other").startswith(f"{arm_model}: model was calibrated for layout 'one_arm', not for "
                                            "layout 'kiip_full_body'; markers differ (CLAV, ")
    line = g.wait_for("[solver_other] ERROR", timeout=5)
    assert "model was calibrated for layout 'one_arm'" in line and "lacks 1 of its 12 markers (CLAV)" in line
    # A gym capture with almost no motion.
    msg = error_of("cal_still")
    assert msg.startswith("gym capture: gym capture has almost no motion (every joint below 25 deg)"), msg

    assert poses(log, "pose_other") == {}  # nothing rather than garbage
    # the source finishes ahead of the solvers (4x real time): wait for the last poses to be logged
    wait_until(lambda: all(len(poses(log, t)) >= 720 for t in ("pose_nan", "pose_gap")), timeout=20,
               what="every frame's pose in the log", graph=g)
    truth = poses(log, "ground_truth")
    for topic, nan_quality in (("pose_nan", 0), ("pose_gap", 1)):
        p = poses(log, topic)
        assert sorted(p) == list(range(720)), topic
        nan_frames = [f for f in p if f % 10 == 9]
        good = [f for f in p if f % 10 != 9]
        assert all(set(p[f]["joint_quality"]) == {nan_quality} for f in nan_frames), topic
        assert all(set(p[f]["joint_quality"]) == {2} for f in good), topic
        err = np.linalg.norm(joints(p, good) - joints(truth, good), axis=-1)
        assert err.mean() < 0.005, topic
        filled = joints(p, nan_frames)
        if nan_quality == 0:
            assert np.isnan(filled).all() and all(set(p[f]["limb_quality"]) == {0} for f in nan_frames)
        else:  # predicted over the one-frame gap, flagged estimated
            assert np.isfinite(filled).all()
            # the 4 s test gym turns limbs too fast for constant velocity; the walk after it is smooth
            walk = [f for f in nan_frames if f >= 600]
            assert np.linalg.norm(joints(p, walk) - joints(truth, walk), axis=-1).max() < 0.015
    filt = poses(log, "pose_filter")  # a filtered solver over the same NaN frames: never garbage
    assert sorted(filt) == list(range(720))
    walk = [f for f in filt if f >= 600]
    assert np.linalg.norm(joints(filt, walk) - joints(truth, walk), axis=-1).mean() < 0.01
    assert g.proc.poll() is None
    exited = [line for line in g.lines if "exited" in line and not any(f"node {n} " in line for n in
                                                                       ("src", "still", "hidden"))]
    assert exited == [], exited
    assert g.stop() == 0


def test_bad_solver_and_calibration_params_fail_the_graph_check(tmp_path, capsys):
    from mocapgraph.cli import main

    g = tmp_path / "g.yaml"
    g.write_text("""\
nodes:
  - name: src
    type: synthetic_actor
  - name: solver
    type: frame_solver
    params: {filter: kalman}
""")
    assert main(["graph", "check", str(g)]) == 2
    err = capsys.readouterr().err
    assert "g.yaml:6" in err and "'kalman' is not one of ['', 'one_euro', 'constant_velocity']" in err
    g.write_text(g.read_text().replace("type: frame_solver\n    params: {filter: kalman}",
                                       "type: calibration\n    params: {gym_seconds: 0}"))
    assert main(["graph", "check", str(g)]) == 2
    assert "gym_seconds" in capsys.readouterr().err
