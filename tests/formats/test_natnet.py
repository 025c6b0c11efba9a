"""The NatNet decoder against the real bytes of a Motive 2.1 / NatNet 3.0 session: every frame of
the capture agrees with OptiTrack's own SampleClient printout; single packets decode as printed;
cut and flipped packets are refused in one line; the 4.1 layout (section byte counts) decodes."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from mocapgraph.formats import natnet as nn
from mocapgraph.testing.pcapng import PcapngError, read_udp
from tests.natnet_reference import PRINT_TOL, frames_of, max_abs, natnet_datagrams, parse_sample_client


@pytest.fixture
def natnet_dir(shared_data):
    d = shared_data / "natnet"
    if not (d / "traffic.pcapng").is_file():
        pytest.skip("../shared/data/natnet is absent")
    return d


def _packet(natnet_dir, name: str) -> bytes:
    return (natnet_dir / name).read_bytes()


def test_pcapng_reader_finds_the_session(natnet_dir) -> None:
    grams = natnet_datagrams(natnet_dir / "traffic.pcapng")
    ids = [nn.message_id(d.payload) for d in grams]
    assert ids.count(nn.NAT_FRAMEOFDATA) == 518
    assert ids.count(nn.NAT_SERVERINFO) == 2 and ids.count(nn.NAT_MODELDEF) == 1
    data = [d for d in grams if nn.message_id(d.payload) == nn.NAT_FRAMEOFDATA]
    assert data[0].dst == ("239.255.42.99", 1511)
    gaps = np.diff([d.time_ns for d in data]) / 1e6
    print(f"\npcapng: {len(grams)} NatNet datagrams, {len(data)} frames, median spacing {np.median(gaps):.3f} ms")
    assert np.median(gaps) == pytest.approx(1000 / 120, abs=0.5)


def test_pcapng_reader_refuses_a_broken_file(tmp_path, natnet_dir) -> None:
    raw = (natnet_dir / "traffic.pcapng").read_bytes()
    bad = tmp_path / "cut.pcapng"
    bad.write_bytes(raw[:5000])
    with pytest.raises(PcapngError, match="claims length"):
        read_udp(bad)
    bad.write_bytes(b"not a capture at all")
    with pytest.raises(PcapngError):
        read_udp(bad)


def test_server_info_packet(natnet_dir) -> None:
    si = nn.decode_server_info(_packet(natnet_dir, "serverinfo_packet_v3.bin"))
    assert (si.app_name, si.app_version, si.natnet_version) == ("Motive", (2, 1, 0, 0), (3, 0, 0, 0))
    assert (si.data_port, si.multicast, si.multicast_group) == (1511, True, "239.255.42.99")
    assert si.clock_hz > 1e6


def test_model_definition_packet_matches_the_sample_client(natnet_dir) -> None:
    md = nn.decode_model_defs(_packet(natnet_dir, "modeldef_packet_v3.bin"), (3, 0))
    # SampleClient: "Received 3 Data Descriptions": MarkerSets RaceQuad and all, RigidBody RaceQuad id 2
    assert md.marker_sets == {"RaceQuad": [f"Marker{i}" for i in range(1, 6)],
                              "all": [f"RaceQuad_{i}" for i in range(1, 6)]}
    (rb,) = md.rigid_bodies
    assert (rb.name, rb.id, rb.parent_id) == ("RaceQuad", 2, -1)
    assert rb.marker_positions.shape == (5, 3) and np.all(rb.offset == 0)


def test_frame_packet(natnet_dir) -> None:
    f = nn.decode_frame(_packet(natnet_dir, "mocapframe_packet_v3.bin"), (3, 0))
    assert f.frame_number == 162734 and f.other_markers.shape == (5, 3)
    assert f.rigid_bodies["id"].tolist() == [2] and f.rigid_body_valid.tolist() == [True]
    model, marker = nn.split_marker_id(f.labelled_markers["id"])
    assert model.tolist() == [2, 2, 2, 2, 2, 0] and marker.tolist() == [1, 2, 3, 4, 5, 50007]
    assert f.timecode_text() == "00:00:00:00.0"


def test_every_captured_frame_agrees_with_the_sample_client(natnet_dir) -> None:
    ref = parse_sample_client(natnet_dir / "SampleClient_output.txt")
    si = nn.decode_server_info(_packet(natnet_dir, "serverinfo_packet_v3.bin"))
    decoded = frames_of(natnet_datagrams(natnet_dir / "traffic.pcapng"), si.version)
    worst = {"timestamp": 0.0, "other": 0.0, "labelled": 0.0, "body pos": 0.0, "body quat": 0.0,
             "latency ms": 0.0}
    compared = markers = 0
    for _, f in decoded:
        r = ref.get(f.frame_number)
        if r is None:
            continue
        compared += 1
        worst["timestamp"] = max(worst["timestamp"], abs(f.timestamp - r.timestamp))
        assert len(r.other) == len(f.other_markers) and len(r.labelled) == len(f.labelled_markers)
        worst["other"] = max(worst["other"], max_abs(r.other, f.other_markers))
        model, marker = nn.split_marker_id(f.labelled_markers["id"])
        assert [(m, k) for m, k, _, _ in r.labelled] == list(zip(model.tolist(), marker.tolist()))
        occl = (f.labelled_markers["params"] & nn.MARKER_OCCLUDED) != 0
        assert [o for _, _, o, _ in r.labelled] == occl.astype(int).tolist()
        worst["labelled"] = max(worst["labelled"], max_abs([p for *_, p in r.labelled], f.labelled_markers["pos"]))
        markers += len(f.labelled_markers)
        assert [(i, v) for i, _, v, _ in r.bodies] == list(zip(f.rigid_bodies["id"].tolist(),
                                                                f.rigid_body_valid.tolist()))
        for (_, err, _, vals), rb in zip(r.bodies, f.rigid_bodies):
            assert abs(err - rb["error"]) <= PRINT_TOL
            worst["body pos"] = max(worst["body pos"], max_abs(vals[:3], rb["pos"]))
            worst["body quat"] = max(worst["body quat"], max_abs(vals[3:], rb["quat_xyzw"]))
        ticks = 1000.0 / si.clock_hz
        worst["latency ms"] = max(worst["latency ms"],
                                  abs((f.transmit_ticks - f.data_received_ticks) * ticks - r.software_ms),
                                  abs((f.transmit_ticks - f.mid_exposure_ticks) * ticks - r.system_ms))
        assert f.timecode_text() == r.timecode
    print(f"\nSampleClient: {compared} of {len(decoded)} captured frames compared ({len(ref)} printed), "
          f"{markers} labelled markers; max |difference|: "
          + ", ".join(f"{k} {v:.4f}" for k, v in worst.items()))
    assert compared >= 200
    assert all(v <= PRINT_TOL for v in worst.values())


# ----- hostile input -----------------------------------------------------------------------------
def _one_line_refusal(fn, data: bytes) -> str:
    with pytest.raises(nn.NatNetError) as info:
        fn(data)
    text = str(info.value)
    assert "\n" not in text and text.startswith("natnet: ")
    return text


def test_truncated_packets_are_refused_in_one_line(natnet_dir) -> None:
    # the frame's 4-byte end-of-data tag carries nothing: a frame cut just before it still decodes
    cases = [(lambda d: nn.decode_frame(d, (3, 0)), _packet(natnet_dir, "mocapframe_packet_v3.bin")[:-4]),
             (lambda d: nn.decode_model_defs(d, (3, 0)), _packet(natnet_dir, "modeldef_packet_v3.bin")),
             (nn.decode_server_info, _packet(natnet_dir, "serverinfo_packet_v3.bin")[:200])]
    refused = 0
    for fn, data in cases:
        for cut in range(0, len(data) - 1):
            short = bytearray(data[:cut])
            if cut >= 4:  # a header that agrees with the cut: the fields themselves run out
                struct.pack_into("<H", short, 2, cut - 4)
            _one_line_refusal(fn, bytes(short))
            refused += 1
    print(f"\n{refused} truncated packets refused")
    frame = cases[0][1]
    assert "header says 332 payload bytes, the packet has 288" in _one_line_refusal(cases[0][0], frame[:-40])
    assert "labelled marker count 6 does not fit in the 78 bytes left" in _one_line_refusal(
        cases[0][0], frame[:2] + struct.pack("<H", 200) + frame[4:204])


def test_huge_counts_allocate_nothing(natnet_dir) -> None:
    frame = bytearray(_packet(natnet_dir, "mocapframe_packet_v3.bin"))
    struct.pack_into("<i", frame, 12, 0x7FFFFFFF)  # other marker count
    assert "other marker count 2147483647 does not fit" in _one_line_refusal(
        lambda d: nn.decode_frame(d, (3, 0)), bytes(frame))
    struct.pack_into("<i", frame, 12, -1)
    _one_line_refusal(lambda d: nn.decode_frame(d, (3, 0)), bytes(frame))
    mdef = bytearray(_packet(natnet_dir, "modeldef_packet_v3.bin"))
    struct.pack_into("<i", mdef, 8, 99)  # first description's type
    assert "unknown description type 99" in _one_line_refusal(lambda d: nn.decode_model_defs(d, (3, 0)), bytes(mdef))


def test_flipped_bytes_never_escape_as_anything_but_natnet_error(natnet_dir) -> None:
    rng = np.random.default_rng(25)
    outcomes = {"decoded": 0, "refused": 0}
    for name, fn in (("mocapframe_packet_v3.bin", lambda d: nn.decode_frame(d, (3, 0))),
                     ("modeldef_packet_v3.bin", lambda d: nn.decode_model_defs(d, (3, 0)))):
        base = _packet(natnet_dir, name)
        for _ in range(1500):
            data = bytearray(base)
            for pos in rng.integers(0, len(data), rng.integers(1, 4)):
                data[pos] ^= 1 << int(rng.integers(0, 8))
            try:
                fn(bytes(data))
                outcomes["decoded"] += 1
            except nn.NatNetError as exc:
                assert "\n" not in str(exc)
                outcomes["refused"] += 1
    print(f"\nflipped packets: {outcomes}")
    assert outcomes["refused"] > 100


def test_version_gates(natnet_dir) -> None:
    frame = _packet(natnet_dir, "mocapframe_packet_v3.bin")
    assert "NatNet 2.9 is not supported" in _one_line_refusal(lambda d: nn.decode_frame(d, (2, 9)), frame)
    # the 3.0 frame read as 4.1 runs into its sections' (missing) byte counts: refused, not misread
    _one_line_refusal(lambda d: nn.decode_frame(d, (4, 1)), frame)


def _v41_frame(f: nn.Frame) -> bytes:
    """The 3.0 frame re-encoded in the 4.1 layout (count + byte count per section, assets, PTP time)."""
    def sec(n: int, body: bytes) -> bytes:
        return struct.pack("<ii", n, len(body)) + body
    body = struct.pack("<i", f.frame_number)
    body += sec(0, b"") + sec(len(f.other_markers), f.other_markers.tobytes())
    body += sec(len(f.rigid_bodies), f.rigid_bodies.tobytes()) + sec(0, b"")
    body += sec(1, b"\x07" * 20)  # one asset we do not decode
    body += sec(len(f.labelled_markers), f.labelled_markers.tobytes())
    body += sec(0, b"") + sec(0, b"")
    body += struct.pack("<IIdQQQIIhi", f.timecode, f.timecode_sub, f.timestamp, f.mid_exposure_ticks,
                        f.data_received_ticks, f.transmit_ticks, 1700000000, 123, 2, 0)
    return struct.pack("<HH", nn.NAT_FRAMEOFDATA, len(body)) + body


def test_natnet_41_layout(natnet_dir) -> None:
    f3 = nn.decode_frame(_packet(natnet_dir, "mocapframe_packet_v3.bin"), (3, 0))
    f4 = nn.decode_frame(_v41_frame(f3), (4, 1))
    assert f4.frame_number == f3.frame_number and f4.skipped_items == 1
    assert np.array_equal(f4.labelled_markers, f3.labelled_markers)
    assert np.array_equal(f4.rigid_bodies, f3.rigid_bodies)
    assert (f4.precision_s, f4.precision_frac, f4.models_changed) == (1700000000, 123, True)
    # a model definition with an unknown type is skipped by its byte count from 4.1
    body = struct.pack("<i", 2) + struct.pack("<ii", 77, 3) + b"abc"
    body += struct.pack("<ii", 0, 0)
    ms = b"Set\0" + struct.pack("<i", 1) + b"M1\0"
    body = body[:-4] + struct.pack("<i", len(ms)) + ms
    md = nn.decode_model_defs(struct.pack("<HH", nn.NAT_MODELDEF, len(body)) + body, (4, 1))
    assert md.marker_sets == {"Set": ["M1"]} and md.skipped == {77: 1}
