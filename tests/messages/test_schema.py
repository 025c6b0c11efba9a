"""Each message type's field-by-field constructor builds what the generic Message.__init__ builds,
errors included: the same values, dtypes, shapes and contiguity, the same defaults, the same message."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.messages import CharacterPose
from mocapgraph.messages.registry import all_types
from mocapgraph.messages.schema import Array, Message, MessageError, Scalar, Strings


def _generic(cls, **kw):
    obj = cls.__new__(cls)
    Message.__init__(obj, **kw)
    return obj


def _values(cls, variant: int) -> dict:
    """Field values of ``cls``: 0 already of the declared types, 1 needing coercion (lists, other
    dtypes, strided arrays, numpy scalars, ints for floats), 2 a subset (the rest default)."""
    rng = np.random.default_rng(variant)
    out = {}
    for k, (name, spec) in enumerate(cls._info.fields.items()):
        if variant == 2 and k % 2:
            continue
        if isinstance(spec, Scalar):
            v = {"int": 7, "float": 0.25, "str": "abc", "bool": True}[spec.kind]
            if variant == 1:
                v = {"int": np.int32(7), "float": 3, "str": "é", "bool": False}[spec.kind]
            out[name] = v
        elif isinstance(spec, Strings):
            out[name] = ("a", "b") if variant == 1 else ["a", "b"]
        else:
            shape = tuple(3 if isinstance(s, str) else s for s in spec.shape)
            a = (rng.normal(size=shape) * 3).astype(spec.dtype)
            if variant == 1:
                big = np.zeros(shape[:-1] + (2 * shape[-1],) if shape else (), np.float32) if shape else a
                if shape:
                    big[..., ::2] = a
                    a = big[..., ::2]            # strided float32: converted and made contiguous
                else:
                    a = a.tolist()
            out[name] = a
    return out


@pytest.mark.parametrize("variant", [0, 1, 2])
def test_every_type_builds_what_the_generic_constructor_builds(variant):
    types = all_types()
    assert len(types) >= 10
    for cls in types.values():
        kw = _values(cls, variant)
        fast, slow = cls(**kw), _generic(cls, **kw)
        assert fast.__dict__.keys() == slow.__dict__.keys(), cls
        for name, spec in cls._info.fields.items():
            a, b = fast.__dict__[name], slow.__dict__[name]
            assert type(a) is type(b), (cls, name)
            if isinstance(spec, Array):
                assert a.dtype == b.dtype and a.shape == b.shape and a.flags.c_contiguous, (cls, name)
                np.testing.assert_array_equal(a, b)
            else:
                assert a == b, (cls, name)
            if isinstance(spec, Strings) and name in kw:
                assert a is not kw[name]           # the message owns its list


def test_an_array_of_the_declared_type_is_kept_and_errors_read_as_before():
    pos = np.zeros((20, 3))
    msg = CharacterPose(character="c", frame_number=1, root_position=np.zeros(3), local_rotations=np.zeros((20, 4)),
                        joint_positions=pos, joint_quality=np.zeros(20, np.int8))
    assert msg.joint_positions is pos
    bad = [dict(nonsense=1), dict(root_position=np.zeros(4)), dict(local_rotations=np.zeros((20, 3))),
           dict(frame_number="one"), dict(character=3)]
    for kw in bad:
        with pytest.raises(MessageError) as fast:
            CharacterPose(**kw)
        with pytest.raises(MessageError) as slow:
            _generic(CharacterPose, **kw)
        assert str(fast.value) == str(slow.value), kw


def test_fields_named_like_builtins_or_self_still_build():
    from mocapgraph.messages.schema import array, scalar

    class OddNames(Message):
        type_name = "TestOddNames"
        type: str = scalar("str", "a field called type")
        len = array("float64", (2,), "a field called len")

    m = OddNames(type="t", len=np.zeros(2))
    assert m.type == "t" and m.len.shape == (2,)
    with pytest.raises(MessageError, match="wants shape"):
        OddNames(len=np.zeros(3))


def test_assigning_a_field_coerces_it_as_the_constructor_does():
    msg = CharacterPose(character="c", frame_number=1, root_position=np.zeros(3), local_rotations=np.zeros((20, 4)),
                        joint_positions=np.zeros((20, 3)), joint_quality=np.zeros(20, np.int8))
    msg.root_position = [1, 2, 3]                   # a list of ints: a float64 array
    assert msg.root_position.dtype == np.float64 and msg.root_position.tolist() == [1.0, 2.0, 3.0]
    msg.frame_number = np.int64(7)                  # a numpy integer: a Python int, as encode wants
    assert type(msg.frame_number) is int and msg.frame_number == 7
    with pytest.raises(MessageError, match="shape"):
        msg.joint_positions = np.zeros((20, 4))
    assert msg.joint_positions.shape == (20, 3)     # the refused value did not land
    msg.note = "not a field"                        # other attributes are plain ones
    assert msg.note == "not a field" and "note" not in type(msg)._info.fields
    assert isinstance(CharacterPose.root_position, Array)   # the class still gives the declaration
