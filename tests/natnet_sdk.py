"""OptiTrack's own Python NatNet client (PyPI ``natnetsdk``, the NatNet SDK's PythonClient) as an
independent decoder: its unpacking of a frame or of model definitions, and ours, as plain values.

Only its unpack functions are used in-process (no ``run()``: its receive threads are not daemons
and its ``shutdown()`` hangs while no server sends, see ``tests/natnet_sdk_client.py``)."""
from __future__ import annotations

import contextlib
import io

import numpy as np

from mocapgraph.formats import natnet as nn


def _client():
    from natnetsdk.NatNetClient import NatNetClient

    return NatNetClient()


def _f(v) -> list[float]:
    return [float(x) for x in (v if isinstance(v, (list, tuple, np.ndarray)) else [v])]


def sdk_frame(packet: bytes, version: nn.Version) -> dict:
    """natnetsdk's reading of a NAT_FRAMEOFDATA packet."""
    c = _client()
    size = int.from_bytes(packet[2:4], "little")
    with contextlib.redirect_stdout(io.StringIO()):
        _, m = c._NatNetClient__unpack_mocap_data(packet[4:], size, *version)
    return sdk_values(m)


def sdk_values(m) -> dict:
    """A natnetsdk MoCapData as plain values (the shape of :func:`our_frame`)."""
    s = m.suffix_data
    prec = [0 if v == -1 else v & 0xFFFFFFFF for v in (s.prec_timestamp_secs, s.prec_timestamp_frac_secs)]
    return {
        "frame": m.prefix_data.frame_number,
        "sets": {d.model_name.decode(): [_f(p) for p in d.marker_pos_list] for d in m.marker_set_data.marker_data_list},
        "other": [_f(p) for p in m.legacy_other_markers.marker_pos_list],
        "bodies": [(b.id_num, _f(b.pos), _f(b.rot), float(b.error), bool(b.tracking_valid))
                   for b in m.rigid_body_data.rigid_body_list],
        "skeletons": {str(k.id_num): [(b.id_num, _f(b.pos), _f(b.rot), float(b.error), bool(b.tracking_valid))
                                      for b in k.rigid_body_list] for k in m.skeleton_data.skeleton_list},
        "labelled": [(lm.id_num, _f(lm.pos), float(lm.size), int(lm.param), float(lm.residual) / 1000.0)
                     for lm in m.labeled_marker_data.labeled_marker_list],
        "suffix": (s.timecode, s.timecode_sub, float(s.timestamp), s.stamp_camera_mid_exposure, s.stamp_data_received,
                   s.stamp_transmit, *prec, s.param),
    }


def our_frame(packet: bytes, version: nn.Version) -> dict:
    """Our decoder's reading of the same packet, in the same shape."""
    f = nn.decode_frame(packet, version)
    rb, lm = f.rigid_bodies, f.labelled_markers
    return {
        "frame": f.frame_number,
        "sets": {k: v.astype(float).tolist() for k, v in f.marker_sets.items()},
        "other": f.other_markers.astype(float).tolist(),
        "bodies": [(int(b["id"]), _f(b["pos"]), _f(b["quat_xyzw"]), float(b["error"]), bool(v))
                   for b, v in zip(rb, f.rigid_body_valid)],
        "skeletons": {str(sid): [(int(b["id"]), _f(b["pos"]), _f(b["quat_xyzw"]), float(b["error"]),
                                  bool(b["params"] & nn.RIGID_BODY_TRACKING_VALID)) for b in bones]
                      for sid, bones in f.skeletons.items()},
        "labelled": [(int(m["id"]), _f(m["pos"]), float(m["size"]), int(m["params"]), float(m["residual"]))
                     for m in lm],
        "suffix": (f.timecode, f.timecode_sub, f.timestamp, f.mid_exposure_ticks, f.data_received_ticks,
                   f.transmit_ticks, f.precision_s, f.precision_frac, f.params),
    }


def sdk_defs(packet: bytes, version: nn.Version) -> dict:
    """natnetsdk's reading of a NAT_MODELDEF packet: marker sets, rigid bodies, skeletons."""
    c = _client()
    size = int.from_bytes(packet[2:4], "little")
    with contextlib.redirect_stdout(io.StringIO()):
        _, d = c._NatNetClient__unpack_data_descriptions(packet[4:], size, *version)
    name = lambda v: v.decode() if isinstance(v, bytes) else str(v)  # noqa: E731
    return {
        "sets": {name(m.marker_set_name): [name(n) for n in m.marker_names_list] for m in d.marker_set_list},
        "bodies": [(name(b.sz_name), b.id_num, b.parent_id, _f(b.pos),
                    [name(k.marker_name) for k in b.rb_marker_list]) for b in d.rigid_body_list],
        "skeletons": {name(s.name): s.id_num for s in d.skeleton_list},
    }


def our_defs(packet: bytes, version: nn.Version) -> dict:
    d = nn.decode_model_defs(packet, version)
    return {
        "sets": d.marker_sets,
        "bodies": [(b.name, b.id, b.parent_id, _f(b.offset),
                    list(b.marker_names) or [""] * len(b.marker_positions)) for b in d.rigid_bodies],
        "skeletons": {k: sid for k, (sid, _) in d.skeletons.items()},
    }
