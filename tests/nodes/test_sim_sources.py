"""The NatNet and QTM simulators serving any source, against our readers (own processes) and natnetsdk:
a C3D the test writes (ezc3d), a bag of marker frames (both simulators), the actor's skeleton
(bones NaN with state 0 where Motive lost them), and NatNet capture stamps under injected delay
and clock drift."""
from __future__ import annotations

import json
import socket
import threading

import numpy as np
import pytest

from mocapgraph.formats import natnet as nn
from mocapgraph.testing.natnet_server import ActorStream, Faults, simulate
from tests.lab_fixtures import PERSON_LABELS, RATE, person_frames, write_points_c3d

pytestmark = pytest.mark.slow


def free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def status(n) -> dict:
    return json.loads(n.messages("reader_status")[-1].data_json)


def frames_from(n, topic: str, count: int, timeout: float = 20.0):
    return n.wait_for(lambda: n.records(topic) if len(n.records(topic)) >= count else None, timeout,
                      f"{count} messages on {topic}")


def natnet_reader(run_node, port: int, **params):
    p = {"server": "127.0.0.1", "command_port": port, "retry_s": 0.2, "silence_s": 0.5}
    p.update(params)
    return run_node("natnet_reader", p)


def serve(stream: ActorStream, version: nn.Version, port: int, count: int, start: int = 0,
          faults: Faults | None = None, tap: socket.socket | None = None) -> threading.Thread:
    """The simulator in a thread, streaming once the reader asked for the model definitions; every
    frame also to ``tap`` (the bytes natnetsdk is given)."""
    ready = (lambda s: s.targets.append(tap.getsockname())) if tap is not None else None
    t = threading.Thread(target=simulate, kwargs=dict(stream=stream, version=version, command_port=port, count=count,
                                                      start_frame=start, faults=faults, on_ready=ready, wait_s=10.0),
                         daemon=True)
    t.start()
    return t


def tapped(tap: socket.socket, n: int) -> list[bytes]:
    """The first ``n`` frames of data the tap received (server info and definitions skipped)."""
    out: list[bytes] = []
    while len(out) < n:
        data = tap.recv(65536)
        if nn.message_id(data) == nn.NAT_FRAMEOFDATA:
            out.append(data)
    return out


def test_natnet_simulator_serves_a_c3d_as_our_reader_and_natnetsdk_read_it(run_node, tmp_path) -> None:
    pytest.importorskip("ezc3d")
    pytest.importorskip("natnetsdk")
    from tests.natnet_sdk import sdk_frame

    truth = person_frames(40)
    truth[5:9, 2] = np.nan                                        # the left foot unseen for 4 frames
    path = write_points_c3d(tmp_path / "walk.c3d", PERSON_LABELS, truth)
    stream = ActorStream(source=str(path))
    assert stream.rate_hz == RATE and stream.labels == list(PERSON_LABELS) and stream.n_bodies == 0
    port = free_port()
    tap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tap.bind(("127.0.0.1", 0))
    tap.settimeout(10.0)
    n = natnet_reader(run_node, port)
    t = serve(stream, (4, 1), port, 60, tap=tap)
    recs = frames_from(n, "markers", 60)
    t.join(5)
    packets = tapped(tap, 60)
    tap.close()
    assert n.messages("marker_layout")[-1].labels == [f"Actor:{m}" for m in PERSON_LABELS]
    want = truth[np.arange(60) % 40]                              # the file loops
    got = np.array([r.msg.positions for r in recs])
    assert [r.msg.frame_number for r in recs] == list(range(60))
    np.testing.assert_allclose(got, want, atol=2e-6, equal_nan=True)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    assert not np.array([r.msg.valid for r in recs])[np.isnan(want).any(axis=2)].any()
    assert status(n)["rate_hz"] == RATE
    # OptiTrack's own client, given the same bytes: the file's values in Motive's axes (Y up)
    dev = stream.dev.points_from_world(np.nan_to_num(want)).astype(np.float32)
    for k, packet in enumerate(packets):
        sdk = sdk_frame(packet, (4, 1))
        assert sdk["frame"] == k
        lab = sdk["labelled"][:len(PERSON_LABELS)]
        assert [m[0] & 0xFFFF for m in lab] == [1, 2, 3, 4]
        seen = ~np.isnan(want[k]).any(axis=1)
        assert [(m[3] & nn.MARKER_OCCLUDED) == 0 for m in lab] == seen.tolist()
        np.testing.assert_array_equal(np.array([m[1] for m in lab])[seen], dev[k][seen])
        np.testing.assert_array_equal(np.array(sdk["sets"]["Actor"])[seen], dev[k][seen])


def write_bag(path, n: int):
    """A bag as mocapgraph writes one: the actor's markers (with occlusions) as MarkerFrames and a
    latched MarkerLayout. Returns its MarkerTrial."""
    from mocapgraph.bag.convert import markers_to_bag
    from mocapgraph.bag.writer import BagWriter
    from mocapgraph.formats.marker_trial import MarkerTrial
    from mocapgraph.testing.sim_sources import ActorSource

    src = ActorSource("plug_in_gait", 120.0, seed=2, dropout_rate_hz=1.0)
    cap = src.window(300, 300 + n)
    trial = MarkerTrial(labels=src.labels, positions=cap.markers, residuals=None, rate_hz=120.0, source="actor")
    with BagWriter(path) as w:
        markers_to_bag(trial, w, start_ns=1_000_000_000)
    return trial


def test_a_bag_served_by_both_simulators_reads_back_as_the_bag(run_node, tmp_path) -> None:
    from mocapgraph.testing.qtm_server import QTMSimServer, TrialQTMSource

    path = tmp_path / "session.mcap"
    trial = write_bag(path, 48)
    assert np.isnan(trial.positions).any()
    want = trial.positions
    # NatNet 4.2
    port = free_port()
    nat = natnet_reader(run_node, port, layout="plug_in_gait")
    stream = ActorStream(source=str(path))
    assert stream.labels == trial.labels and stream.rate_hz == 120.0
    t = serve(stream, (4, 2), port, 48)
    recs = frames_from(nat, "markers", 48)
    t.join(5)
    got = np.array([r.msg.positions for r in recs])
    np.testing.assert_allclose(got, want, atol=2e-6, equal_nan=True)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    # QTM (over TCP): millimetres as float32, in QTM's Z-up axes
    srv = QTMSimServer(TrialQTMSource(str(path)), port=0).start()
    try:
        qtm = run_node("qtm_reader", {"port": srv.port, "layout": "plug_in_gait"}, name="qtm")
        qrecs = frames_from(qtm, "markers", 48)[:48]
    finally:
        srv.stop()
    k = np.array([r.msg.frame_number for r in qrecs])
    assert np.array_equal(np.diff(k), np.ones(47))                 # frame k is the bag's frame k % 48
    q = np.array([r.msg.positions for r in qrecs])
    np.testing.assert_allclose(q, want[k % 48], atol=1e-6, equal_nan=True)
    assert np.array_equal(np.isnan(q), np.isnan(want[k % 48]))
    assert qtm.messages("marker_layout")[-1].name == nat.messages("marker_layout")[-1].name == "plug_in_gait"


def test_natnet_skeleton_bones_published_and_natnetsdk_reads_the_same(run_node) -> None:
    pytest.importorskip("natnetsdk")
    from tests.natnet_sdk import our_frame, sdk_frame

    port = free_port()
    stream = ActorStream("plug_in_gait", rate_hz=120.0, n_bodies=1, bone_dropout_every=5)
    tap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tap.bind(("127.0.0.1", 0))
    tap.settimeout(10.0)
    n = natnet_reader(run_node, port)
    t = serve(stream, (3, 0), port, 40, start=3600 * 120 + 7, tap=tap)
    recs = frames_from(n, "skeleton_pose", 40)
    t.join(5)
    packets = tapped(tap, 40)
    tap.close()
    info = n.messages("skeleton_info")[-1]
    assert info.joint_names == stream.bone_names and info.joint_parent.tolist() == stream.bone_parent.tolist()
    np.testing.assert_allclose(info.rest_offsets, stream.bone_offsets(), atol=2e-6)
    first = 3600 * 120 + 7
    pos, quat, ok = stream.bones(first, first + 40)
    got_p = np.array([r.msg.joint_positions for r in recs])
    got_q = np.array([r.msg.joint_orientations for r in recs])
    state = np.array([r.msg.tracking_state for r in recs])
    assert [r.msg.source_id for r in recs[:1]] == ["Actor"] and (~ok).sum() == 8
    assert np.array_equal(state, np.where(ok, 2, 0))
    assert np.isnan(got_p[~ok]).all() and np.isnan(got_q[~ok]).all()          # lost: NaN, never 0,0,0
    np.testing.assert_allclose(got_p[ok], pos[ok], atol=2e-6)
    got_q *= np.sign(got_q[..., :1]) * np.sign(quat[..., :1])
    np.testing.assert_allclose(got_q[ok], quat[ok], atol=2e-6)
    n.wait_for(lambda: status(n)["frames"] == 40, what="a status counting every frame")
    assert status(n)["timecode"] == "01:00:00:46.0"          # the last frame: 1 h, 0 min, 0 s, frame 46
    for packet in packets:                                    # natnetsdk reads the bones as we do
        sdk, ours = sdk_frame(packet, (3, 0)), our_frame(packet, (3, 0))
        assert sdk["skeletons"] == ours["skeletons"] and len(ours["skeletons"]["1"]) == len(stream.bone_names)


def test_natnet_capture_stamps_on_the_fastest_path_despite_random_delay_and_drift(run_node) -> None:
    port = free_port()
    stream = ActorStream("plug_in_gait", rate_hz=240.0, n_bodies=0, n_unlabelled=0)
    faults = Faults(delay_ms=(0.0, 20.0), drift_ppm=100.0, seed=3)
    n = natnet_reader(run_node, port)
    t = serve(stream, (4, 1), port, 240 * 4, start=1000, faults=faults)
    t.join(20)
    recs = n.wait_for(lambda: n.records("markers") if n.records("markers") and
                      n.records("markers")[-1].msg.frame_number >= 1000 + 240 * 4 - 30 else None,
                      what="the last frames")
    truth = dict(faults.captured)
    k = np.array([r.msg.frame_number for r in recs])
    err_ms = np.array([(r.env.capture_ns - truth[r.msg.frame_number]) / 1e6 for r in recs])
    arrival_ms = np.array([(r.receive_ns - truth[r.msg.frame_number]) / 1e6 for r in recs])
    late = k >= 1000 + 2 * 240                                   # after 2 s
    print(f"\nNatNet stamps, 0-20 ms delay, +100 ppm drift: {len(recs)} frames published (late ones dropped); "
          f"error after 2 s {err_ms[late].min():.3f}..{err_ms[late].max():.3f} ms; arrival at our subscriber "
          f"{arrival_ms.min():.3f} ms at least, {np.percentile(arrival_ms, 50):.1f} ms median")
    assert np.percentile(arrival_ms, 90) > 10.0                  # the delays were there to be undone
    assert late.sum() > 240                                      # enough frames to judge
    # A stamp is the capture time plus the least transport delay seen so far (ClockSync's line under
    # the fastest frames; a one-way delay below that is invisible to any stamp), plus, until its
    # minima span 6 s and the drift is estimated, up to 100 ppm x 4 s = 0.4 ms of drift: never
    # before the capture; never 1 ms later than the frame before (a frame's own 0-20 ms delay
    # never shows); and no later than the least delay this test's own subscriber had seen by then
    # (it receives after the reader) plus that drift. On an idle machine that least delay is a few
    # tenths of a ms; on a loaded one (5 sessions on 2 cores) 0.6-4 ms. Stamping on arrival, or on
    # the first frame's delay, fails this.
    e = err_ms[late]
    floor = np.minimum.accumulate(arrival_ms)[late]
    why = (np.percentile(e, [0, 50, 100]), arrival_ms.min(), status(n)["clock"],
           f"simulator sent frames up to {faults.late_ms_max:.0f} ms late")   # a stall over 0.5 s: a reset
    assert e.min() > -0.2 and np.diff(e).max() < 1.0, why
    assert (e <= floor + 0.6).all(), why
