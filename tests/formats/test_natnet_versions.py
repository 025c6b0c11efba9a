"""NatNet 3.0, 4.0, 4.1 and 4.2 bitstreams field by field: packets packed by hand from the protocol's
field order (a table written here, not the encoder), every field a distinct value, so a field read
at a wrong offset fails; our encoder must write the same bytes; OptiTrack's own client (natnetsdk)
must read the same values (see the 4.0 note); the simulator's frames decode to their source values."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from mocapgraph.formats import natnet as nn
from mocapgraph.formats import natnet_encode as ne
from mocapgraph.testing.natnet_server import ActorStream
from tests.natnet_sdk import our_defs, our_frame

VERSIONS = [(3, 0), (4, 0), (4, 1), (4, 2)]
RB = struct.pack("<i3f4ffh", 42, 0.125, 0.25, 0.375, 0.1, 0.2, 0.3, 0.9, 0.0005, 1)
BONE = struct.pack("<i3f4ffh", (5 << 16) | 1, 1.125, 1.25, 1.375, 0.5, 0.5, 0.5, 0.5, 0.0015, 0)


def spec_frame(version: nn.Version) -> tuple[bytes, dict]:
    """A frame packed field by field as NatNet ``version`` lays it out, and the values it holds."""
    sized = version >= (4, 1)

    def sec(n: int, body: bytes) -> bytes:  # item count, (4.1+) byte count, items
        return struct.pack("<i", n) + (struct.pack("<i", len(body)) if sized else b"") + body

    body = struct.pack("<i", 7001)
    body += sec(1, b"Set\0" + struct.pack("<i6f", 2, 1.5, 2.5, 3.5, 4.5, 5.5, 6.5))
    body += sec(1, struct.pack("<3f", 7.25, 8.25, 9.25))
    body += sec(1, RB)
    body += sec(1, struct.pack("<ii", 5, 1) + BONE)
    if sized:
        body += sec(0, b"")                                                  # assets (4.1+)
    body += sec(1, struct.pack("<i3ffhf", (42 << 16) | 3, -1.0, -2.0, -3.0, 0.015, 0x22, 0.0007))
    body += sec(0, b"") + sec(0, b"")                                        # force plates, devices
    body += struct.pack("<IIdQQQ", 0x01020304, 5, 12.5, 1000, 2000, 3000)
    if sized:
        body += struct.pack("<II", 1700000000, 0x80000001)                  # precision time (4.1+)
    body += struct.pack("<h", 3) + b"\0" * 4
    f32 = lambda *v: [float(np.float32(x)) for x in v]  # noqa: E731
    want = {"frame": 7001, "sets": {"Set": [[1.5, 2.5, 3.5], [4.5, 5.5, 6.5]]}, "other": [[7.25, 8.25, 9.25]],
            "bodies": [(42, f32(0.125, 0.25, 0.375), f32(0.1, 0.2, 0.3, 0.9), f32(0.0005)[0], True)],
            "skeletons": {"5": [((5 << 16) | 1, f32(1.125, 1.25, 1.375), f32(0.5, 0.5, 0.5, 0.5), f32(0.0015)[0], False)]},
            "labelled": [((42 << 16) | 3, [-1.0, -2.0, -3.0], f32(0.015)[0], 0x22, f32(0.0007)[0])],
            "suffix": (0x01020304, 5, 12.5, 1000, 2000, 3000, *((1700000000, 0x80000001) if sized else (0, 0)), 3)}
    return struct.pack("<HH", nn.NAT_FRAMEOFDATA, len(body)) + body, want  # the count covers the end tag


def spec_defs(version: nn.Version) -> tuple[bytes, dict]:
    """Model definitions packed field by field: a marker set, a rigid body with 2 markers (names
    from 4.0), a skeleton with one bone; (4.1+) a byte count after each description's type."""
    names = version >= (4, 0)

    def rb(name: bytes, rid: int, parent: int, off: tuple, markers: list[bytes]) -> bytes:
        out = name + b"\0" + struct.pack("<ii3fi", rid, parent, *off, len(markers))
        out += b"".join(struct.pack("<3f", k, k + 0.5, k + 0.25) for k in range(len(markers)))
        out += struct.pack(f"<{len(markers)}i", *range(11, 11 + len(markers)))
        return out + (b"".join(m + b"\0" for m in markers) if names else b"")

    descs = [(0, b"Wand\0" + struct.pack("<i", 2) + b"Tip\0Base\0"),
             (1, rb(b"Wand", 42, -1, (0.5, 0.75, 1.0), [b"Tip", b"Base"])),
             (2, b"Actor\0" + struct.pack("<ii", 5, 1) + rb(b"Hips", 1, -1, (0.0, 1.0, 0.0), []))]
    body = struct.pack("<i", len(descs))
    for kind, d in descs:
        body += struct.pack("<i", kind) + (struct.pack("<i", len(d)) if version >= (4, 1) else b"") + d
    want = {"sets": {"Wand": ["Tip", "Base"]},
            "bodies": [("Wand", 42, -1, [0.5, 0.75, 1.0], ["Tip", "Base"] if names else ["", ""])],
            "skeletons": {"Actor": 5}}
    return struct.pack("<HH", nn.NAT_MODELDEF, len(body)) + body, want


@pytest.mark.parametrize("version", VERSIONS, ids=lambda v: "%d.%d" % v)
def test_every_frame_field_at_its_offset(version) -> None:
    packet, want = spec_frame(version)
    assert our_frame(packet, version) == want
    f = nn.decode_frame(packet, version)
    assert f.skeletons[5]["pos"].tolist() == [[1.125, 1.25, 1.375]] and f.skeletons[5]["error"][0] == np.float32(0.0015)
    assert ne.frame(f, version) == packet                 # the encoder writes the same bytes
    # read with the other frame layout (3.0 and 4.0 share one, 4.1 and 4.2 another): refused, or
    # some value comes out wrong
    for other in VERSIONS:
        if (other >= (4, 1)) != (version >= (4, 1)):
            try:
                assert our_frame(packet, other) != want
            except nn.NatNetError:
                pass


@pytest.mark.parametrize("version", VERSIONS, ids=lambda v: "%d.%d" % v)
def test_every_model_definition_field_at_its_offset(version) -> None:
    packet, want = spec_defs(version)
    assert our_defs(packet, version) == want
    assert nn.decode_model_defs(packet, version).skeletons["Actor"][1][0].offset.tolist() == [0.0, 1.0, 0.0]
    assert ne.model_defs(nn.decode_model_defs(packet, version), version) == packet
    for other in VERSIONS:                # each version's descriptions differ from every other's
        if other != version and {other, version} != {(4, 1), (4, 2)}:
            try:
                assert our_defs(packet, other) != want
            except nn.NatNetError:
                pass


@pytest.mark.parametrize("version", VERSIONS, ids=lambda v: "%d.%d" % v)
def test_natnetsdk_reads_the_hand_packed_bytes_as_we_do(version) -> None:
    pytest.importorskip("natnetsdk")
    from tests.natnet_sdk import sdk_defs, sdk_frame

    packet, want = spec_frame(version)
    if version == (4, 0):
        # natnetsdk 4.1.1 reads the precision timestamp from 4.0 on; OptiTrack's C++ PacketClient and
        # the 2025 Python sample from 4.1 on (as we do): on a 4.0 frame it runs out of bytes
        with pytest.raises(struct.error):
            sdk_frame(packet, version)
        sdk = sdk_frame(packet[:-4] + b"\0" * 8, version)  # with 8 more bytes it gets that far
        assert {k: v for k, v in sdk.items() if k != "suffix"} == {k: v for k, v in want.items() if k != "suffix"}
    else:
        assert sdk_frame(packet, version) == want
    dpacket, dwant = spec_defs(version)
    assert sdk_defs(dpacket, version) == dwant


@pytest.mark.parametrize("version", VERSIONS, ids=lambda v: "%d.%d" % v)
def test_simulator_frames_decode_to_their_source_values(version) -> None:
    stream = ActorStream("plug_in_gait", rate_hz=240.0, n_bodies=5, dropout_rate_hz=0.5, seed=9)
    src = list(stream.frames(1000, 48))
    for f in src:
        g = nn.decode_frame(ne.frame(f, version), version)
        assert g.frame_number == f.frame_number and g.timestamp == f.timestamp
        assert np.array_equal(g.labelled_markers, f.labelled_markers)
        assert np.array_equal(g.rigid_bodies, f.rigid_bodies)
        assert g.skeletons.keys() == f.skeletons.keys() == {1} and np.array_equal(g.skeletons[1], f.skeletons[1])
        assert np.array_equal(g.marker_sets["Actor"], f.marker_sets["Actor"])
        assert (g.mid_exposure_ticks, g.data_received_ticks, g.transmit_ticks) == \
            (f.mid_exposure_ticks, f.data_received_ticks, f.transmit_ticks)
        if version >= (4, 1):
            assert (g.precision_s, g.precision_frac) == (f.precision_s, f.precision_frac)
    occluded = np.array([(f.labelled_markers["params"] & nn.MARKER_OCCLUDED) != 0 for f in src])
    assert occluded.any()
    d = nn.decode_model_defs(ne.model_defs(stream.model_defs(), version), version)
    assert d.marker_sets["Actor"] == stream.labels and [b.name for b in d.rigid_bodies] == stream.body_names


def test_labels_from_marker_sets_and_bodies() -> None:
    from mocapgraph.formats.natnet_model import NatNetModel

    d = nn.ModelDefs(marker_sets={"Actor": ["Actor_LFHD", "RFHD"], "Loose": ["A"], "all": ["x", "y", "z"]})
    d.skeletons["Actor"] = (3, [])
    d.rigid_bodies.append(nn.RigidBodyDef("Wand", 9, -1, np.zeros(3, np.float32), np.zeros((2, 3), np.float32),
                                          np.zeros(2, np.int32), ["Tip", "Base"]))
    m = NatNetModel(d)
    assert m.labels == ["Actor:LFHD", "Actor:RFHD", "Loose:A", "Wand:Tip", "Wand:Base"]
    lm = np.zeros(5, nn.LABELLED_MARKER)
    lm["id"] = [(3 << 16) | 2, (9 << 16) | 1, (9 << 16) | 2, 40001, (7 << 16) | 1]
    lm["pos"] = np.arange(15, dtype=np.float32).reshape(5, 3)
    lm["params"] = [0, 0, nn.MARKER_OCCLUDED, nn.MARKER_UNLABELLED, 0]
    f = nn.Frame(1, {"Loose": np.array([[0, 0, 0]], np.float32)}, np.zeros((0, 3), np.float32),
                 np.zeros(0, nn.RIGID_BODY), {}, lm, 0, 0, 0.0, 0, 0, 0)
    lab = m.labelled(f)
    assert np.isnan(lab.positions[0]).all() and lab.positions[1].tolist() == [0, 1, 2]
    assert np.isnan(lab.positions[2]).all()                       # Motive's 0,0,0 in a set: not seen
    assert lab.positions[3].tolist() == [3, 4, 5] and np.isnan(lab.positions[4]).all()   # occluded: NaN
    assert lab.unknown                                            # model 7 is not described
    from mocapgraph.formats.natnet_model import unlabelled
    assert unlabelled(f)[0].tolist() == [[9, 10, 11]]
