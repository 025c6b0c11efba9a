"""QTM RT protocol: our simulator read by Qualisys's own client (qtm-rt), our decoder against qtm-rt's
packet parser on the same bytes, and hostile packets and XML.

The independent reference is ``qtm-rt`` (Qualisys's Python SDK): it connects to the simulator over
loopback TCP with asyncio, negotiates the version, reads the parameter XML and frames, and must get
the values the simulator put in, which in turn must be the synthetic actor's ground truth in
millimetres. No captured QTM traffic exists, so the vendor's client is the check on the bytes.
"""
from __future__ import annotations

import asyncio
import socket
import struct
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.formats import qtm_rt as q
from mocapgraph.testing.qtm_server import ActorQTMSource, QTMSimServer, encode_components

qtm_rt = pytest.importorskip("qtm_rt")
from qtm_rt.packet import QRTPacket  # noqa: E402

START = 2400          # inside the range-of-motion gym: limbs turned, not the base pose
ALL = ("3d", "3dnolabels", "6d", "skeleton:global", "timecode")


@pytest.fixture(scope="module")
def source() -> ActorQTMSource:
    return ActorQTMSource("plug_in_gait", 120.0, n_bodies=5, occlude_every=3)


@pytest.fixture
def server(source):
    srv = QTMSimServer(source, port=0, start_frame=START).start()
    yield srv
    srv.stop()


def run(coro, timeout: float = 10.0):
    return asyncio.run(asyncio.wait_for(coro, timeout))


async def connect(port: int, version: str = "1.25"):
    conn = await qtm_rt.connect("127.0.0.1", port, version=version, timeout=3)
    assert conn is not None, f"qtm-rt could not connect with version {version}"
    return conn


# ----- the simulator, read by qtm-rt ------------------------------------------------------------------
@pytest.mark.parametrize("version", ["1.19", "1.21", "1.25", "1.26"])
def test_qtm_rt_negotiates_and_reads_parameters(server, source, version):
    async def go():
        conn = await connect(server.port, version)
        xml = await conn.get_parameters(["general", "3d", "6d", "skeleton"])
        order = await conn.byte_order()
        conn.disconnect()
        return xml, order

    xml, order = run(go())
    assert order == b"Byte order is little endian"
    root = ET.fromstring(xml.decode())          # read with the standard parser, not ours
    assert root.tag == f"QTM_Parameters_Ver_{version}"
    assert float(root.findtext("General/Frequency")) == 120.0
    assert root.findtext("The_3D/AxisUpwards") == "+Z"
    assert [lab.findtext("Name") for lab in root.findall("The_3D/Label")] == source.labels
    assert int(root.findtext("The_3D/Labels")) == len(source.labels)
    assert [b.findtext("Name") for b in root.findall("The_6D/Body")] == source.body_names[:5]
    segs = root.findall("Skeletons/Skeleton/Segments//Segment")
    assert [s.get("Name") for s in segs] == source.limb_names
    ids = {s.get("Name"): s.get("ID") for s in segs}
    for name, parent in zip(source.limb_names, source.limb_parent):
        seg = next(s for s in segs if s.get("Name") == name)
        assert seg.get("Parent_ID") == (None if parent < 0 else ids[source.limb_names[parent]])
    # and our parser reads the same document to the same names and parents
    p = q.parse_parameters(xml)
    assert (p.version, p.labels, p.bodies) == (version, source.labels, source.body_names)
    assert p.skeletons[0].segment_names == source.limb_names
    assert p.skeletons[0].parents == [int(x) for x in source.limb_parent]


def test_unsupported_version_is_refused(server):
    async def go():
        return await qtm_rt.connect("127.0.0.1", server.port, version="1.7", timeout=2)

    assert run(go()) is None      # the server answered with an error packet: qtm-rt gives up


def test_qtm_rt_frame_equals_the_actor_ground_truth(server, source):
    comps = ["3d", "3dnolabels", "6d", "6deulerres", "skeleton:global", "timecode"]

    async def go():
        conn = await connect(server.port)
        pk = await conn.get_current_frame(comps)
        local = await conn.get_current_frame(["skeleton"])
        conn.disconnect()
        return pk, local

    pk, local = run(go())
    k = pk.framenumber
    assert k >= START and pk.timestamp == round((k - START) * 1e6 / 120.0)
    cap = source.actor.capture(k, k + 1)
    truth_mm = cap.markers[0] * 1000.0          # QTM's axes are the world's here (+Z up), mm
    _, markers = pk.get_3d_markers()
    got = np.array([[m.x, m.y, m.z] for m in markers])
    seen = ~np.isnan(got).any(axis=1)
    np.testing.assert_allclose(got[seen], truth_mm[seen], atol=1e-3)
    if k % 3 == 0:
        assert not seen[k % len(seen)]           # the occluded marker travels as NaN, not 0,0,0
    _, strays = pk.get_3d_markers_no_label()
    assert [m.id for m in strays] == [101, 102]
    _, bodies = pk.get_6d()
    pos = np.array([[b[0].x, b[0].y, b[0].z] for b in bodies])
    rot = np.array([b[1].matrix for b in bodies]).reshape(-1, 3, 3).transpose(0, 2, 1)   # column-major
    R_true = Rotation.from_quat(cap.limb_quat[0, :5], scalar_first=True).as_matrix()
    ok = ~np.isnan(pos).any(axis=1)
    np.testing.assert_allclose(pos[ok], cap.limb_centroids[0, :5][ok] * 1000.0, atol=1e-3)
    np.testing.assert_allclose(rot[ok], R_true[ok], atol=1e-6)
    assert np.abs(R_true - np.eye(3)).max() > 0.1          # a frame where the limbs are turned
    _, eul = pk.get_6d_euler_residual()
    e = np.array([[b[1].a1, b[1].a2, b[1].a3] for b in eul])
    np.testing.assert_allclose(Rotation.from_euler("XYZ", e[ok], degrees=True).as_matrix(), R_true[ok], atol=1e-5)
    assert all(b[2].residual == 0.5 for b, good in zip(eul, ok) if good)
    _, skels = pk.get_skeletons()
    segs = skels[0]
    assert [s[0] for s in segs] == list(range(1, len(source.limb_names) + 1))
    q_xyzw = np.array([[s[2].x, s[2].y, s[2].z, s[2].w] for s in segs])
    R_seg = Rotation.from_quat(q_xyzw).as_matrix()
    np.testing.assert_allclose(R_seg, Rotation.from_quat(cap.limb_quat[0], scalar_first=True).as_matrix(), atol=1e-5)
    root_pos = np.array([segs[0][1].x, segs[0][1].y, segs[0][1].z])
    np.testing.assert_allclose(root_pos, cap.limb_centroids[0, 0] * 1000.0, atol=1e-3)
    child = [i for i, p in enumerate(source.limb_parent) if p >= 0][0]
    j = int(source.origin_joint[child])
    np.testing.assert_allclose([segs[child][1].x, segs[child][1].y, segs[child][1].z],
                               cap.joint_centres[0, j] * 1000.0, atol=1e-3)
    # local skeleton: each segment relative to its parent composes back to the global one
    lk = local.framenumber
    g = source.frame(lk).seg_global
    lsegs = local.get_skeletons()[1][0]
    lq = Rotation.from_quat([[s[2].x, s[2].y, s[2].z, s[2].w] for s in lsegs])
    lp = np.array([[s[1].x, s[1].y, s[1].z] for s in lsegs])
    gR = Rotation.from_quat(g.quats_xyzw)
    for i, par in enumerate(source.limb_parent):
        if par >= 0:
            np.testing.assert_allclose((gR[par] * lq[i]).as_matrix(), gR[i].as_matrix(), atol=1e-5)
            np.testing.assert_allclose(g.positions[par] + gR[par].apply(lp[i]), g.positions[i], atol=1e-2)
    _, codes = pk.get_timecode()
    assert codes[0].type == q.TIMECODE_SMPTE and codes[0].hi == q.smpte(k, 120.0)
    # (qtm-rt reads every timecode at the first one's offset: only the first can be compared)


def test_qtm_rt_streams_every_frame_and_the_frequency(server, source):
    async def go(frames):
        conn = await connect(server.port)
        got = []
        await conn.stream_frames(frames=frames, components=["3d"], on_packet=got.append)
        await asyncio.sleep(0.6)
        await conn.stream_frames_stop()
        conn.disconnect()
        return got

    got = run(go("allframes"))
    fns = [p.framenumber for p in got]
    assert len(fns) >= 40 and np.all(np.diff(fns) == 1)
    for p in got[:: max(1, len(got) // 8)]:
        m = np.array([[v.x, v.y, v.z] for v in p.get_3d_markers()[1]])
        np.testing.assert_array_equal(m, source.frame(p.framenumber).markers)
    fns = [p.framenumber for p in run(go("frequency:30"))]
    assert len(fns) >= 10 and set(np.diff(fns)) == {4}   # 120 Hz / 30 Hz


def test_udp_streaming_datagrams_are_qtm_packets(server, source):
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(3.0)

    async def go():
        conn = await connect(server.port)
        await conn._protocol.send_command(f"streamframes allframes udp:{rx.getsockname()[1]} 3d 6d", callback=False)
        datagrams = [rx.recv(65536) for _ in range(5)]
        await conn.stream_frames_stop()
        conn.disconnect()
        return datagrams

    for d in run(go()):
        size, ptype = struct.unpack_from("<II", d)
        assert (size, ptype) == (len(d), q.PACKET_DATA)
        pk = QRTPacket(d[8:])
        m = np.array([[v.x, v.y, v.z] for v in pk.get_3d_markers()[1]])
        np.testing.assert_array_equal(m, source.frame(pk.framenumber).markers)
    rx.close()


def test_end_of_measurement_sends_no_more_data(source):
    srv = QTMSimServer(source, port=0, frames=6).start()
    try:
        with socket.create_connection(("127.0.0.1", srv.port), timeout=3) as s:
            s.sendall(q.encode_string(q.PACKET_COMMAND, "Version 1.25"))
            s.sendall(q.encode_string(q.PACKET_COMMAND, "StreamFrames AllFrames 3D"))
            split, packets = q.PacketSplitter(), []
            while q.PACKET_NO_MORE_DATA not in [t for t, _ in packets]:
                packets += split.feed(s.recv(65536))
        types = [t for t, _ in packets]
        assert types[:2] == [q.PACKET_COMMAND, q.PACKET_COMMAND]   # welcome, "Version set to 1.25"
        assert q.packet_text(packets[1][1]) == "Version set to 1.25"
        # the frames still due when streaming began, then the end (all 6 may be over by then)
        assert types[2:] == [q.PACKET_DATA] * (len(types) - 3) + [q.PACKET_NO_MORE_DATA]
        assert [q.decode_data(p).frame_number for t, p in packets if t == q.PACKET_DATA] == list(range(6 - (len(types) - 3), 6))
    finally:
        srv.stop()


# ----- our decoder against qtm-rt's parser on the same bytes ----------------------------------------
def _components_for_both(source, k):
    f = source.frame(k)
    names = ("3d", "3dres", "3dnolabelsres", "6dres", "6deuler", "skeleton", "timecode")
    return f, q.encode_data(k, 12345678901, encode_components(f, names, 120.0))


@pytest.mark.parametrize("k", [START, START + 1, START + 3])
def test_decoder_reads_every_field_where_qtm_rt_does(source, k):
    f, pkt = _components_for_both(source, k)
    ours = q.decode_data(pkt[8:])
    ref = QRTPacket(pkt[8:])
    assert (ours.frame_number, ours.timestamp_us) == (ref.framenumber, ref.timestamp) == (k, 12345678901)
    m = np.array(ref.get_3d_markers_residual()[1])
    np.testing.assert_array_equal(np.c_[ours.markers, ours.marker_residuals], m)
    u = ref.get_3d_markers_no_label_residual()[1]
    np.testing.assert_array_equal(ours.unlabelled, [[v.x, v.y, v.z] for v in u])
    np.testing.assert_array_equal(ours.unlabelled_ids, [v.id for v in u])
    b = ref.get_6d_residual()[1]
    np.testing.assert_array_equal(ours.body_positions, [[x[0].x, x[0].y, x[0].z] for x in b])
    np.testing.assert_array_equal(ours.body_rotations, [x[1].matrix for x in b])
    np.testing.assert_array_equal(ours.body_residuals, [x[2].residual for x in b])
    e = ref.get_6d_euler()[1]
    np.testing.assert_array_equal(ours.body_euler, [[x[1].a1, x[1].a2, x[1].a3] for x in e])
    s = ref.get_skeletons()[1][0]
    np.testing.assert_array_equal(ours.skeletons[0].ids, [x[0] for x in s])
    np.testing.assert_array_equal(ours.skeletons[0].positions, [[x[1].x, x[1].y, x[1].z] for x in s])
    np.testing.assert_array_equal(ours.skeletons[0].quats_xyzw, [[x[2].x, x[2].y, x[2].z, x[2].w] for x in s])
    t = ref.get_timecode()[1][0]
    assert tuple(ours.timecodes[0]) == (t.type, t.hi, t.lo)
    cam = ours.timecodes[1]
    assert (int(cam["hi"]) << 32 | int(cam["lo"])) == round(k * 1e6 / 120.0)
    np.testing.assert_array_equal(ours.markers, f.markers)


def test_unknown_components_are_skipped_by_their_size(source):
    f = source.frame(START)
    odd = q.HEADER.pack(8 + 20, 4) + bytes(20)       # a force component we do not read
    pkt = q.encode_data(START, 0, [odd, q.component_3d(f.markers)])
    out = q.decode_data(pkt[8:])
    assert out.skipped == [4]
    np.testing.assert_array_equal(out.markers, f.markers)


# ----- hostile input ------------------------------------------------------------------------------------
def test_every_truncation_is_one_qtm_error(source):
    _, pkt = _components_for_both(source, START)
    payload = pkt[8:]
    for n in range(len(payload)):
        with pytest.raises(q.QTMError) as err:
            q.decode_data(payload[:n])
        assert "\n" not in str(err.value) and str(err.value).startswith("QTM RT: ")


def test_lying_counts_fail_before_allocating():
    for comp in (q.HEADER.pack(16, q.COMP_3D) + q.COUNT_RATES.pack(0xFFFFFFFF, 0, 0),
                 q.HEADER.pack(12, q.COMP_SKELETON) + q.COUNT.pack(0xFFFFFFFF),
                 q.HEADER.pack(12, q.COMP_TIMECODE) + q.COUNT.pack(1 << 30)):
        with pytest.raises(q.QTMError, match="cannot fit|need"):
            q.decode_data(q.DATA_HEADER.pack(0, 1, 1) + comp)
    with pytest.raises(q.QTMError, match="components cannot fit"):
        q.decode_data(q.DATA_HEADER.pack(0, 1, 0xFFFFFFFF))
    with pytest.raises(q.QTMError, match="says"):
        q.decode_data(q.DATA_HEADER.pack(0, 1, 1) + q.HEADER.pack(4, q.COMP_3D))


def test_random_bytes_never_escape_as_another_exception():
    rng = np.random.default_rng(5)
    for _ in range(3000):
        n = int(rng.integers(0, 200))
        blob = q.DATA_HEADER.pack(0, 1, int(rng.integers(0, 6))) + rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        try:
            q.decode_data(blob)
        except q.QTMError:
            pass


def test_packet_splitter_reassembles_and_refuses_bad_headers(source):
    _, pkt = _components_for_both(source, START)
    stream = q.encode_string(q.PACKET_COMMAND, q.WELCOME) + pkt + q.encode_packet(q.PACKET_NO_MORE_DATA)
    sp = q.PacketSplitter()
    got = [p for i in range(len(stream)) for p in sp.feed(stream[i:i + 1])]
    assert [t for t, _ in got] == [q.PACKET_COMMAND, q.PACKET_DATA, q.PACKET_NO_MORE_DATA]
    assert q.packet_text(got[0][1]) == q.WELCOME and got[1][1] == pkt[8:] and got[2][1] == b""
    assert len(sp.buf) == 0
    for size in (0, 7, q.MAX_PACKET_BYTES + 1):     # size 0 would never advance; huge would buffer forever
        with pytest.raises(q.QTMError, match="packet header says"):
            q.PacketSplitter().feed(struct.pack("<II", size, 3) + bytes(16))


def test_parameter_xml_faults_are_one_line():
    for text, match in (("<QTM_Parameters_Ver_1.25><The_3D>", "parameter XML"),
                        ("<!DOCTYPE x [<!ENTITY a 'b'>]><QTM_Parameters_Ver_1.25/>", "DOCTYPE"),
                        ("<Something/>", "root"),
                        ("<QTM_Parameters_Ver_1.25>" + "x" * q.MAX_XML_BYTES + "</QTM_Parameters_Ver_1.25>", "limit")):
        with pytest.raises(q.QTMError, match=match) as err:
            q.parse_parameters(text)
        assert "\n" not in str(err.value)
    flat = ("<QTM_Parameters_Ver_1.20><Skeletons><Skeleton Name='s'><Segment Name='a' ID='5'/>"
            "<Segment Name='b' ID='6' Parent_ID='5'/></Skeleton></Skeletons></QTM_Parameters_Ver_1.20>")
    sk = q.parse_parameters(flat).skeletons[0]
    assert (sk.segment_names, sk.parents) == (["a", "b"], [-1, 0])


# ----- the client conversation (sans-IO) --------------------------------------------------------------
def _commands(data: bytes) -> list[str]:
    return [q.packet_text(p) for _t, p in q.PacketSplitter().feed(data)]


def test_session_order_of_business_and_parameters_read_again_on_qtm_events(source):
    from mocapgraph.formats.qtm_session import QTMSession

    s = QTMSession("1.25", "Frequency:60", udp_port=0)
    assert s.receive(q.encode_string(q.PACKET_COMMAND, q.WELCOME)) == []
    assert _commands(s.take_outgoing()) == ["Version 1.25"]
    s.receive(q.encode_string(q.PACKET_COMMAND, "Version set to 1.25"))
    assert _commands(s.take_outgoing()) == ["GetParameters General 3D 6D Skeleton"]
    ev = s.receive(q.encode_string(q.PACKET_XML, source.parameters("1.25", ("all",))))
    assert [e.kind for e in ev] == ["parameters"] and ev[0].value.labels == source.labels
    assert _commands(s.take_outgoing()) == ["StreamFrames Frequency:60 3DRes 3DNoLabels 6DRes Skeleton:Global Timecode"]
    f = source.frame(START)
    ev = s.receive(q.encode_data(START, 0, encode_components(f, ("3dres",), 120.0))
                   + q.encode_packet(q.PACKET_DATA, b"\x01")
                   + q.encode_packet(q.PACKET_EVENT, bytes([q.EVENT_CAPTURE_STARTED]))
                   + q.encode_packet(q.PACKET_NO_MORE_DATA))
    assert [e.kind for e in ev] == ["frame", "bad_packet", "event", "no_more_data"]
    assert _commands(s.take_outgoing()) == ["GetParameters General 3D 6D Skeleton"]   # labels may have changed
    refused = QTMSession("1.99")
    refused.receive(q.encode_string(q.PACKET_COMMAND, q.WELCOME))
    ev = refused.receive(q.encode_string(q.PACKET_ERROR, "Version NOT supported"))
    assert [(e.kind, e.value) for e in ev] == [("refused", "Version NOT supported")]
    assert [e.kind for e in s.datagram(b"\x00" * 5)] == ["bad_packet"]
    assert [e.kind for e in s.datagram(q.encode_data(START, 0, encode_components(f, ("3d",), 120.0)))] == ["frame"]


def test_a_c3d_streamed_by_the_simulator_reads_back_in_qtm_rt(shared_data):
    from mocapgraph.formats.sources import read_marker_file
    from mocapgraph.testing.qtm_server import TrialQTMSource

    path = shared_data / "c3d" / "pycgm" / "Movement_trial.c3d"
    trial = read_marker_file(path)
    srv = QTMSimServer(TrialQTMSource(str(path), axis_up="+Y"), port=0).start()

    async def go():
        conn = await connect(srv.port)
        xml = await conn.get_parameters(["3d", "6d"])
        pk = await conn.get_current_frame(["3dres"])
        conn.disconnect()
        return xml, pk

    try:
        xml, pk = run(go())
    finally:
        srv.stop()
    root = ET.fromstring(xml.decode())
    assert [lab.findtext("Name") for lab in root.findall("The_3D/Label")] == trial.labels
    assert root.findtext("The_3D/AxisUpwards") == "+Y" and root.findall("The_6D/Body") == []
    k = pk.framenumber % trial.positions.shape[0]
    got = np.array([[m.x, m.y, m.z] for m in pk.get_3d_markers_residual()[1]])
    w = trial.positions[k] * 1000.0          # world (X forward, Y left, Z up) -> QTM Y up, X forward: (x, z, -y)
    want = np.c_[w[:, 0], w[:, 2], -w[:, 1]]
    seen = ~np.isnan(want).any(axis=1)
    np.testing.assert_allclose(got[seen], want[seen], atol=1e-3)
    assert np.isnan(got[~seen]).all()


def test_hostile_parameter_documents_and_session_bytes_are_one_line_errors():
    from mocapgraph.formats.qtm_session import QTMSession

    deep = ("<QTM_Parameters_Ver_1.25><Skeletons><Skeleton Name='s'><Segments>" + "<Segment Name='x'>" * 5000
            + "</Segment>" * 5000 + "</Segments></Skeleton></Skeletons></QTM_Parameters_Ver_1.25>")
    with pytest.raises(q.QTMError, match="nested over"):
        q.parse_parameters(deep)
    with pytest.raises(q.QTMError, match="not a number"):
        q.parse_parameters("<QTM_Parameters_Ver_1.25><Skeletons><Skeleton><Segment ID='x'/></Skeleton></Skeletons>"
                           "</QTM_Parameters_Ver_1.25>")
    rng = np.random.default_rng(9)
    kinds = [q.PACKET_ERROR, q.PACKET_COMMAND, q.PACKET_XML, q.PACKET_DATA, q.PACKET_NO_MORE_DATA, q.PACKET_EVENT, 99]
    for _ in range(2000):
        s = QTMSession()
        s.state = str(rng.choice(["welcome", "version", "parameters", "streaming"]))
        body = rng.integers(0, 256, int(rng.integers(0, 80)), dtype=np.uint8).tobytes()
        if rng.random() < 0.3:
            body = b"<QTM_Parameters_Ver_1.25><The_3D><Label><Name>" + body + b"</Name></Label></The_3D>"
        try:
            s.receive(q.encode_packet(int(rng.choice(kinds)), body))
        except q.QTMError:
            pass        # (only a broken stream raises; everything else is an event)
