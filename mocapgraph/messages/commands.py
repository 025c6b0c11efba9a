"""Node commands: which NodeCommand names each commandable node takes (calibration, bag player, retargeter, physics tracker), the viewer's share, and their args.

Written once here; the calibration node and the bag player dispatch exactly these, and the viewer
server forwards only the subset its buttons send (a browser can ask for nothing else). A
command's ``args_json`` is a JSON object (empty: ``{}``), read by :func:`parse_command`.
"""
from __future__ import annotations

from typing import Any, Sequence

from .bounded_json import loads_bounded

#: a command's args are a small object: a few names and numbers, a path
MAX_ARGS_BYTES = 64 * 1024
MAX_ARGS_DEPTH = 8

CALIBRATION_COMMANDS = ("find_base_pose", "capture_gym", "process", "reset", "save", "load")
PLAYER_COMMANDS = ("play", "pause", "toggle", "step", "seek", "rate", "stop")
RETARGET_COMMANDS = ("capture_rest_pose", "reset")
PHYSICS_COMMANDS = ("push", "shoot", "hold", "drop", "dodge", "reach", "release", "reset")

#: channel -> commands the viewer page may send (buttons); a subset of the nodes' own lists
VIEWER_COMMANDS: dict[str, tuple[str, ...]] = {
    "calibration": ("find_base_pose", "capture_gym", "process"),
    "player": ("play", "pause", "step", "seek"),
}

assert set(VIEWER_COMMANDS["calibration"]) <= set(CALIBRATION_COMMANDS)
assert set(VIEWER_COMMANDS["player"]) <= set(PLAYER_COMMANDS)


def parse_command(command: str, args_json: str, allowed: Sequence[str]) -> dict[str, Any]:
    """The args of a NodeCommand named ``command`` as a dict; ValueError (one line) when the
    args are not a JSON object (of at most MAX_ARGS_BYTES, nested at most MAX_ARGS_DEPTH, checked
    before parsing) or the command is not one of ``allowed``."""
    try:
        args = loads_bounded(args_json or "{}", MAX_ARGS_BYTES, MAX_ARGS_DEPTH)
    except ValueError as exc:
        raise ValueError(f"command {command!r}: bad args_json ({exc})") from None
    if not isinstance(args, dict):
        raise ValueError(f"command {command!r}: bad args_json (not a JSON object)")
    if command not in allowed:
        raise ValueError(f"unknown command {command!r} (expected one of {', '.join(allowed)})")
    return args
