"""The codec's per-stream shortcuts (cached text blocks, dims checked once per shape, conforming
arrays taken as they are) change no byte and let no malformed frame through."""
from __future__ import annotations

import json

import numpy as np
import pytest

from mocapgraph.messages import CharacterPose, DecodeError, MessageError, SkeletonInfo, decode, encode


def _pose(name: str, J: int, seed: int = 0) -> CharacterPose:
    rng = np.random.default_rng(seed)
    return CharacterPose(character=name, frame_number=seed, root_position=rng.normal(size=3),
                         local_rotations=rng.normal(size=(J, 4)), joint_positions=rng.normal(size=(J, 3)),
                         joint_quality=rng.integers(0, 3, J).astype(np.int8))


def _wire(msg, seq: int = 1) -> list[bytes]:
    return [bytes(f) for f in encode("character_pose", msg, seq, 5, "rt", publish_ns=7)]


def test_text_blocks_follow_the_values_and_equal_json():
    for name in ("a", "b", "a", 'quote " and ü'):
        frames = _wire(_pose(name, 4))
        _, got = decode(frames)
        assert got.character == name
        block = frames[2]
        assert json.loads(block[block.index(b"{"):]) == {"character": name}   # the text block is plain JSON
    # list-valued text fields are not cached by value and come back as fresh lists
    info = SkeletonInfo(source="x", joint_names=["a", "b"], joint_parent=np.array([-1, 0], np.int32),
                        rest_offsets=np.zeros((2, 3)))
    frames = [bytes(f) for f in encode("skeleton_info", info, 1, 5, "rt")]
    one, two = decode(frames)[1], decode(frames)[1]
    assert one.joint_names == ["a", "b"] and one.joint_names is not two.joint_names


def test_a_stream_changing_shape_and_a_truncated_frame_after_the_cached_shape():
    for J in (20, 20, 21, 20):
        msg = _pose("c", J, seed=J)
        _, got = decode(_wire(msg))
        assert got == msg
    frames = _wire(_pose("c", 20))
    frames[4] = frames[4][:-8]                   # one joint position short, same dims as cached
    with pytest.raises(DecodeError, match="bytes for shape"):
        decode(frames)
    frames = _wire(_pose("c", 20))
    frames[5] = frames[5] + b"\0"               # one quality byte too many
    with pytest.raises(DecodeError, match="bytes for shape"):
        decode(frames)


def test_conforming_arrays_are_taken_as_they_are_others_converted_or_refused():
    q = np.zeros((3, 4))
    msg = CharacterPose(character="c", root_position=np.zeros(3), local_rotations=q, joint_positions=np.zeros((3, 3)),
                        joint_quality=np.zeros(3, np.int8))
    assert msg.local_rotations is q
    msg = CharacterPose(character="c", root_position=np.zeros(3), local_rotations=np.zeros((3, 4), np.float32),
                        joint_positions=np.zeros((6, 3))[::2], joint_quality=[2, 2, 2])
    assert msg.local_rotations.dtype == np.float64 and msg.joint_positions.flags.c_contiguous
    assert msg.joint_quality.dtype == np.int8
    with pytest.raises(MessageError, match="wants shape"):
        CharacterPose(root_position=np.zeros(4))
    with pytest.raises(MessageError, match="wants shape"):
        CharacterPose(local_rotations=np.zeros((3, 3)))


def test_header_names_and_topic_frames_follow_sender_and_topic_and_stay_bounded():
    from mocapgraph.messages import codec
    from mocapgraph.messages.codec import decode_envelope, topic_frame
    msg = _pose("c", 3)
    for sender, topic in (("rt", "character_pose"), ("other", "poses/b"), ("rt", "character_pose"), ("ü-node", "t")):
        env = decode_envelope(encode(topic, msg, 3, 5, sender, publish_ns=7))
        assert (env.sender, env.topic, env.type_name) == (sender, topic, "CharacterPose")
        assert topic_frame(topic) == topic.encode() + b"\0"
    for k in range(5000):   # a hostile flood of names: the caches stop growing, the bytes stay right
        env = decode_envelope(encode(f"t{k}", msg, 3, 5, f"s{k}", publish_ns=7))
        assert (env.sender, env.topic) == (f"s{k}", f"t{k}")
    assert len(codec._TOPIC_FRAMES) <= 4096
    assert len(codec._plan(CharacterPose._info).names_out) <= codec._TEXT_CACHE
