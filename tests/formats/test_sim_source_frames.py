"""The simulators' shared sources and faults without sockets: a bag and a C3D as marker sources
(looping, NaN kept), both simulators' frames from the same recording, the delay line's order,
the drifting clock, and the NatNet frames' bones against the actor's segments."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.formats import FormatError
from mocapgraph.formats import natnet as nn
from mocapgraph.formats import natnet_encode as ne
from mocapgraph.testing.natnet_server import ActorStream, Faults
from mocapgraph.testing.qtm_server import TrialQTMSource
from mocapgraph.testing.sim_sources import DelayLine, LinkFaults, RecordedMarkers
from tests.lab_fixtures import PERSON_LABELS, person_frames, write_points_c3d
from tests.nodes.test_sim_sources import write_bag


def test_a_bag_is_a_marker_source_for_both_simulators(tmp_path) -> None:
    path = tmp_path / "s.mcap"
    trial = write_bag(path, 30)
    rec = RecordedMarkers(path)
    assert rec.labels == trial.labels and rec.rate_hz == 120.0 and rec.n_frames == 30
    pos, res = rec.markers(25, 35)                                       # loops past the end
    np.testing.assert_array_equal(pos, trial.positions[np.arange(25, 35) % 30])
    assert np.array_equal(np.isnan(res), np.isnan(pos[..., 0]))
    qtm = TrialQTMSource(str(path))                                      # QTM: mm, Z up (= world)
    np.testing.assert_allclose(qtm.frame(31).markers, trial.positions[1] * 1000.0, atol=1e-3, equal_nan=True)
    nat = ActorStream(source=str(path))
    f = list(nat.frames(28, 4))
    assert [x.frame_number for x in f] == [28, 29, 30, 31] and f[0].skeletons == {} and len(f[0].rigid_bodies) == 0
    lm = f[3].labelled_markers[: len(trial.labels)]
    seen = ~np.isnan(trial.positions[1]).any(axis=1)
    assert np.array_equal((lm["params"] & nn.MARKER_OCCLUDED) == 0, seen) and not seen.all()
    np.testing.assert_allclose(nat.dev.points_to_world(lm["pos"][seen].astype(float)), trial.positions[1][seen],
                               atol=1e-6)


def test_a_c3d_source_and_a_refused_file(tmp_path) -> None:
    pytest.importorskip("ezc3d")
    truth = person_frames(10)
    rec = RecordedMarkers(write_points_c3d(tmp_path / "p.c3d", PERSON_LABELS, truth))
    np.testing.assert_allclose(rec.markers(0, 10)[0], truth, atol=1e-6)
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(FormatError, match="notes.txt: not a marker recording"):
        RecordedMarkers(tmp_path / "notes.txt")


def test_delay_line_keeps_tcp_order_and_lets_datagrams_overtake() -> None:
    udp, tcp = DelayLine(), DelayLine(keep_order=True)
    for due, item in [(1.0, "a"), (0.5, "b"), (0.7, "c")]:
        udp.push(due, item)
        tcp.push(due, item)
    assert udp.pop_due(0.8) == ["b", "c"] and udp.pop_due(2.0) == ["a"]
    assert tcp.pop_due(0.8) == [] and tcp.pop_due(1.0) == ["a", "b", "c"] and tcp.next_due == float("inf")
    link = LinkFaults((0.0, 20.0), 100.0, seed=1)
    holds = np.array([link.hold_s() for _ in range(2000)])
    assert 0 <= holds.min() < 0.001 and 0.019 < holds.max() <= 0.020
    assert link.device_s(10.0) == pytest.approx(10.001)
    with pytest.raises(ValueError):
        LinkFaults((5.0, 1.0))


def test_natnet_frames_carry_the_actors_bones_on_a_drifting_clock() -> None:
    from scipy.spatial.transform import Rotation

    stream = ActorStream("plug_in_gait", rate_hz=120.0, n_bodies=1, bone_dropout_every=3)
    faults = Faults(drift_ppm=100.0)
    f = [faults.on_device_clock(x) for x in stream.frames(240, 6)]
    plain = list(stream.frames(240, 6))
    assert f[0].transmit_ticks == round(plain[0].transmit_ticks * 1.0001) and f[0].timestamp == plain[0].timestamp * 1.0001
    pos, quat, ok = stream.bones(240, 246)
    d = nn.decode_model_defs(ne.model_defs(stream.model_defs(), (4, 1)), (4, 1))
    sid, bones = d.skeletons["Actor"]
    assert [b.name for b in bones] == stream.bone_names and [b.parent_id for b in bones] == list(stream.bone_parent + 1)
    for k, fr in enumerate(f):
        rb = nn.decode_frame(ne.frame(fr, (4, 1)), (4, 1)).skeletons[sid]
        valid = (rb["params"] & nn.RIGID_BODY_TRACKING_VALID) != 0
        assert np.array_equal(valid, ok[k]) and (rb["pos"][~valid] == 0).all()
        np.testing.assert_allclose(stream.dev.points_to_world(rb["pos"][valid].astype(float)), pos[k][ok[k]], atol=2e-6)
        w = Rotation.from_matrix(stream.dev.rotation) * Rotation.from_quat(rb["quat_xyzw"][valid])
        q = w.as_quat(scalar_first=True)
        q *= np.sign(q[:, :1]) * np.sign(quat[k][ok[k]][:, :1])
        np.testing.assert_allclose(q, quat[k][ok[k]], atol=2e-6)


@pytest.mark.parametrize("coordinates", ["global", "local"])
def test_reader_skeleton_pose_from_global_and_parent_relative_bones(coordinates) -> None:
    """The reader's per-frame skeleton step (``_skeleton_pose``) on the simulator's bytes, with Motive
    streaming bones global or relative to their parent: the actor's bones in world axes, lost bones
    (and with 'local', the bones under them) NaN with state 0."""
    from mocapgraph.formats.device_file import device_or_default
    from mocapgraph.formats.natnet_model import rotation_quat, skeleton_bones
    from mocapgraph.nodes.natnet_reader import _skeleton_pose

    stream = ActorStream("plug_in_gait", rate_hz=120.0, n_bodies=0, bone_dropout_every=4,
                         skeleton_local=coordinates == "local")
    b = skeleton_bones(nn.decode_model_defs(ne.model_defs(stream.model_defs(), (4, 2)), (4, 2)))
    dev = device_or_default("", "y")
    pos, quat, ok = stream.bones(120, 128)              # frame 120 loses the root, 124 bone 4
    assert (~ok[0]).sum() == 1 and not ok[0, 0] and (~ok[4]).sum() == 1
    if coordinates == "local":                               # a lost bone hides the bones under it
        for _ in range(len(b.levels)):
            ok[:, 1:] &= np.where(stream.bone_parent[1:] >= 0, ok[:, np.maximum(stream.bone_parent[1:], 0)], True)
    for k, f in enumerate(stream.frames(120, 8)):
        sp = _skeleton_pose(nn.decode_frame(ne.frame(f, (4, 2)), (4, 2)), b, dev, rotation_quat(dev.rotation),
                            coordinates)
        assert np.array_equal(sp.tracking_state, np.where(ok[k], 2, 0))
        assert np.isnan(sp.joint_positions[~ok[k]]).all()
        if not ok[k].any():                                   # 'local' and the root lost: nothing to check
            assert coordinates == "local" and k == 0
            continue
        np.testing.assert_allclose(sp.joint_positions[ok[k]], pos[k][ok[k]], atol=5e-6)
        q = sp.joint_orientations[ok[k]]
        q *= np.sign(q[:, :1]) * np.sign(quat[k][ok[k]][:, :1])
        np.testing.assert_allclose(q, quat[k][ok[k]], atol=5e-6)
