"""Messages: every type round-trips bit-exactly; malformed frames raise DecodeError, never crash."""
from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from mocapgraph.messages import (
    DecodeError, MarkerFrame, MarkerLayout, Message, MessageError, NodeCommand,
    all_types, decode, decode_envelope, encode,
)
from mocapgraph.messages.codec import HEADER, local_copy, local_envelope
from mocapgraph.messages.schema import Array, Scalar, Strings


def sample(cls: type[Message], rng: np.random.Generator, n: int = 5) -> Message:
    """An instance with every field filled with random data of the declared kind."""
    values = {}
    for name, spec in cls.fields().items():
        if isinstance(spec, Scalar):
            values[name] = {"int": int(rng.integers(-1000, 1000)), "float": float(rng.normal()),
                            "str": f"s{rng.integers(100)}", "bool": bool(rng.integers(2))}[spec.kind]
        elif isinstance(spec, Strings):
            values[name] = [f"name{i}" for i in range(n)]
        else:
            shape = tuple(n if isinstance(s, str) else s for s in spec.shape)
            values[name] = (rng.normal(size=shape) * 100).astype(spec.dtype)
    return cls(**values)


@pytest.mark.parametrize("type_name", sorted(all_types()))
def test_every_type_round_trips_exactly(type_name: str) -> None:
    cls = all_types()[type_name]
    msg = sample(cls, np.random.default_rng(1))
    frames = [bytes(f) for f in encode("some/topic", msg, seq=42, capture_ns=123456789, sender="n1")]
    env, back = decode(frames)
    assert back == msg
    assert (env.topic, env.type_name, env.seq, env.capture_ns, env.sender) == ("some/topic", type_name, 42,
                                                                               123456789, "n1")
    for name, spec in cls.fields().items():
        if isinstance(spec, Array):
            assert getattr(back, name).dtype == np.dtype(spec.dtype)
    schema = cls.json_schema()
    assert schema["title"] == type_name and set(schema["properties"]) == set(cls.fields())
    json.dumps(schema)


def test_nan_survives_and_missing_markers_stay_missing() -> None:
    pos = np.arange(12.0).reshape(4, 3)
    pos[2] = np.nan
    msg = MarkerFrame(frame_number=7, rate_hz=240, positions=pos, valid=[1, 1, 0, 1], residual=np.zeros(4))
    _, back = decode(encode("markers", msg, 1, 0))
    assert np.isnan(back.positions[2]).all() and not back.valid[2] and back.valid.dtype == bool


def test_construction_checks_types_and_shapes() -> None:
    with pytest.raises(MessageError, match="positions"):
        MarkerFrame(positions=np.zeros((4, 2)))
    with pytest.raises(MessageError, match="frame_number"):
        MarkerFrame(frame_number="seven")
    with pytest.raises(MessageError, match="no field"):
        MarkerFrame(bogus=1)
    with pytest.raises(MessageError, match="list of strings"):
        MarkerLayout(labels="LASI")


def good_frames() -> list[bytes]:
    msg = MarkerFrame(frame_number=1, rate_hz=100, positions=np.ones((8, 3)), valid=np.ones(8, bool),
                      residual=np.zeros(8))
    return [bytes(f) for f in encode("markers", msg, 1, 0, "src")]


@pytest.mark.parametrize("mutate, reason", [
    (lambda f: f[:2], "at least 3"),
    (lambda f: [f[0], f[1][:10], *f[2:]], "truncated"),
    (lambda f: [f[0], b"XX" + f[1][2:], *f[2:]], "magic"),
    (lambda f: [f[0], f[1].replace(b"MarkerFrame", b"MarkerFrumx"), *f[2:]], "unknown message type"),
    (lambda f: [*f[:3], f[3][:-8], *f[4:]], "bytes for shape"),
    (lambda f: [*f[:2], f[2][:5], *f[3:]], "truncated"),
    (lambda f: [*f[:2], f[2] + b"xx", *f[3:]], "too many"),
    (lambda f: [*f[:2], f[2][:24] + struct.pack("<I", 9) + f[2][28:], *f[3:]], "disagrees"),
    (lambda f: f[:-1], "wants 6 frames"),
])
def test_garbage_raises_decode_error(mutate, reason: str) -> None:
    with pytest.raises(DecodeError, match=reason):
        decode(mutate(good_frames()))


def test_random_bytes_never_escape_as_other_errors() -> None:
    rng = np.random.default_rng(0)
    base = good_frames()
    for _ in range(500):
        frames = [bytearray(f) for f in base]
        i = rng.integers(len(frames))
        if len(frames[i]):
            frames[i][rng.integers(len(frames[i]))] = rng.integers(256)
        try:
            decode([bytes(f) for f in frames])
        except DecodeError:
            pass


def test_envelope_is_cheap_and_carries_header() -> None:
    frames = [bytes(f) for f in encode("cmd", NodeCommand(target="cal", command="capture_gym"), 9, 5, "viewer",
                                       publish_ns=77, latched=True)]
    env = decode_envelope(frames)
    assert (env.seq, env.capture_ns, env.publish_ns, env.sender, env.latched) == (9, 5, 77, "viewer", True)
    assert len(frames[1]) == HEADER.size + len("NodeCommand") + len("viewer")


def test_text_fields_travel_as_json_and_bad_text_is_rejected() -> None:
    msg = MarkerLayout(name="kiip", labels=["A", "B"], limb_names=["arm"], marker_limb=[0, 0])
    frames = [bytes(f) for f in encode("marker_layout", msg, 1, 0)]
    assert decode(frames)[1] == msg
    with pytest.raises(DecodeError, match="text fields"):
        decode([*frames[:2], frames[2][:-3], *frames[3:]])


@pytest.mark.parametrize("type_name", sorted(all_types()))
def test_a_local_copy_is_what_decoding_gives_and_owns_its_arrays(type_name: str) -> None:
    """In-process delivery hands a copy over instead of bytes: equal to the decoded message, the same
    dtypes and read-only flags (so compiled kernels see the same types), sharing nothing."""
    cls = all_types()[type_name]
    msg = sample(cls, np.random.default_rng(2))
    frames = [bytes(f) for f in encode("t", msg, seq=7, capture_ns=99, sender="n", latched=True)]
    env, decoded = decode(frames)
    copy = local_copy(msg)
    assert copy == decoded and type(copy) is cls
    assert local_envelope("t", type_name, "n", frames[1]) == env
    for name, spec in cls.fields().items():
        mine, theirs = getattr(copy, name), getattr(decoded, name)
        if isinstance(spec, Array):
            assert mine.dtype == theirs.dtype and mine.flags.writeable == theirs.flags.writeable is False
            assert mine.flags.c_contiguous and not np.shares_memory(mine, getattr(msg, name))
        elif isinstance(spec, Strings):
            assert mine == getattr(msg, name) and mine is not getattr(msg, name)


def test_a_local_copy_refuses_shapes_decoding_refuses() -> None:
    bad = MarkerFrame(frame_number=1, positions=np.zeros((4, 3)), valid=np.ones(4, bool), residual=np.zeros(3))
    with pytest.raises(DecodeError, match="N=3 disagrees with N=4"):
        decode([bytes(f) for f in encode("t", bad, seq=1, capture_ns=0)])
    with pytest.raises(DecodeError, match="N=3 disagrees with N=4"):
        local_copy(bad)
    good = MarkerFrame(frame_number=1, positions=np.zeros((3, 3)), valid=np.ones(3, bool), residual=np.zeros(3))
    assert local_copy(good) == good
    with pytest.raises(DecodeError):   # after a good frame of other shapes, the check is made again
        local_copy(bad)
