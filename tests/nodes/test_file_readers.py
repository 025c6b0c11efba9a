"""C3D / TRC replay nodes on real files: layout order, timing, ranges, loops, and bad files as a
new user would meet them (one-line error, exit code 1, state 'error')."""
from __future__ import annotations

import json

import numpy as np

from mocapgraph.formats import read_c3d, read_trc
from mocapgraph.kinematics.skeleton import SkeletonDefinition

MOVEMENT = "c3d/pycgm/Movement_trial.c3d"
WALK_TRC = "trc/opensim-gait2392/subject01_walk1.trc"


def layout_rows(layout: str, labels: list[str]) -> list[int]:
    """Independent reference: where each layout marker sits among the file's labels (-1 absent)."""
    low = [lab.lower() for lab in labels]
    return [low.index(m.lower()) if m.lower() in low else -1
            for m in SkeletonDefinition.from_layout_file(layout).marker_labels]


def test_c3d_replay_publishes_layout_order_at_file_rate(run_node, shared_data) -> None:
    path = shared_data / MOVEMENT
    n = run_node("c3d_reader", {"file": str(path), "layout": "plug_in_gait", "start_frame": 700,
                                "end_frame": 759})
    assert n.wait_exit(10) == 0
    layout = n.messages("marker_layout")
    assert len(layout) == 1
    sk = SkeletonDefinition.from_layout_file("plug_in_gait")
    assert layout[0].labels == list(sk.marker_labels) and layout[0].unplaced == []
    assert "mm -> m" in layout[0].units_note
    recs = n.records("markers")
    assert [r.msg.frame_number for r in recs] == list(range(700, 760))
    trial = read_c3d(path)
    rows = layout_rows("plug_in_gait", trial.labels)
    assert min(rows) >= 0
    for r in recs[::13]:
        want = trial.positions[r.msg.frame_number - trial.first_frame][rows]
        np.testing.assert_array_equal(r.msg.positions, want)
        np.testing.assert_array_equal(r.msg.valid, ~np.isnan(want).any(axis=1))
        assert r.msg.rate_hz == 120.0
    # Capture stamps keep the file's spacing; real-time replay takes the file's duration.
    cap = np.array([r.env.capture_ns for r in recs])
    np.testing.assert_allclose(np.diff(cap), 1e9 / 120, atol=1)
    pub = np.array([r.env.publish_ns for r in recs])
    assert 0.45 < (pub[-1] - pub[0]) / 1e9 < 0.65
    assert n.messages("reader_status")[-1].state == "finished"


def test_c3d_unlabelled_points_are_passed_or_reported_as_unplaced(run_node, shared_data) -> None:
    path = shared_data / MOVEMENT
    raw = run_node("c3d_reader", {"file": str(path), "include_unlabelled": True, "rate_scale": 0.0,
                                  "end_frame": 704}, name="raw")
    mapped = run_node("c3d_reader", {"file": str(path), "include_unlabelled": True, "layout": "plug_in_gait",
                                     "rate_scale": 0.0, "end_frame": 704}, name="mapped")
    assert raw.wait_exit(10) == 0 and mapped.wait_exit(10) == 0
    trial = read_c3d(path, include_unlabelled=True)
    stars = [lab for lab in trial.labels if lab.startswith("*")]
    assert len(stars) > 30
    assert raw.messages("marker_layout")[0].labels == trial.labels      # passed through, file order
    assert raw.messages("markers")[0].positions.shape == (len(trial.labels), 3)
    lay = mapped.messages("marker_layout")[0]
    assert sorted(lay.unplaced) == sorted(stars) and len(lay.labels) == 39
    # Zero-coded / negative-residual samples of unlabelled points arrive as NaN + valid False.
    frames = raw.messages("markers")
    assert [f.frame_number for f in frames] == list(range(695, 705))
    gaps = np.array([~f.valid for f in frames])
    assert gaps.any()
    assert np.isnan(np.array([f.positions for f in frames])[gaps]).all()


def test_trc_replay_fast_with_loop_keeps_stamps_increasing(run_node, shared_data) -> None:
    path = shared_data / WALK_TRC
    n = run_node("trc_reader", {"file": str(path), "layout": "opensim_gait2392", "rate_scale": 4.0,
                                "loop": True, "start_frame": 141})
    recs = n.wait_for(lambda: n.records("markers")[:25] if len(n.records("markers")) >= 25 else None,
                      what="25 frames")
    nums = [r.msg.frame_number for r in recs]
    assert nums[:11] == list(range(141, 152)) and nums[11:22] == list(range(141, 152))
    cap = np.array([r.env.capture_ns for r in recs])
    np.testing.assert_allclose(np.diff(cap), 1e9 / 60, atol=1)          # file spacing across the loop
    pub = np.array([r.env.publish_ns for r in recs])
    assert (pub[-1] - pub[0]) / 1e9 < 24 / 60 / 4 * 1.5                  # four times the file's rate
    trial = read_trc(path)
    rows = layout_rows("opensim_gait2392", trial.labels)
    lay = n.messages("marker_layout")[0]
    absent = [lab for lab, i in zip(lay.labels, rows) if i < 0]
    assert absent  # the walk trial lacks the static trial's medial knee/ankle markers
    want = np.where(np.array(rows)[:, None] >= 0, trial.positions[141 - 1][np.maximum(rows, 0)], np.nan)
    np.testing.assert_array_equal(recs[0].msg.positions, want)
    assert not recs[0].msg.valid[[lay.labels.index(a) for a in absent]].any()
    assert np.isnan(recs[0].msg.residual).all()                         # TRC has no residuals
    assert "mm -> m" in lay.units_note and "Z-up" in lay.units_note


def error_of(n) -> str:
    assert n.wait_exit(10) == 1
    status = n.messages("reader_status")
    assert status and status[-1].state == "error"
    return status[-1].detail


def test_missing_file_is_one_line_and_exit_1(run_node, tmp_path) -> None:
    n = run_node("c3d_reader", {"file": str(tmp_path / "nope.c3d")})
    detail = error_of(n)
    assert "nope.c3d" in detail and "not found" in detail and "\n" not in detail
    assert n.logged("nope.c3d", level="ERROR")
    assert n.messages("markers") == []


def test_truncated_c3d_is_one_line_and_exit_1(run_node, shared_data, tmp_path) -> None:
    data = (shared_data / MOVEMENT).read_bytes()
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(data[: len(data) // 3])
    detail = error_of(run_node("c3d_reader", {"file": str(cut)}))
    assert detail.startswith("cut.c3d: ") and "\n" not in detail


def test_trc_with_broken_header_is_one_line_and_exit_1(run_node, tmp_path) -> None:
    bad = tmp_path / "broken.trc"
    bad.write_text("PathFileType\t4\t(X/Y/Z)\tbroken.trc\nDataRate\tCameraRate\nsixty\tsixty\n"
                   "Frame#\tTime\tA\n\t\tX1\tY1\tZ1\n1\t0\t1\t2\t3\n")
    detail = error_of(run_node("trc_reader", {"file": str(bad)}))
    assert detail.startswith("broken.trc: ") and "\n" not in detail


def test_wrong_layout_and_frame_range_are_clear_errors(run_node, shared_data) -> None:
    path = str(shared_data / MOVEMENT)
    d1 = error_of(run_node("c3d_reader", {"file": path, "layout": "opensim_gait2392"}, name="a"))
    assert "opensim_gait2392" in d1 and "none of its" in d1
    d2 = error_of(run_node("c3d_reader", {"file": path, "start_frame": 10}, name="b"))
    assert "start_frame 10" in d2 and "695..1017" in d2
    d3 = error_of(run_node("c3d_reader", {"file": path, "layout": "no_such_layout"}, name="c"))
    assert "no_such_layout" in d3


def test_status_reports_progress_counters(run_node, shared_data) -> None:
    n = run_node("c3d_reader", {"file": str(shared_data / MOVEMENT), "end_frame": 710, "rate_scale": 0.0})
    assert n.wait_exit(10) == 0
    last = n.messages("reader_status")[-1]
    assert last.state == "finished" and last.progress == 1.0
    assert json.loads(last.data_json)["frames_sent"] == 16
