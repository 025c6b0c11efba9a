"""Registry of message types by type name (the name written into every header and bag).

It imports nothing of ours: a `Message` subclass registers itself when it is defined, and the
built-in types are defined when the package loads (``messages/__init__`` imports ``types``), which
is before any of its modules can be used.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .schema import Message

_TYPES: dict[str, type["Message"]] = {}


class UnknownTypeError(KeyError):
    """A type name that no registered message type carries."""

    def __str__(self) -> str:
        return f"unknown message type {self.args[0]!r}"


def register(cls: type["Message"]) -> None:
    """Add a message type; a second type with the same name is a programming error."""
    existing = _TYPES.get(cls.type_name)
    if existing is not None and existing is not cls and existing.__module__ != cls.__module__:
        raise ValueError(f"message type name {cls.type_name!r} is used twice")
    _TYPES[cls.type_name] = cls


def lookup(type_name: str) -> type["Message"]:
    """The message class registered under ``type_name``."""
    try:
        return _TYPES[type_name]
    except KeyError:
        raise UnknownTypeError(type_name) from None


def all_types() -> dict[str, type["Message"]]:
    """Every registered type by name."""
    return dict(_TYPES)
