"""Pure parts of the readers: the playback schedule and the layout mapping (no sockets)."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.formats.device_file import DeviceConfigError, load_device_config
from mocapgraph.nodes.marker_source import LayoutMap
from mocapgraph.nodes.source_base import Playback, SourceError


def test_playback_real_time_sends_each_frame_at_its_time_never_early() -> None:
    times = np.arange(10) * 10_000_000                      # 100 Hz file
    pb = Playback(times, 2, 6, 100.0, rate_scale=2.0)        # frames 2..6 at twice the speed
    pb.start(100.0, 5_000)
    assert pb.period_s == pytest.approx(0.005)
    assert pb.due(100.0) == [(2, 5_000)]
    assert pb.due(100.0048) == []                            # 0.2 ms before the next frame is due
    assert pb.due(100.0050) == [(3, 5_000 + 10_000_000)]     # capture stamps keep the file's spacing
    assert [i for i, _ in pb.due(100.0151)] == [4, 5]        # after a stall: catch up, nothing lost
    assert [i for i, _ in pb.due(100.5)] == [6] and pb.finished and pb.due(101.0) == []


def test_playback_loop_continues_capture_time_and_fast_mode_batches() -> None:
    times = np.arange(4) * 10_000_000
    pb = Playback(times, 0, 3, 100.0, rate_scale=0.0, loop=True, batch=10)
    pb.start(0.0, 0)
    out = pb.due(0.0)
    assert [i for i, _ in out] == [0, 1, 2, 3, 0, 1, 2, 3, 0, 1]
    assert np.all(np.diff([c for _, c in out]) == 10_000_000)   # one period across each seam
    assert pb.period_s == 0.0 and not pb.finished and pb.passes == 2


def test_playback_irregular_stamps_follow_the_recording() -> None:
    times = np.array([0, 33, 66, 133, 166]) * 1_000_000     # a dropped frame after 66 ms
    pb = Playback(times, 0, 4, 30.0)
    assert not pb.uniform and pb.period_s == pytest.approx(1 / 30 / 4)
    pb.start(0.0, 0)
    assert [i for i, _ in pb.due(0.07)] == [0, 1, 2]
    assert pb.due(0.13) == []
    assert pb.due(0.1331) == [(3, 133_000_000)]


def test_layout_map_orders_by_layout_and_reports_what_does_not_fit() -> None:
    sk = SkeletonDefinition.from_layout_file("one_arm")
    labels = list(sk.marker_labels)
    src = ["Subject:" + labels[2], "extra", labels[0].lower()] + labels[3:]   # one missing, one unknown
    m = LayoutMap.build("one_arm", src)
    assert m.labels == labels and m.unplaced == ["extra"] and m.missing == [labels[1]]
    pos = np.arange(len(src) * 3, dtype=float).reshape(len(src), 3)
    out = m.positions(pos[None])[0]
    np.testing.assert_array_equal(out[0], pos[2])
    assert np.isnan(out[1]).all()
    np.testing.assert_array_equal(out[2], pos[0])
    np.testing.assert_array_equal(out[3:], pos[3:])
    np.testing.assert_array_equal(m.values(np.arange(len(src), dtype=float), -1.0)[:3], [2, -1, 0])
    assert list(m.marker_limb) == list(sk.marker_limb)
    with pytest.raises(SourceError, match="none of its 2 labels"):
        LayoutMap.build("one_arm", ["foo", "bar"], "file.c3d")
    with pytest.raises(SourceError, match="has 12 markers but the device sends 5"):
        LayoutMap.in_order("one_arm", 5)


def test_device_files_transform_both_ways_and_errors_name_the_key(tmp_path) -> None:
    dev = load_device_config("example_serial_bridge")           # Y up, Z forward
    p = np.array([[0.1, 1.7, 2.0]])                              # device: x left?, y up, z forward
    np.testing.assert_allclose(dev.points_to_world(p), [[2.0, 0.1, 1.7]])
    np.testing.assert_allclose(dev.points_from_world(dev.points_to_world(p)), p)
    udp = load_device_config("example_udp_bridge")              # turned 90 deg, 1.5 m back
    np.testing.assert_allclose(udp.points_to_world(np.array([[1.0, 0.0, 0.5]])), [[-1.5, 1.0, 0.5]], atol=1e-12)
    q = udp.quats_to_world(np.array([[1.0, 0.0, 0.0, 0.0], [np.nan] * 4]))
    np.testing.assert_allclose(q[0], [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)], atol=1e-12)
    assert np.isnan(q[1]).all()
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nto_world:\n  up: '+Y'\n  forward: '+Y'\n")
    with pytest.raises(DeviceConfigError, match=r"bad.yaml:3: to_world.up: .*not perpendicular"):
        load_device_config(bad)
    bad.write_text("name: x\nchanels: [A]\n")
    with pytest.raises(DeviceConfigError, match=r"bad.yaml:2: chanels: unknown key"):
        load_device_config(bad)
    with pytest.raises(DeviceConfigError, match="no such device configuration"):
        load_device_config("no_such_device")
