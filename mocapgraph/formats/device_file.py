"""Device configurations (``graph_configs/devices/*.yaml``): where a device sits in the world and
what its channels are.

A device file::

    name: lab_serial_bridge            # required
    description: free text             # optional
    rate_hz: 240                       # optional nominal frame rate, Hz (0 or absent: measured)
    units: mm                          # optional: units of positions the device sends (LSL only;
                                       #   the serial/UDP wire protocol is millimetres by definition)
    to_world:                          # optional; default: the device frame IS the world frame
      up: "+Y"                         #   device axis pointing up in the room (becomes world +Z)
      forward: "+Z"                    #   device axis pointing forward (becomes world +X)
      yaw_deg: 0                       #   then a turn about world Z, degrees
      translation_m: [0, 0, 0]         #   device origin in the world, metres
    channels: [LASI, RASI, ...]        # optional: marker label of each device channel, wire order
                                       #   (skeleton sources ignore it)

A point seen by the device maps to the world as ``p_world = R @ p_device + t`` with
``R = Rz(yaw) @ axes(up, forward)`` (column vectors) and ``t = translation_m``; orientations as
``q_world = q_R * q_device``. Errors are one line naming the file, line and key.

A reader's ``up_axis`` param (:meth:`DeviceConfig.with_up_axis`) names the device axis that
points up when the file does not: it stands in for ``to_world.up`` (forward: the file's
``to_world.forward``, else +X, or +Y when X is up; yaw and translation still apply after). A file
whose own ``to_world.up`` differs is refused in one line: two answers to one question.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .axes import axis_name, default_forward, describe_rotation, parse_axis, to_world_rotation, up_option
from .yaml_source import GraphError, LinedDict, load_yaml_file

DEVICE_DIR = Path(__file__).resolve().parents[2] / "graph_configs" / "devices"
UNITS_TO_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
TOP_KEYS = ("name", "description", "rate_hz", "units", "to_world", "channels")
WORLD_KEYS = ("up", "forward", "yaw_deg", "translation_m")


class DeviceConfigError(ValueError):
    """A device configuration that cannot be used (one line: file, line, key, fault)."""


@dataclass
class DeviceConfig:
    """A device's pose in the world and its channel labels."""

    name: str = "device"
    description: str = ""
    rate_hz: float = 0.0
    units: str = "m"
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # world = R @ device
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))  # m, world
    channels: list[str] = field(default_factory=list)
    source: str = "<default>"
    up: str = ""              # the file's own to_world.up ("+Y" style), '' when not given
    up_where: str = ""        # "file:line" of that key, for errors
    forward: str = ""         # the file's own to_world.forward, '' when not given
    yaw_deg: float = 0.0
    up_from_reader: str = ""  # the reader's up_axis when it set the up axis

    @property
    def is_identity(self) -> bool:
        return bool(np.array_equal(self.rotation, np.eye(3)) and not self.translation.any())

    @property
    def scale(self) -> float:
        """Metres per device unit."""
        return UNITS_TO_M[self.units]

    def points_to_world(self, p: np.ndarray) -> np.ndarray:
        """Device points [..., 3] (metres) to world [..., 3]; NaN stays NaN."""
        if self.is_identity:
            return p
        return p @ self.rotation.T + self.translation

    def points_from_world(self, p: np.ndarray) -> np.ndarray:
        """World points [..., 3] (metres) to the device frame (the inverse of points_to_world)."""
        if self.is_identity:
            return p
        return (p - self.translation) @ self.rotation

    def quats_to_world(self, q: np.ndarray) -> np.ndarray:
        """Device orientations [..., 4] wxyz to world; NaN rows stay NaN."""
        if np.array_equal(self.rotation, np.eye(3)):
            return q
        flat = q.reshape(-1, 4)
        out = np.full_like(flat, np.nan)
        ok = np.isfinite(flat).all(axis=1)
        if ok.any():
            from scipy.spatial.transform import Rotation   # (see _parse_world)
            r = Rotation.from_matrix(self.rotation) * Rotation.from_quat(flat[ok], scalar_first=True)
            out[ok] = r.as_quat(scalar_first=True)
        return out.reshape(q.shape)

    def describe(self) -> str:
        """What the transform does, for MarkerLayout.units_note / SkeletonInfo.units_note."""
        if self.is_identity:
            return f"device '{self.name}': device frame taken as the world frame"
        t = ", ".join(f"{v:g}" for v in self.translation)
        why = f" (up axis {self.up_from_reader} from the reader's up_axis)" if self.up_from_reader else ""
        return f"device '{self.name}'{why}: {describe_rotation(self.rotation)}, then origin moved to ({t}) m"

    def with_up_axis(self, up_axis: str | None) -> "DeviceConfig":
        """This device with a reader's ``up_axis`` ("auto"/''/None: unchanged; else "y", "-Z"...)
        as its up axis (see the module doc). DeviceConfigError (one line) when the file's own
        ``to_world.up`` differs, or the file's forward is not perpendicular to it."""
        try:
            up = up_option(up_axis)
        except ValueError as exc:
            raise DeviceConfigError(f"up_axis: {exc}") from None
        if up is None or up == self.up:
            return self
        if self.up:
            raise DeviceConfigError(
                f"{self.up_where}: to_world.up: the device file says {self.up!r} but the reader's "
                f"up_axis is {up_axis!r}: set only one (up_axis: auto takes the file's)")
        forward = self.forward or default_forward(up)
        try:
            R = to_world_rotation(up, forward)
        except ValueError as exc:
            raise DeviceConfigError(f"{self.source}: to_world.forward: with the reader's up_axis "
                                    f"{up_axis!r}: {exc}") from None
        from scipy.spatial.transform import Rotation   # (see _parse_world)
        R = Rotation.from_euler("z", self.yaw_deg, degrees=True).as_matrix() @ R
        R[np.abs(R) < 1e-15] = 0.0
        return replace(self, rotation=R, up_from_reader=up)


def device_path(name_or_path: str | Path) -> Path:
    """A device name under graph_configs/devices, or a path to a YAML file."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p
    return DEVICE_DIR / f"{name_or_path}.yaml"


def _fail(d: LinedDict | None, file: Path, key: str, msg: str) -> DeviceConfigError:
    line = d.line_of(key.split(".")[-1]) if isinstance(d, LinedDict) else None
    return DeviceConfigError(str(GraphError(file, line, key, msg)))


def load_device_config(name_or_path: str | Path) -> DeviceConfig:
    """Read and check a device file; DeviceConfigError names file, line and key."""
    path = device_path(name_or_path)
    if not path.is_file():
        raise DeviceConfigError(f"{path}: no such device configuration "
                                f"(a name under {DEVICE_DIR} or a path to a .yaml file)")
    try:
        doc = load_yaml_file(path)
    except GraphError as exc:
        raise DeviceConfigError(str(exc)) from None
    if not isinstance(doc, dict) or "name" not in doc:
        raise DeviceConfigError(f"{path}: a device configuration is a mapping with at least 'name'")
    for key in doc:
        if key not in TOP_KEYS:
            raise _fail(doc, path, str(key), f"unknown key (expected one of {', '.join(TOP_KEYS)})")
    cfg = DeviceConfig(name=str(doc["name"]), description=str(doc.get("description", "")), source=str(path))
    rate = doc.get("rate_hz", 0)
    if not _finite(rate) or rate < 0:  # (.nan passes every comparison; .inf: frames 0 s apart)
        raise _fail(doc, path, "rate_hz", f"wants a finite rate in Hz >= 0, got {rate!r}")
    cfg.rate_hz = float(rate)
    units = str(doc.get("units", "m"))
    if units not in UNITS_TO_M:
        raise _fail(doc, path, "units", f"{units!r} is not one of {list(UNITS_TO_M)}")
    cfg.units = units
    chans = doc.get("channels", [])
    if not isinstance(chans, list) or not all(isinstance(c, str) and c.strip() for c in chans):
        raise _fail(doc, path, "channels", "wants a list of marker labels")
    if len({c.strip().lower() for c in chans}) != len(chans):
        raise _fail(doc, path, "channels", "labels must be unique")
    cfg.channels = [c.strip() for c in chans]
    world = doc.get("to_world")
    if world is not None:
        cfg.rotation, cfg.translation = _parse_world(world, path, doc)
        for key in ("up", "forward"):  # what the file itself says, for a reader's up_axis
            if world.get(key) is not None and str(world[key]).strip():
                setattr(cfg, key, axis_name(parse_axis(str(world[key]))))
        cfg.up_where = f"{path}:{world.line_of('up')}" if isinstance(world, LinedDict) else str(path)
        cfg.yaw_deg = float(world.get("yaw_deg", 0.0))
    return cfg


def _parse_world(world: Any, path: Path, doc: LinedDict) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(world, dict):
        raise _fail(doc, path, "to_world", "wants a mapping with up, forward, yaw_deg, translation_m")
    for key in world:
        if key not in WORLD_KEYS:
            raise _fail(world, path, f"to_world.{key}", f"unknown key (expected one of {', '.join(WORLD_KEYS)})")
    try:
        R = to_world_rotation(str(world.get("up", "+Z")), str(world.get("forward", "+X")))
    except ValueError as exc:
        raise _fail(world, path, "to_world.up", str(exc)) from None
    yaw = world.get("yaw_deg", 0.0)
    if not _finite(yaw):   # .nan would turn every marker into NaN
        raise _fail(world, path, "to_world.yaw_deg", f"wants a finite angle in degrees, got {yaw!r}")
    # scipy (a third of a second to import) only for a device that is turned: every marker reader
    # imports this module for its errors, most never turn. A node turning one imports it here,
    # building its config, so quats_to_world never imports it on a frame.
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("z", float(yaw), degrees=True).as_matrix() @ R
    R[np.abs(R) < 1e-15] = 0.0
    t = world.get("translation_m", [0.0, 0.0, 0.0])
    if not isinstance(t, list) or len(t) != 3 or not all(_finite(v) for v in t):
        raise _fail(world, path, "to_world.translation_m", f"wants [x, y, z], finite, in metres, got {t!r}")
    return R, np.asarray(t, dtype=np.float64)


def _finite(v: Any) -> bool:
    """A real number that is not NaN or infinite (YAML's .nan and .inf are floats)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def device_or_default(name_or_path: str, up_axis: str | None = None) -> DeviceConfig:
    """The named device configuration, or the identity device for "", with a reader's
    ``up_axis`` applied (:meth:`DeviceConfig.with_up_axis`)."""
    dev = load_device_config(name_or_path) if name_or_path else DeviceConfig()
    return dev.with_up_axis(up_axis)
