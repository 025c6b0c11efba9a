"""The video skeleton sources as processes: one camera and four cameras of the Pose2Sim demo
publish Kinect v2 skeletons; a video with no person and a missing camera fail in one line."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mediapipe")

from mocapgraph.formats import KINECT_V2_JOINTS  # noqa: E402
from mocapgraph.video.pose_models import resolve  # noqa: E402


# the shared_data fixture's folder (tests/conftest.py), here for the module-scoped runs
DEMO = (Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "video" / "pose2sim_demo").resolve()


@pytest.fixture(scope="module")
def offline(run_module_node) -> dict:
    """The one-camera and the four-camera estimations (``rate_scale: 0``: as fast as the estimator
    goes), started together at the first test that needs one: each estimator uses one core, so the
    two share both instead of queueing."""
    if not DEMO.is_dir():
        pytest.skip("../shared/data/video/pose2sim_demo is absent")
    return {"one": run_module_node("video_pose_reader", {"file": str(DEMO / "cam02.mp4"), "rate_scale": 0.0}),
            "four": run_module_node("multiview_pose", {"file": str(DEMO / "Calib.qca.txt"), "rate_scale": 0.0})}


def test_video_pose_reader_publishes_a_skeleton_for_every_frame(offline) -> None:
    n = offline["one"]
    assert n.wait_exit(180) == 0        # 100 frames; minutes only on a machine loaded to 250 ms a frame
    info = n.messages("skeleton_info")[0]
    assert info.source == "video_mediapipe" and info.joint_names == list(KINECT_V2_JOINTS)
    poses = n.messages("skeleton_pose")
    assert len(poses) == 100
    P = np.array([p.joint_positions for p in poses])
    q = np.array([p.tracking_state for p in poses])
    assert np.isfinite(P[:, 0]).mean() >= 0.95
    assert np.isnan(P[q == 0]).all() and np.isfinite(P[q > 0]).all()
    status = n.messages("reader_status")
    assert json.loads(status[-1].data_json)["person_frames"] == 100
    states = [m.state for m in status]
    assert states.index("estimating") < states.index("playing")   # ready first, estimated after start


def test_multiview_pose_triangulates_the_four_cameras(offline) -> None:
    n = offline["four"]
    assert n.wait_exit(300) == 0        # 4 x 100 frames estimated after start
    info = n.messages("skeleton_info")[0]
    assert info.source == "video_multiview"
    P = np.array([p.joint_positions for p in n.messages("skeleton_pose")])
    assert P.shape == (100, 25, 3)
    feet = np.nanmin(P[:, [15, 19], 2], axis=1)
    head = P[:, 3, 2]
    assert np.nanmedian(head - feet) > 1.3          # a standing adult, metres, Z up
    thigh = np.linalg.norm(P[:, 13] - P[:, 12], axis=-1)   # KneeLeft - HipLeft: held at its first-second length
    assert np.nanstd(thigh) < 1e-9 and 0.3 < np.nanmean(thigh) < 0.5
    status = json.loads(n.messages("reader_status")[-1].data_json)
    assert "reprojection_px" in status
    assert status["pose_model"] == resolve("auto")[0]      # heavy, when scripts/setup.sh installed it


def test_missing_camera_and_no_person_fail_in_one_line(run_node, shared_data, tmp_path) -> None:
    demo = shared_data / "video" / "pose2sim_demo"
    (tmp_path / "side.mp4").symlink_to(demo / "cam02.mp4")      # a video the calibration has no camera for
    (tmp_path / "broken.mp4").write_bytes((demo / "cam01.mp4").read_bytes()[:3000])   # the header only
    import cv2
    path = tmp_path / "nobody.mp4"
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (320, 240))
    for _ in range(10):
        out.write(np.full((240, 320, 3), 120, np.uint8))
    out.release()
    # three independent nodes, started at once (each start-up spends a core's second importing)
    side = run_node("multiview_pose", {"file": str(demo / "Calib.qca.txt"),
                                       "videos": [str(demo / "cam01.mp4"), str(tmp_path / "side.mp4")]})
    broken = run_node("video_pose_reader", {"file": str(tmp_path / "broken.mp4")})
    nobody = run_node("video_pose_reader", {"file": str(path)})
    n = side
    assert n.wait_exit(30) == 1
    detail = n.messages("reader_status")[-1].detail
    assert detail == "Calib.qca.txt: no camera for side (its cameras: cam01, cam02, cam03, cam04)"
    assert n.log().strip().splitlines() == [f"ERROR {detail}"]
    n = broken
    assert n.wait_exit(30) == 1
    detail = n.messages("reader_status")[-1].detail
    assert detail.startswith("broken.mp4: ") and n.log().strip().splitlines() == [f"ERROR {detail}"]
    print(detail)
    n = nobody
    assert n.wait_exit(60) == 1
    assert n.messages("reader_status")[-1].detail == "nobody.mp4: no person found in any of its 10 frames"
    assert n.log().strip().splitlines() == ["ERROR nobody.mp4: no person found in any of its 10 frames"]


def test_video_camera_reader_streams_a_video_as_if_live(run_node, shared_data) -> None:
    path = shared_data / "video" / "pose2sim_demo" / "cam01.mp4"
    n = run_node("video_camera_reader", {"camera": str(path), "calibrate_s": 0.05})
    assert n.wait_exit(60) == 0
    info = n.messages("skeleton_info")
    assert len(info) == 1 and info[0].joint_names == list(KINECT_V2_JOINTS)
    st = json.loads(n.messages("reader_status")[-1].data_json)
    print(st)
    thigh = np.linalg.norm(info[0].rest_offsets[KINECT_V2_JOINTS.index("KneeLeft")])
    assert 0.3 < thigh < 0.5, (thigh, st)                      # observed over the first frames
    # 100 frames at 60 fps: each read, then estimated or skipped (the estimator slower than 60 fps;
    # on a loaded machine the more so: 20-250 ms a frame seen, 1-54 frames published)
    assert st["read"] == 100 and st["estimated"] + st["skipped"] >= 100 and st["no_person"] == 0, st
    poses = n.messages("skeleton_pose")
    assert 1 <= len(poses) == st["published"] <= st["estimated"], (len(poses), st)
    stamps = np.array([r.env.capture_ns for r in n.records("skeleton_pose")])
    assert (np.diff(stamps) > 0).all()
    P = np.array([p.joint_positions for p in poses])
    assert np.isfinite(P[:, 0]).all()


def test_video_camera_reader_without_the_camera_fails_in_one_line(run_node) -> None:
    n = run_node("video_camera_reader", {"camera": "camera:57"})
    assert n.wait_exit(30) == 1
    detail = n.messages("reader_status")[-1].detail
    assert detail == "camera:57: cannot be opened (no such camera device, or busy)"
    assert n.log().strip().splitlines() == [f"ERROR {detail}"]


def test_multiview_live_with_a_camera_the_calibration_lacks_fails_in_one_line(run_node, shared_data) -> None:
    calib = shared_data / "video" / "pose2sim_demo" / "Calib.qca.txt"
    n = run_node("multiview_live", {"file": str(calib), "cameras": ["cam01", "side"]})
    assert n.wait_exit(30) == 1
    detail = n.messages("reader_status")[-1].detail
    assert detail == "Calib.qca.txt: no camera for side (its cameras: cam01, cam02, cam03, cam04)"
    assert n.log().strip().splitlines() == [f"ERROR {detail}"]
    n = run_node("multiview_live", {"file": str(calib), "cameras": ["cam01"]})
    assert n.wait_exit(30) == 1
    assert n.log().strip().splitlines() == ["ERROR needs at least two cameras to triangulate, got 1"]
