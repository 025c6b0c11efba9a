"""What a node declares: inputs, outputs and typed parameters.

These are class attributes on a `Node` subclass; the runtime binds them to sockets. The launcher
reads the same declarations to check a graph before any process starts.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ..messages import Message

#: "file" is a str naming an input file: the graph check resolves it and refuses a missing or
#: unreadable one (mocapgraph.bus.input_files); "" means "not given" unless ``required``
PARAM_KINDS = ("bool", "int", "float", "str", "list", "dict", "file")


class ParamError(ValueError):
    """A parameter value of the wrong type or out of range."""


def _kind_of(value: Any) -> str:
    for kind, py in (("bool", bool), ("int", int), ("float", float), ("str", str), ("list", list), ("dict", dict)):
        if isinstance(value, py):
            return kind
    raise TypeError(f"parameter default {value!r} is not bool, int, float, str, list or dict")


@dataclass(frozen=True)
class Param:
    """A typed parameter with a default, a doc line (give units) and optional bounds/choices.

    required: for kind "file", an empty value is an error of the graph check.
    """

    default: Any
    doc: str
    kind: str = ""
    choices: tuple[Any, ...] | None = None
    minimum: float | None = None
    maximum: float | None = None
    name: str = ""
    required: bool = False

    def __post_init__(self) -> None:
        if not self.kind:
            object.__setattr__(self, "kind", _kind_of(self.default) if self.default is not None else "str")
        if self.kind not in PARAM_KINDS:
            raise TypeError(f"unknown parameter kind {self.kind!r}")

    def check(self, value: Any) -> Any:
        """The value converted to this parameter's kind, or ParamError saying what is wrong."""
        if value is None and self.default is None:
            return None
        k = self.kind
        ok = (
            (k == "bool" and isinstance(value, bool))
            or (k == "int" and isinstance(value, int) and not isinstance(value, bool))
            or (k == "float" and isinstance(value, (int, float)) and not isinstance(value, bool))
            or (k in ("str", "file") and isinstance(value, str))
            or (k == "list" and isinstance(value, list))
            or (k == "dict" and isinstance(value, dict))
        )
        if not ok:
            raise ParamError(f"wants {k}, got {type(value).__name__} {value!r}")
        if k == "float":
            value = float(value)
            if not math.isfinite(value):  # .nan / .inf pass every bound check and then misbehave (inf: a busy loop)
                raise ParamError(f"wants a finite number, got {value!r}")
        if self.choices is not None and value not in self.choices:
            raise ParamError(f"{value!r} is not one of {list(self.choices)}")
        if self.minimum is not None and value < self.minimum:
            raise ParamError(f"{value!r} is below the minimum {self.minimum}")
        if self.maximum is not None and value > self.maximum:
            raise ParamError(f"{value!r} is above the maximum {self.maximum}")
        return value

    def __get__(self, obj: Any, owner: type) -> Any:
        if obj is None:
            return self
        return obj.params[self.name]

    def __set_name__(self, owner: type, name: str) -> None:
        object.__setattr__(self, "name", name)


class _PortDeclaration:
    """Class-level access gives the declaration; instance access the node's bound port."""

    name: str

    def __set_name__(self, owner: type, name: str) -> None:
        object.__setattr__(self, "name", name)

    def __get__(self, obj: Any, owner: type) -> Any:
        if obj is None:
            return self
        return obj._ports[self.name]


@dataclass(frozen=True)
class Input(_PortDeclaration):
    """A subscription. ``msg_type`` None takes any type (recorders, viewers).

    queue: messages buffered by the socket before new ones are dropped (and counted as gaps).
    latest_only: deliver only the newest message per loop turn (viewers).
    required: the graph check fails when no node publishes the topic.
    raw: the handler gets ``(envelope, frames)`` without decoding the payload (recorders).
    """

    topic: str
    msg_type: type[Message] | None
    doc: str = ""
    latched: bool = False
    queue: int = 1000
    latest_only: bool = False
    required: bool = True
    raw: bool = False
    name: str = ""

    @classmethod
    def optional(cls, topic: str, msg_type: type[Message], doc: str, *, queue: int,
                 latched: bool = False) -> "Input":
        """A subscription the graph may leave unpublished (viewers, bridges draw what there is)."""
        return cls(topic, msg_type, doc, latched=latched, queue=queue, required=False)

    @property
    def type_name(self) -> str:
        return self.msg_type.type_name if self.msg_type else "*"


@dataclass(frozen=True)
class Output(_PortDeclaration):
    """A publication. Latched outputs resend their last value to every late subscriber."""

    topic: str
    msg_type: type[Message]
    doc: str = ""
    latched: bool | None = None
    name: str = ""

    @property
    def is_latched(self) -> bool:
        return self.msg_type.latched_by_default if self.latched is None else self.latched

    @property
    def type_name(self) -> str:
        return self.msg_type.type_name


@dataclass
class Interface:
    """A node type's declared ports and parameters (possibly shaped by its parameter values)."""

    inputs: dict[str, Input] = field(default_factory=dict)
    outputs: dict[str, Output] = field(default_factory=dict)
    params: dict[str, Param] = field(default_factory=dict)


def declared_interface(cls: type) -> Interface:
    """The Input/Output/Param class attributes of a node class and its bases (a subclass's win)."""
    iface = Interface()
    for klass in reversed(cls.__mro__):
        for key, value in vars(klass).items():
            if isinstance(value, Input):
                iface.inputs[key] = value
            elif isinstance(value, Output):
                iface.outputs[key] = value
            elif isinstance(value, Param):
                iface.params[key] = value
    return iface
