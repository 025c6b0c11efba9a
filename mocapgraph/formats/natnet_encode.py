"""Encodes OptiTrack NatNet packets (server info, model definitions, frames), the inverse of formats.natnet.

Pure: dataclasses of :mod:`mocapgraph.formats.natnet` in, bytes out, for the NatNet simulator and
the replay server. The layout per version is the decoder's (see its module doc): 3.0 and 4.0
frames have no section byte counts and no precision timestamp, 4.0 rigid body descriptions carry
marker names, 4.1 and later frames carry a byte count after every section's item count, an (empty)
assets section and the PTP timestamp pair, and every model description a byte count after its type.
"""
from __future__ import annotations

import struct

import numpy as np

from . import natnet as nn

#: the NatNet versions the encoder writes (what Motive 2.x, 3.0, 3.1 and 3.2 stream)
VERSIONS: tuple[nn.Version, ...] = ((3, 0), (4, 0), (4, 1), (4, 2))


def _packet(msg_id: int, body: bytes) -> bytes:
    if len(body) > 0xFFFF:
        raise nn.NatNetError(f"{nn.MESSAGE_NAMES.get(msg_id, msg_id)}: {len(body)} bytes do not fit a "
                             "NatNet packet (65535 at most)")
    return struct.pack("<HH", msg_id, len(body)) + body


def _cstr(s: str) -> bytes:
    return s.encode("utf-8") + b"\0"


def server_info(info: nn.ServerInfo) -> bytes:
    """NAT_SERVERINFO: 256-byte application name, versions, clock rate, data port, multicast group."""
    name = info.app_name.encode("utf-8")[:255].ljust(256, b"\0")
    group = bytes(int(x) for x in (info.multicast_group or "0.0.0.0").split("."))
    body = name + bytes(info.app_version) + bytes(info.natnet_version)
    body += struct.pack("<QHB", info.clock_hz, info.data_port, int(info.multicast)) + group
    return _packet(nn.NAT_SERVERINFO, body)


def _rigid_body_def(rb: nn.RigidBodyDef, version: nn.Version) -> bytes:
    n = len(rb.marker_positions)
    out = _cstr(rb.name) + struct.pack("<ii3fi", rb.id, rb.parent_id, *map(float, rb.offset), n)
    out += np.asarray(rb.marker_positions, "<f4").reshape(n, 3).tobytes()
    out += np.asarray(rb.marker_labels, "<i4").reshape(n).tobytes()
    if version >= (4, 0):
        names = rb.marker_names or [""] * n
        out += b"".join(_cstr(s) for s in names)
    return out


def model_defs(defs: nn.ModelDefs, version: nn.Version) -> bytes:
    """NAT_MODELDEF: marker sets, rigid bodies, skeletons (in that order)."""
    descs: list[tuple[int, bytes]] = []
    for name, markers in defs.marker_sets.items():
        descs.append((nn.DESC_MARKERSET, _cstr(name) + struct.pack("<i", len(markers))
                      + b"".join(_cstr(m) for m in markers)))
    for rb in defs.rigid_bodies:
        descs.append((nn.DESC_RIGIDBODY, _rigid_body_def(rb, version)))
    for name, (sid, bodies) in defs.skeletons.items():
        descs.append((nn.DESC_SKELETON, _cstr(name) + struct.pack("<ii", sid, len(bodies))
                      + b"".join(_rigid_body_def(b, version) for b in bodies)))
    body = struct.pack("<i", len(descs))
    for kind, data in descs:
        body += struct.pack("<i", kind)
        if version >= (4, 1):
            body += struct.pack("<i", len(data))
        body += data
    return _packet(nn.NAT_MODELDEF, body)


def _section(n: int, data: bytes, sized: bool) -> bytes:
    return struct.pack("<ii", n, len(data)) + data if sized else struct.pack("<i", n) + data


def frame(f: nn.Frame, version: nn.Version) -> bytes:
    """NAT_FRAMEOFDATA of ``f`` (no assets, force plates or devices)."""
    sized = version >= (4, 1)
    body = struct.pack("<i", f.frame_number)
    sets = b"".join(_cstr(name) + struct.pack("<i", len(p)) + np.asarray(p, "<f4").tobytes()
                    for name, p in f.marker_sets.items())
    body += _section(len(f.marker_sets), sets, sized)
    body += _section(len(f.other_markers), np.asarray(f.other_markers, "<f4").tobytes(), sized)
    rbs = np.asarray(f.rigid_bodies, nn.RIGID_BODY)
    body += _section(len(rbs), rbs.tobytes(), sized)
    skel = b"".join(struct.pack("<ii", sid, len(b)) + np.asarray(b, nn.RIGID_BODY).tobytes()
                    for sid, b in f.skeletons.items())
    body += _section(len(f.skeletons), skel, sized)
    if sized:
        body += _section(0, b"", True)  # assets
    lm = np.asarray(f.labelled_markers, nn.LABELLED_MARKER)
    body += _section(len(lm), lm.tobytes(), sized)
    body += _section(0, b"", sized) + _section(0, b"", sized)  # force plates, devices
    body += struct.pack("<IIdQQQ", f.timecode, f.timecode_sub, f.timestamp, f.mid_exposure_ticks,
                        f.data_received_ticks, f.transmit_ticks)
    if sized:
        body += struct.pack("<II", f.precision_s, f.precision_frac)
    body += struct.pack("<h", f.params) + b"\0" * 4  # end-of-data tag, as Motive sends it
    return _packet(nn.NAT_FRAMEOFDATA, body)


def response(text: str) -> bytes:
    """NAT_RESPONSE carrying a NUL-terminated string (e.g. a Bitstream reply)."""
    return _packet(nn.NAT_RESPONSE, _cstr(text))
