"""Declaring message types: typed scalar fields and numpy array fields with dtype and shape.

A message type is a subclass of `Message` whose class attributes are `Scalar`, `Strings` or
`Array` declarations. Shapes name their symbolic sizes (``("N", 3)``); every array of one
message that uses the same symbol must agree on it, which is what lets a decoder reject a frame
whose arrays were cut or padded.

Conventions carried by every type (see README "Conventions"): SI units, world frame right-handed
Z up X forward, quaternions (w, x, y, z), time stamps in integer nanoseconds, missing data as NaN
plus a quality flag.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, ClassVar

import numpy as np

SCALAR_TYPES: dict[str, type] = {"int": int, "float": float, "str": str, "bool": bool}
#: struct code of each numeric scalar kind in the field block (the codec's frame 2): i64, f64, u8
FIELD_BLOCK_CODES: dict[str, str] = {"int": "q", "float": "d", "bool": "?"}


class MessageError(ValueError):
    """A message that does not fit its declared schema."""


@dataclass(frozen=True)
class Scalar:
    """A scalar field: ``kind`` is one of int, float, str, bool."""

    kind: str
    doc: str
    default: Any = None
    name: str = ""

    def coerce(self, value: Any) -> Any:
        py = SCALAR_TYPES[self.kind]
        if self.kind == "float" and isinstance(value, (int, float, np.floating, np.integer)):
            return float(value)
        if self.kind == "int" and isinstance(value, (int, np.integer)) and not isinstance(value, bool):
            return int(value)
        if isinstance(value, py):
            return value
        raise MessageError(f"field {self.name!r} wants {self.kind}, got {type(value).__name__}")

    def json_schema(self) -> dict:
        kinds = {"int": "integer", "float": "number", "str": "string", "bool": "boolean"}
        return {"type": kinds[self.kind], "description": self.doc}


@dataclass(frozen=True)
class Strings:
    """A list of strings (names carried in latched messages, not per frame)."""

    doc: str
    name: str = ""

    def coerce(self, value: Any) -> list[str]:
        if isinstance(value, str) or not all(isinstance(v, str) for v in value):
            raise MessageError(f"field {self.name!r} wants a list of strings")
        return list(value)

    def json_schema(self) -> dict:
        return {"type": "array", "items": {"type": "string"}, "description": self.doc}


@dataclass(frozen=True)
class Array:
    """A numpy array field with a fixed dtype and a shape of ints and symbols."""

    dtype: str
    shape: tuple[int | str, ...]
    doc: str
    name: str = ""

    @cached_property
    def _fast(self) -> tuple:
        """(numpy dtype, rank, fixed (axis, size) pairs): what an array that needs no conversion has."""
        return np.dtype(self.dtype), len(self.shape), tuple((i, s) for i, s in enumerate(self.shape) if isinstance(s, int))

    def coerce(self, value: Any) -> np.ndarray:
        if type(value) is np.ndarray:   # already right (the usual case): the same array ascontiguousarray returns
            dt, rank, fixed = self._fast
            if value.dtype is dt and value.ndim == rank and value.flags.c_contiguous:
                shape = value.shape
                for i, s in fixed:
                    if shape[i] != s:
                        break
                else:
                    return value
        arr = np.ascontiguousarray(value, dtype=self.dtype)
        if arr.ndim != len(self.shape):
            raise MessageError(
                f"field {self.name!r} wants shape {self.shape_text()}, got {arr.shape}"
            )
        for size, want in zip(arr.shape, self.shape):
            if isinstance(want, int) and size != want:
                raise MessageError(
                    f"field {self.name!r} wants shape {self.shape_text()}, got {arr.shape}"
                )
        return arr

    def shape_text(self) -> str:
        return "[" + ",".join(str(s) for s in self.shape) + "]"

    def empty(self) -> np.ndarray:
        return np.zeros(tuple(0 if isinstance(s, str) else s for s in self.shape), self.dtype)

    def json_schema(self) -> dict:
        return {
            "type": "array",
            "description": self.doc,
            "x-dtype": self.dtype,
            "x-shape": list(self.shape),
            "x-encoding": "raw little-endian buffer, C order, in its own ZeroMQ frame",
        }


FieldSpec = Scalar | Strings | Array


def scalar(kind: str, doc: str, default: Any = None) -> Scalar:
    """Declare a scalar field (kind: int, float, str, bool)."""
    if kind not in SCALAR_TYPES:
        raise ValueError(f"unknown scalar kind {kind!r}")
    if default is None:
        default = SCALAR_TYPES[kind]()
    return Scalar(kind, doc, default)


def strings(doc: str) -> Strings:
    """Declare a list-of-strings field."""
    return Strings(doc)


def array(dtype: str, shape: tuple[int | str, ...], doc: str) -> Array:
    """Declare an array field, e.g. ``array("float64", ("N", 3), "positions, m, world")``."""
    np.dtype(dtype)  # fail early on a typo
    return Array(dtype, tuple(shape), doc)


@dataclass
class _TypeInfo:
    name: str
    version: int
    scalars: tuple[Scalar, ...] = ()
    strings: tuple[Strings, ...] = ()
    arrays: tuple[Array, ...] = ()
    fields: dict[str, FieldSpec] = field(default_factory=dict)
    latched: bool = False

    def field_block(self) -> str:
        """The struct format of the field block (the codec's frame 2), little-endian: each numeric
        scalar in declaration order, then a u32 per dimension of each array."""
        codes = "".join(FIELD_BLOCK_CODES[s.kind] for s in self.scalars if s.kind != "str")
        return "<" + codes + "I" * sum(len(a.shape) for a in self.arrays)


class Message:
    """Base of all message types. Subclass with field declarations and ``type_name``/``version``.

    Instances are plain attribute bags; constructing one coerces each given field to its
    declared type so that an encoder never meets a surprise.
    """

    type_name: ClassVar[str] = ""
    version: ClassVar[int] = 1
    latched_by_default: ClassVar[bool] = False
    _info: ClassVar[_TypeInfo]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        specs: dict[str, FieldSpec] = {}
        for base in reversed(cls.__mro__):
            for key, value in vars(base).items():
                if isinstance(value, (Scalar, Strings, Array)):
                    specs[key] = type(value)(**{**value.__dict__, "name": key})
        if not cls.type_name:
            cls.type_name = cls.__name__
        cls._info = _TypeInfo(
            name=cls.type_name,
            version=cls.version,
            scalars=tuple(s for s in specs.values() if isinstance(s, Scalar)),
            strings=tuple(s for s in specs.values() if isinstance(s, Strings)),
            arrays=tuple(s for s in specs.values() if isinstance(s, Array)),
            fields=specs,
            latched=cls.latched_by_default,
        )
        for key in specs:
            # Instance attributes shadow the declarations; keep class-level access to specs.
            setattr(cls, key, _FieldDescriptor(key, specs[key]))
        if "__init__" not in vars(cls) and not any(k == "self" or k.startswith("_") for k in specs):
            cls.__init__ = _field_by_field_init(cls._info)   # (else the generic one: names it could clash with)
        from .registry import register

        register(cls)

    def __init__(self, **values: Any) -> None:
        info = self._info
        unknown = values.keys() - info.fields.keys()
        if unknown:
            raise MessageError(f"{info.name} has no field(s) {sorted(unknown)}")
        d = self.__dict__
        for spec in info.scalars:
            d[spec.name] = spec.coerce(values[spec.name]) if spec.name in values else spec.default
        for spec in info.strings:
            d[spec.name] = spec.coerce(values[spec.name]) if spec.name in values else []
        for spec in info.arrays:
            d[spec.name] = spec.coerce(values[spec.name]) if spec.name in values else spec.empty()

    def __setattr__(self, name: str, value: Any) -> None:
        spec = self._info.fields.get(name)
        if spec is None:
            object.__setattr__(self, name, value)
        elif type(value) is _FAST_SCALAR.get(getattr(spec, "kind", None)):   # (a scalar of its own type: kept)
            self.__dict__[name] = value
        else:   # a field keeps its declared type, as the constructor makes it
            self.__dict__[name] = spec.coerce(value)

    @classmethod
    def fields(cls) -> dict[str, FieldSpec]:
        """The declared fields by name, in declaration order."""
        return dict(cls._info.fields)

    def to_dict(self) -> dict[str, Any]:
        """Plain-Python view (arrays as nested lists) for JSON, echo and the web viewer."""
        out: dict[str, Any] = {}
        for name, spec in self._info.fields.items():
            v = getattr(self, name)
            out[name] = v.tolist() if isinstance(spec, Array) else v
        return out

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        for name, spec in self._info.fields.items():
            a, b = getattr(self, name), getattr(other, name)
            if isinstance(spec, Array):
                if a.shape != b.shape or not np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
                    return False
            elif a != b:
                return False
        return True

    def __repr__(self) -> str:
        parts = []
        for name, spec in self._info.fields.items():
            v = getattr(self, name)
            parts.append(f"{name}={'array' + str(v.shape) if isinstance(spec, Array) else repr(v)}")
        return f"{self._info.name}({', '.join(parts)})"

    @classmethod
    def json_schema(cls) -> dict:
        """JSON Schema of this type (stored in bags so another tool can read them)."""
        info = cls._info
        return {
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": info.name,
            "description": (cls.__doc__ or "").strip(),
            "type": "object",
            "x-mocapgraph-version": info.version,
            "x-field-block": info.field_block(),
            "properties": {k: s.json_schema() for k, s in info.fields.items()},
        }


_MISSING = object()
_FAST_SCALAR = {"int": int, "float": float, "str": str, "bool": bool}


def _field_by_field_init(info: _TypeInfo):
    """``Message.__init__`` for one type written out field by field, as dataclasses writes its
    constructors: a value that already has its declared type (a Python scalar of the kind, a
    C-contiguous array of the dtype, rank and fixed sizes) is stored after one inline check, any
    other goes through its field's ``coerce`` (so the result is the generic constructor's). A frame
    message is built per frame on the hot path: the generic loop costs several us more."""
    env: dict[str, Any] = {"_MISSING": _MISSING, "_ndarray": np.ndarray, "_info": info, "_type": type,
                           "_unknown_fields": _unknown_fields}   # (a field may be called ``type``)
    names = [f.name for f in (*info.scalars, *info.strings, *info.arrays)]
    body = ["    if _unknown:", "        _unknown_fields(_info, _unknown)", "    _sd = self.__dict__"]
    for f in info.scalars:
        n = f.name
        env[f"_c_{n}"], env[f"_t_{n}"], env[f"_d_{n}"] = f.coerce, _FAST_SCALAR[f.kind], f.default
        body.append(f"    _sd[{n!r}] = _d_{n} if {n} is _MISSING else {n} if _type({n}) is _t_{n} else _c_{n}({n})")
    for f in info.strings:   # always copied: the message owns its list
        n = f.name
        env[f"_c_{n}"] = f.coerce
        body.append(f"    _sd[{n!r}] = [] if {n} is _MISSING else _c_{n}({n})")
    for f in info.arrays:
        n = f.name
        dt, rank, fixed = f._fast
        env[f"_c_{n}"], env[f"_dt_{n}"], env[f"_e_{n}"] = f.coerce, dt, f.empty
        sizes = "".join(f" and {n}.shape[{i}] == {size}" for i, size in fixed)
        body.append(f"    _sd[{n!r}] = _e_{n}() if {n} is _MISSING else {n} if (_type({n}) is _ndarray and "
                    f"{n}.dtype is _dt_{n} and {n}.ndim == {rank}{sizes} and {n}.flags.c_contiguous) "
                    f"else _c_{n}({n})")
    args = "".join(f"{n}=_MISSING, " for n in names)
    src = f"def __init__(self, *, {args}**_unknown):\n" + "\n".join(body) + "\n"
    exec(compile(src, f"<{info.name}.__init__>", "exec"), env)   # noqa: S102 (our own field names)
    init = env["__init__"]
    init.__doc__ = f"A {info.name} from its fields by name (missing ones take their defaults)."
    return init


def _unknown_fields(info: _TypeInfo, unknown: dict) -> None:
    raise MessageError(f"{info.name} has no field(s) {sorted(unknown)}")


class _FieldDescriptor:
    """Class-level access returns the spec; instances store values in __dict__, which a read finds
    first (a non-data descriptor: a field read is a dict lookup, no Python call; a frame's handler
    reads several). Writes go through ``Message.__setattr__``, which coerces."""

    def __init__(self, name: str, spec: FieldSpec) -> None:
        self.name = name
        self.spec = spec

    def __get__(self, obj: Any, owner: type) -> Any:
        if obj is None:
            return self.spec
        try:
            return obj.__dict__[self.name]
        except KeyError:
            raise AttributeError(self.name) from None
