"""The command whitelist: which NodeCommand names each commandable node takes (calibration, bag player, retargeter, physics tracker), and the viewer's share.

Written once here; the calibration node and the bag player dispatch exactly these, and the viewer
server forwards only the subset its buttons send (a browser can ask for nothing else).
"""
from __future__ import annotations

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
