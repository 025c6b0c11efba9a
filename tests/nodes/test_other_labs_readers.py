"""Reader nodes, graph checks and batch commands on files "from other labs" (issue 11): real node
threads and sockets, the real CLI, fixtures written here with their ground truth."""
from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest

from lab_fixtures import (PERSON_LABELS, RATE, bvh_with_root_offset, kinect_csv, person_frames,
                          write_points_c3d)
from mocapgraph.bag.reader import BagReader
from mocapgraph.cli import main
from mocapgraph.formats import MarkerTrial, read_c3d, write_c3d, write_trc

Y_UP_TO_WORLD = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])


def status_data(node) -> dict:
    return json.loads(node.messages("reader_status")[-1].data_json)


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


# ----- nodes -------------------------------------------------------------------------------------
def test_c3d_reader_up_axis_param_and_status_naming_the_file(run_node, tmp_path) -> None:
    truth = person_frames(12)
    path = write_points_c3d(tmp_path / "y_up.c3d", PERSON_LABELS, truth @ Y_UP_TO_WORLD, y_screen=None)
    n = run_node("c3d_reader", {"file": str(path), "up_axis": "y", "rate_scale": 0.0})
    assert n.wait_exit(10) == 0
    frames = n.messages("markers")
    np.testing.assert_allclose(np.array([f.positions for f in frames]), truth, atol=1e-6)
    assert "+Y-up -> Z-up (as requested" in n.messages("marker_layout")[0].units_note
    assert status_data(n)["file"] == str(path.resolve())


def test_c3d_segment_reader_publishes_the_rotation_group(run_node, tmp_path) -> None:
    T = 8
    poses = np.tile(np.eye(4), (T, 2, 1, 1))
    poses[:, 0, :3, 3] = [0.0, 0.0, 1.0]
    poses[:, 1, :3, 3] = [0.0, 0.1, 0.5]
    poses[:, 1, :3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # 90 deg about Z
    path = write_points_c3d(tmp_path / "markerless.c3d", [], np.zeros((T, 0, 3)), rotations=poses,
                            rotation_labels=["pelvis", "r_thigh"], first_frame=11)
    n = run_node("c3d_segment_reader", {"file": str(path), "rate_scale": 0.0, "start_frame": 13})
    assert n.wait_exit(10) == 0
    info = n.messages("skeleton_info")[0]
    assert info.joint_names == ["pelvis", "r_thigh"] and list(info.joint_parent) == [-1, -1]
    got = n.records("skeleton_pose")
    assert [r.msg.frame_number for r in got] == list(range(13, 19))      # the file's frame numbers
    np.testing.assert_allclose(got[0].msg.joint_positions, [[0, 0, 1.0], [0, 0.1, 0.5]], atol=1e-9)
    np.testing.assert_allclose(np.abs(got[0].msg.joint_orientations[1]), [np.sqrt(0.5), 0, 0, np.sqrt(0.5)],
                               atol=1e-9)
    assert (got[0].msg.tracking_state == 2).all()
    # the marker reader refuses the same file in one line, exit 1, state error
    m = run_node("c3d_reader", {"file": str(path)}, name="markers")
    assert m.wait_exit(10) == 1
    st = m.messages("reader_status")[-1]
    assert st.state == "error" and st.detail.startswith("markerless.c3d: holds no markers, only 2 segment poses")


def test_kinect_reader_counts_samples_behind_the_sensor(run_node, tmp_path) -> None:
    path = kinect_csv(tmp_path / "k.csv", frames=6, behind=((0, 3, 2), (4, 3, 1), (4, 9, 2), (5, 0, 2)))
    n = run_node("kinect_reader", {"file": str(path), "rate_scale": 0.0})
    assert n.wait_exit(10) == 0
    poses = [m for m in n.messages("skeleton_pose")]
    assert len(poses) == 6 and poses[4].tracking_state[3] == 0 and np.isnan(poses[4].joint_positions[9]).all()
    d = status_data(n)
    assert d["behind_sensor"] == 4 and d["file"] == str(path.resolve())


def test_bvh_player_root_offset_feet_on_the_floor(run_node, tmp_path) -> None:
    path = bvh_with_root_offset(tmp_path / "offset.bvh")
    n = run_node("bvh_player", {"file": str(path), "rate_scale": 0.0, "scale": 0.01})
    assert n.wait_exit(10) == 0
    info = n.messages("skeleton_info")[0]
    feet = [info.joint_names.index(f) for f in ("LeftFoot_End", "RightFoot_End")]
    z = np.array([m.joint_positions[feet, 2] for m in n.messages("skeleton_pose")])
    np.testing.assert_allclose(z, 0.0, atol=1e-9)
    assert info.rest_offsets[info.joint_names.index("Hips"), 2] == pytest.approx(0.9)


# ----- graph check --------------------------------------------------------------------------------
GRAPH = """\
# a lab's graph naming its capture
nodes:
  - name: reader
    type: c3d_reader
    params:
      rate_scale: 0.0
      file: {capture}
  - name: log
    type: topic_logger
    params: {{path: {log}, topics: [markers]}}
"""


def test_graph_check_refuses_a_missing_or_unreadable_capture(tmp_path, capsys) -> None:
    graph = tmp_path / "lab.yaml"
    cases = [(tmp_path / "absent.c3d", "absent.c3d: file not found"),
             (tmp_path, "is a directory, not a file"),
             ("''", "no file given")]
    for capture, want in cases:
        graph.write_text(GRAPH.format(capture=capture, log=tmp_path / "l.jsonl"))
        for cmd in (["graph", "check"], ["launch"]):
            code, out, err = run(capsys, *cmd, graph)
            assert code == 2, (cmd, out, err)
            assert err.count("\n") == 1 and "Traceback" not in err
            # file:line: key: message; line 7 is where the file is named
            assert err.startswith(f"mocapgraph: {graph}:7: nodes[reader].params.file: "), err
            assert want in err, err
    assert not (tmp_path / "l.jsonl").exists()
    good = write_points_c3d(tmp_path / "here.c3d", PERSON_LABELS, person_frames(3), y_screen="+Z")
    graph.write_text(GRAPH.format(capture=good, log=tmp_path / "l.jsonl"))
    assert run(capsys, "graph", "check", graph)[0] == 0
    # drawing a graph needs no capture
    graph.write_text(GRAPH.format(capture=tmp_path / "absent.c3d", log=tmp_path / "l.jsonl"))
    code, out, _ = run(capsys, "graph", "show", graph)
    assert code == 0 and "reader (c3d_reader)" in out


# ----- batch commands ------------------------------------------------------------------------------
def test_bag_convert_up_option_and_rotation_group(tmp_path, capsys) -> None:
    truth = person_frames(10)
    y = write_points_c3d(tmp_path / "y_up.c3d", PERSON_LABELS, truth @ Y_UP_TO_WORLD, y_screen=None)
    code, out, _ = run(capsys, "bag", "convert", y, "-o", tmp_path / "y.mcap", "--up", "Y")
    assert code == 0
    with BagReader(tmp_path / "y.mcap") as r:
        got = np.array([m.positions for _, m in r.decoded("markers")])
    np.testing.assert_allclose(got, truth, atol=1e-6)
    poses = np.tile(np.eye(4), (10, 1, 1, 1))
    poses[:, 0, :3, 3] = truth[:, 1]
    seg = write_points_c3d(tmp_path / "both.c3d", PERSON_LABELS, truth, y_screen="+Z", rotations=poses,
                           rotation_labels=["pelvis"])
    code, out, _ = run(capsys, "bag", "convert", seg, "-o", tmp_path / "both.mcap")
    assert code == 0 and "skeleton_pose (10)" in out and "markers (10)" in out, out
    with BagReader(tmp_path / "both.mcap") as r:
        sk = np.array([m.joint_positions[0] for _, m in r.decoded("skeleton_pose")])
        info = next(m for _, m in r.decoded("skeleton_info"))
    assert info.joint_names == ["pelvis"]
    np.testing.assert_allclose(sk, truth[:, 1], atol=1e-6)
    with pytest.raises(SystemExit) as e:
        main(["bag", "convert", str(y), "-o", str(tmp_path / "z.mcap"), "--up", "x"])
    assert e.value.code == 2 and "--up: invalid choice: 'x'" in capsys.readouterr().err


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    """A one-arm synthetic gym (ground truth) as files: a static C3D, a ROM TRC without RFIN."""
    from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
    from mocapgraph.kinematics.synthetic.motion import MotionScript

    d = tmp_path_factory.mktemp("arm")
    cap = SyntheticActor("one_arm", rate=60.0, seed=2, script=MotionScript(gym_block_s=1.0),
                         options=CaptureOptions(noise_mm=0.5)).capture(0, 300)
    labels = list(cap.skeleton.marker_labels)
    write_c3d(d / "static.c3d", MarkerTrial(labels, cap.markers[:30], None, 60.0))
    keep = [i for i, lab in enumerate(labels) if lab != "RFIN"]
    write_trc(d / "rom_no_rfin.trc", MarkerTrial([labels[i] for i in keep], cap.markers[:, keep], None, 60.0))
    write_trc(d / "rom.trc", MarkerTrial(labels, cap.markers, None, 60.0))
    late = MarkerTrial(labels, cap.markers[100:160], None, 60.0, first_frame=15)   # starts at 14/60 s
    write_c3d(d / "late.c3d", late)
    late.extra["time_s"] = 0.23 + np.arange(60) / 60.0
    write_trc(d / "late.trc", late)
    return d


def test_calibrate_allow_missing_names_what_is_missing_per_file(arm, capsys, tmp_path) -> None:
    code, _, err = run(capsys, "calibrate", arm / "static.c3d", arm / "rom_no_rfin.trc", "--layout", "one_arm",
                       "-o", tmp_path / "m.json")
    assert code == 2 and "rom_no_rfin.trc: layout 'one_arm' names markers the capture lacks: RFIN" in err
    code, out, _ = run(capsys, "calibrate", arm / "static.c3d", arm / "rom_no_rfin.trc", "--layout", "one_arm",
                       "-o", tmp_path / "m.json", "--allow-missing")
    assert code == 0, out
    assert "note: rom_no_rfin.trc: 1 layout markers absent (always missing): RFIN" in out
    assert "static.c3d: 1 layout" not in out                                  # static has them all
    code, _, err = run(capsys, "calibrate", arm / "rom_no_rfin.trc", "--layout", "one_arm", "-o",
                       tmp_path / "x.json", "--allow-missing")
    assert code == 2 and err.count("\n") == 1
    assert "markers absent from every file: RFIN" in err


def test_solve_csv_keeps_the_trial_start_time(arm, capsys, tmp_path) -> None:
    assert run(capsys, "calibrate", arm / "rom.trc", "--layout", "one_arm", "-o", tmp_path / "m.json")[0] == 0
    for name, t0 in (("late.trc", 0.23), ("late.c3d", 14 / 60.0)):
        code, out, _ = run(capsys, "solve", arm / name, "--model", tmp_path / "m.json", "-o", tmp_path / "o.csv",
                           "--frames", "5:")
        assert code == 0, out
        rows = np.genfromtxt(tmp_path / "o.csv", delimiter=",", skip_header=1)
        np.testing.assert_allclose(rows[:, 1], t0 + (5 + np.arange(55)) / 60.0, atol=1e-6)
        assert rows[0, 0] == 20                                        # frame numbers as the file has them
    code, _, err = run(capsys, "solve", arm / "late.c3d", "--model", tmp_path / "m.json", "-o", tmp_path / "o.trc",
                       "--up", "z")
    assert code == 0
    assert run(capsys, "bag", "convert", arm / "late.c3d", "-o", tmp_path / "late.mcap")[0] == 0
    code, _, err = run(capsys, "solve", tmp_path / "late.mcap", "--model", tmp_path / "m.json", "-o",
                       tmp_path / "b.csv", "--up", "y")
    assert code == 2 and err.count("\n") == 1 and "--up y applies to C3D and TRC files; a bag is already" in err
    back = read_c3d(arm / "late.c3d")
    from mocapgraph.formats import read_trc

    assert read_trc(tmp_path / "o.trc").file_times_s[0] == pytest.approx(back.file_times_s[0], abs=1e-6)


def test_c3d_reader_warns_of_a_renamed_duplicate_and_a_layout_leaves_it_unplaced(run_node, tmp_path) -> None:
    truth = person_frames(6)
    pts = np.concatenate([truth, truth[:, 1:2] + [0.0, 0.05, 0.0]], axis=1)      # two "PELV"
    layout = tmp_path / "person.yaml"
    layout.write_text(textwrap.dedent("""\
        name: person
        limbs:
          - name: body
            markers: [HEAD, PELV, LFOOT]
          - name: right
            parent: body
            joint: {name: hip_r, type: ball}
            markers: [RFOOT, PELV_2, HEAD_2]
        """))
    path = write_points_c3d(tmp_path / "dup.c3d", list(PERSON_LABELS) + ["PELV"], pts, y_screen="+Z")
    n = run_node("c3d_reader", {"file": str(path), "rate_scale": 0.0})
    assert n.wait_exit(10) == 0
    assert n.messages("marker_layout")[0].labels == ["HEAD", "PELV", "LFOOT", "RFOOT", "PELV_2"]
    np.testing.assert_allclose(n.messages("markers")[0].positions[4], pts[0, 4], atol=1e-6)
    warned = [line for line in n.log().splitlines() if line.startswith("WARNING ") and "duplicate label" in line]
    assert len(warned) == 1 and "points 1 and 4 share it; point 4 renamed 'PELV_2'" in warned[0]
    # a layout naming only PELV gets the first one; the renamed one is reported unplaced, not merged
    only = tmp_path / "only.yaml"
    only.write_text(layout.read_text().replace("[RFOOT, PELV_2, HEAD_2]", "[RFOOT]\n    shared: [PELV, LFOOT]"))
    m = run_node("c3d_reader", {"file": str(path), "rate_scale": 0.0, "layout": str(only)}, name="only")
    assert m.wait_exit(10) == 0
    lay = m.messages("marker_layout")[0]
    assert lay.unplaced == ["PELV_2"]
    np.testing.assert_allclose(m.messages("markers")[0].positions[lay.labels.index("PELV")], pts[0, 1], atol=1e-6)
    # a layout may name the renamed one to use it
    m = run_node("c3d_reader", {"file": str(path), "rate_scale": 0.0, "layout": str(layout)}, name="mapped")
    assert m.wait_exit(10) == 0
    lay = m.messages("marker_layout")[0]
    np.testing.assert_allclose(m.messages("markers")[0].positions[lay.labels.index("PELV_2")], pts[0, 4], atol=1e-6)


def test_segment_reader_feeds_the_skeleton_pipeline_as_a_launched_graph(launch_graph, tmp_path) -> None:
    from pathlib import Path

    from graph_helpers import read_jsonl, wait_until

    T = 30
    poses = np.tile(np.eye(4), (T, 2, 1, 1))
    poses[:, :, :3, 3] = [[0.0, 0.0, 1.0], [0.0, 0.1, 0.5]]
    path = write_points_c3d(tmp_path / "markerless.c3d", [], np.zeros((T, 0, 3)), rotations=poses,
                            rotation_labels=["pelvis", "r_thigh"])
    pipeline = Path(__file__).resolve().parents[2] / "graph_configs" / "skeleton_pipeline.yaml"
    g = launch_graph(f"""\
include:
  - file: {pipeline}
    args: {{session_log: {tmp_path / 's.jsonl'}, viewer: false}}
nodes:
  - name: reader
    type: c3d_segment_reader
    params: {{file: {path}, rate_scale: 4.0}}
  - name: poses
    type: topic_logger
    params: {{path: {tmp_path / 'p.jsonl'}, topics: [skeleton_pose]}}
""")
    g.wait_ready(30)
    done = wait_until(lambda: [r for r in read_jsonl(tmp_path / "s.jsonl", "reader_status")
                               if r["msg"]["state"] == "finished"], what="finished", graph=g)
    assert json.loads(done[-1]["msg"]["data_json"])["file"] == str(path.resolve())
    info = read_jsonl(tmp_path / "s.jsonl", "skeleton_info")[0]["msg"]
    assert info["joint_names"] == ["pelvis", "r_thigh"] and info["source"] == "c3d_segments"
    wait_until(lambda: len(read_jsonl(tmp_path / "p.jsonl", "skeleton_pose")) == T, what="every pose", graph=g)
    assert "Traceback" not in g.output
