"""The actor pipeline as real processes: synthetic actor -> calibration -> solver -> logger.

Sources run faster than real time; calibration and solver go by capture stamps, so they see a
120 Hz capture. Poses are compared with the source's exact ground truth frame by frame.
"""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

from actor_support import ACTOR_SOURCE, PIPELINE, joints, poses, read_jsonl, states, statuses, wait_until
from graph_helpers import CommandSender
from mocapgraph.kinematics.model import load_model

SOURCE = """\
  - name: src
    type: actor_source:ActorSource
    params: {{duration_s: {duration}, speed: 4.0, seed: 3}}
""".replace("actor_source:ActorSource", ACTOR_SOURCE)


def _pipeline_graph(log, model_file, rate_scale: float = 3.0, start_s: float = 0.0) -> str:
    """The shipped actor pipeline on the real synthetic actor node: 1 s base pose, 16 s gym, 5 s of
    performance at ``rate_scale`` x real time (3x: 360 frames/s, what two loaded cores carry through
    reader, calibration, solver and logger while only the performance is solved; at 6x the solver's
    input queue overflowed on such a machine), from ``start_s`` into that session on."""
    return f"""\
include:
  - file: {PIPELINE}
    args: {{model_file: {model_file}}}
nodes:
  - name: reader
    type: synthetic_actor
    params: {{noise_mm: 1.0, rate_scale: {rate_scale}, duration_s: 22.0, loop: false, seed: 2, start_s: {start_s}}}
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [actor_pose, ground_truth, calibration_status]}}
"""


@pytest.mark.timing
def test_auto_calibration_solves_like_the_ground_truth_and_a_reload_solves_identically(launch_graph, tmp_path):
    model_file = tmp_path / "actor_model.json"
    log1, log2 = tmp_path / "run1.jsonl", tmp_path / "run2.jsonl"
    g = launch_graph(_pipeline_graph(log1, model_file))
    g.wait_ready()
    g.wait_for("node reader exited with code 0", timeout=60)
    t_end = time.monotonic()
    # the source may finish ahead of the solver (faster than real time): stop once the
    # last frame's pose has reached the log, so nothing still queued is cut off by the stop
    # (a deadline against hangs: with the cores oversubscribed twice the last pose came 1-3 s late)
    wait_until(lambda: 2639 in poses(log1), timeout=90, what="the last frame's pose", graph=g)
    print(f"\nlast pose logged {time.monotonic() - t_end:.1f} s after the source ended")
    assert g.stop() == 0
    seq = states(log1, "calibration")
    assert seq == ["finding_base_pose", "base_pose_found", "capturing_gym", "gym_captured", "processing",
                   "calibrated"], seq
    final = statuses(log1, "calibration")[-1]
    report = json.loads(final["data_json"])
    assert report["origin"] == "calibration" and report["model_file"] == str(model_file)
    assert report["base_frame"] == 0
    assert all(j["reliable"] and j["residual_mm"] < 5.0 and j["rom_deg"] > 25 for j in report["joints"])
    capturing = [m["progress"] for m in statuses(log1, "calibration") if m["state"] == "capturing_gym"]
    assert capturing == sorted(capturing) and capturing[0] == 0.0 and 0.5 < capturing[-1] <= 1.0
    assert len(capturing) >= 2  # periodic 2 Hz reports during the 5.3 s (wall) capture; fewer on a loaded machine
    model = load_model(model_file, "kiip_full_body", load_model(model_file).marker_labels)
    assert model.n_gym_frames == 961  # base pose + 16 s at 60 frames/s

    p1, truth = poses(log1), poses(log1, "ground_truth")
    frames = sorted(p1)
    assert len(truth) == 2640 and frames[-1] == 2639
    assert frames[0] > 1921 and frames == list(range(frames[0], 2640))  # from calibration on, none lost
    err = np.linalg.norm(joints(p1, frames) - joints(truth, frames), axis=-1)
    print(f"\nlive pipeline: {len(frames)} frames, joint error mean {1000 * err.mean():.2f} mm, "
          f"max {1000 * err.max():.2f} mm")
    assert err.mean() < 0.005 and err.max() < 0.02
    assert all(set(p1[f]["joint_quality"]) == {2} for f in frames)

    # A second session loads the saved model at once and interprets the same frames identically.
    # It solves every frame it is sent, so its source runs at the camera's own 120 Hz: at 3x, with
    # the two cores oversubscribed twice, the solver fell behind and its queue dropped frames
    # 2001-2639 (measured); a live capture must not lose any. Its source starts a quarter second
    # before the first frame solved above (that was frame 1998 here, 16.6 s into the session; at
    # least 15 s in, frame 1800): the base pose and gym before would only be waited through, in
    # real time.
    start = max(1800, frames[0] - 30)
    g2 = launch_graph(_pipeline_graph(log2, model_file, rate_scale=1.0, start_s=start / 120.0))
    g2.wait_ready()
    g2.wait_for("node reader exited with code 0", timeout=60)
    t_end = time.monotonic()
    wait_until(lambda: 2639 in poses(log2), timeout=90, what="the last frame's pose", graph=g2)
    print(f"second session: last pose logged {time.monotonic() - t_end:.1f} s after the source ended")
    assert g2.stop() == 0
    assert states(log2, "calibration") == ["calibrated"]
    assert json.loads(statuses(log2, "calibration")[-1]["data_json"])["origin"] == f"loaded {model_file}"
    p2 = poses(log2)
    # from (almost) the first frame: the reader may send one or two before the model reaches the solver
    assert start <= min(p2) < start + 24 and sorted(p2) == list(range(min(p2), 2640)), g2.output
    assert min(p2) < frames[0]
    for f in frames:
        assert p2[f]["joint_positions"] == p1[f]["joint_positions"], f
        assert p2[f]["limb_orientations"] == p1[f]["limb_orientations"], f


@pytest.fixture(scope="module")
def side_graphs(launch_module_graph, tmp_path_factory) -> dict:
    """The commanded-calibration graph and the unreliable-joints graph, launched together: each
    spends seconds starting up, neither is judged on time, and each test stops its own."""
    import warnings

    from mocapgraph.kinematics.calibration.calibrate import CalibrationWarning, calibrate
    from mocapgraph.kinematics.model import save_model
    from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
    from mocapgraph.kinematics.synthetic.motion import MotionScript

    commanded, unreliable = tmp_path_factory.mktemp("commanded"), tmp_path_factory.mktemp("unreliable")
    cmd = CommandSender("calibration_command", "the calibration node")
    log = commanded / "status.jsonl"
    g_cmd = launch_module_graph(f"""\
external:
  - {{topic: calibration_command, type: NodeCommand, endpoint: "tcp://127.0.0.1:{cmd.port}"}}
nodes:
{SOURCE.format(duration=60.0)}\
  - name: cal
    type: calibration
    params: {{layout: kiip_full_body, model_file: {commanded / 'actor_model.json'}}}  # save/load: in its folder
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [calibration_status, skeleton_model]}}
""")
    # A model whose calibration found some joints unreliable (a 60 deg bar on a short gym), made
    # while the first graph starts up.
    actor = SyntheticActor("kiip_full_body", rate=120.0, seed=3, script=MotionScript(gym_block_s=1.0),
                           options=CaptureOptions(noise_mm=1.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        model = calibrate(actor.skeleton, actor.capture(0, 600).markers[::2], rate_hz=60.0, min_rom_deg=60.0)
    save_model(model, unreliable / "m.json")
    poses_log = unreliable / "poses.jsonl"
    g_unreliable = launch_module_graph(f"""\
nodes:
{SOURCE.format(duration=3.0)}\
  - name: solver
    type: frame_solver
    params: {{model_file: {unreliable / "m.json"}}}
  - name: solver_global
    type: frame_solver
    params: {{model_file: {unreliable / "m.json"}, fit: global}}
    remap: {{actor_pose: actor_pose_global}}
  - name: solver_lowpass
    type: frame_solver
    params: {{model_file: {unreliable / "m.json"}, fit: global, lowpass_hz: 20.0, lowpass_lag_s: 0.1, lowpass_rate_hz: 120.0}}
    remap: {{actor_pose: actor_pose_lowpass}}
  - name: logger
    type: topic_logger
    params: {{path: {poses_log}, topics: [actor_pose, actor_pose_global, actor_pose_lowpass, ground_truth]}}
""")
    yield {"commanded": (g_cmd, cmd, log, commanded), "unreliable": (g_unreliable, model, poses_log)}
    cmd.close()


def test_calibration_driven_by_commands_reports_every_state(side_graphs):
    g, cmd, log, tmp_path = side_graphs["commanded"]
    saved = tmp_path / "commanded.json"
    g.wait_ready()
    cmd.wait_subscriber(15.0)

    def last() -> dict:
        st = statuses(log, "cal")
        return st[-1] if st else {}

    def reach(state: str, detail: str = "") -> dict:
        return wait_until(lambda: (m := last()).get("state") == state and detail in m["detail"] and m,
                          what=f"state {state} {detail!r}", graph=g)

    reach("idle")
    cmd.send("process")
    reach("idle", "nothing captured")
    cmd.send("capture_gym", seconds=1.0)
    reach("idle", "no base pose yet")
    cmd.send("find_base_pose", target="cal")
    found = reach("base_pose_found")
    cmd.send("capture_gym", seconds=4.0, rate_hz=30.0)
    captured = reach("gym_captured")
    assert json.loads(captured["data_json"])["frames"] in (120, 121)
    cmd.send("process")
    done = reach("calibrated")
    report = json.loads(done["data_json"])
    assert report["origin"] == "calibration" and len(report["joints"]) == 16
    assert report["base_frame"] == json.loads(found["data_json"])["base_frame"]
    cmd.send("save", path=str(saved))
    reach("calibrated", f"saved to {saved}")
    assert load_model(saved).layout == "kiip_full_body"
    n = len(statuses(log, "cal"))
    cmd.send("reset", target="someone_else")  # not for this node: ignored
    cmd.send("save", target="cal", path=str(saved) + ".2")
    reach("calibrated", f"saved to {saved}.2")
    assert {m["state"] for m in statuses(log, "cal")[n:]} == {"calibrated"}
    cmd.send("reset")
    reach("idle", "reset")
    cmd.send("load", path=str(saved))
    reach("calibrated", f"loaded {saved}")
    cmd.send("load", path=str(tmp_path / "nope.json"))
    reach("error", "no such skeleton model file")
    cmd.send("dance")
    reach("error", "unknown command 'dance'")
    cmd.send("capture_gym", seconds="long")
    cmd.send("find_base_pose")
    reach("base_pose_found")
    cmd.send("capture_gym", seconds=-1)
    reach("base_pose_found", "seconds must be > 0")

    seq = states(log, "cal")
    assert seq[:7] == ["idle", "finding_base_pose", "base_pose_found", "capturing_gym", "gym_captured",
                       "processing", "calibrated"], seq
    progress = [m["progress"] for m in statuses(log, "cal") if m["state"] == "capturing_gym"]
    assert len(progress) >= 2 and progress[0] == 0.0 and max(progress) > 0.4  # reported at 2 Hz
    models = read_jsonl(log, "skeleton_model")
    assert len(models) == 2 and models[0]["msg"] == models[1]["msg"]  # calibrated, then the same reloaded
    assert g.proc.poll() is None
    assert g.stop() == 0
    cmd.close()


def test_the_solver_node_never_calls_an_unreliable_joint_good(side_graphs):
    # A model whose calibration found some joints unreliable (a 60 deg bar on a short gym): the
    # live solver node publishes them estimated on every frame, the others good.
    g, model, log = side_graphs["unreliable"]
    bad = ~model.quality.reliable
    assert bad.any() and not bad.all()
    g.wait_ready()
    g.wait_for("node src exited with code 0", timeout=30)
    wait_until(lambda: min(len(poses(log, t)) for t in ("actor_pose", "actor_pose_global", "actor_pose_lowpass")) > 300,
               what="poses", graph=g)
    assert g.stop() == 0
    truth = poses(log, "ground_truth")
    errors = {}
    for topic in ("actor_pose", "actor_pose_global", "actor_pose_lowpass"):  # segment-wise, global, low-passed
        got = poses(log, topic)
        q = np.array([p["joint_quality"] for p in got.values()])
        assert (q[:, bad] == 1).all() and (q[:, ~bad] == 2).mean() > 0.99
        frames = sorted(set(got) & set(truth))
        err = np.linalg.norm(joints(got, frames) - joints(truth, frames), axis=-1)
        assert np.median(err[:, ~bad]) < 0.005, topic
        run = [f for f in frames if f + 1 in got and f + 2 in got]
        off = [joints(got, [f + k for f in run]) - joints(truth, [f + k for f in run]) for k in (0, 1, 2)]
        accel = off[2] - 2 * off[1] + off[0]      # the error's own jitter, the motion taken out
        errors[topic] = (err[:, ~bad].mean(), np.sqrt(np.nanmean(accel[:, ~bad] ** 2)))
    # The low-passed node's poses come 12 frames late, each under its own frame number: against
    # the truth of that frame no worse than the same global fit unfiltered (this short-gym model's
    # own centre errors dominate both), and far less jitter (the error's second
    # difference, frame to frame).
    (e_g, j_g), (e_l, j_l) = errors["actor_pose_global"], errors["actor_pose_lowpass"]
    print(f"\nreliable joints, global fit: error {1e3 * e_g:.2f} mm, jitter {1e3 * j_g:.3f} mm; "
          f"low-passed at 20 Hz: {1e3 * e_l:.2f} mm, {1e3 * j_l:.3f} mm")
    assert e_l <= 1.02 * e_g and j_l < 0.5 * j_g
