"""OSC bundles of per-joint messages: built once with python-osc as a template, filled per frame with numpy.

Addresses, for a stream ``<name>`` (actor, character or skeleton source) under ``/<prefix>``::

    /<prefix>/<kind>/<name>/frame              i        source frame number
    /<prefix>/<kind>/<name>/<joint>/position   f f f    metres, world frame (Z up, X forward)
    /<prefix>/<kind>/<name>/<joint>/rotation   f f f f  quaternion w, x, y, z
    /<prefix>/<kind>/<name>/<joint>/quality    i        0 missing, 1 estimated, 2 good

``kind`` is ``actor``, ``character`` or ``skeleton``, so an actor and the character it drives
may share a name.

A frame is one bundle (time tag = capture time), so a receiver sees every joint of one instant
together. A missing position or rotation (NaN) is left out of the bundle unless ``send_missing`` asks for NaN;
their quality message is always there. OSC big-endian float32 and int32 throughout.
"""
from __future__ import annotations

import re

import numpy as np
from pythonosc.osc_bundle_builder import OscBundleBuilder
from pythonosc.osc_message import OscMessage
from pythonosc.osc_message_builder import OscMessageBuilder

_FORBIDDEN = re.compile(r"[\s#*,/?\[\]{}]")
_NTP_EPOCH = 2208988800  # seconds from 1900-01-01 (NTP) to 1970-01-01 (Unix)


def address_part(name: str) -> str:
    """A name usable as one OSC address part (characters OSC reserves become '_')."""
    return _FORBIDDEN.sub("_", name) or "_"


def _message(address: str, tags: str) -> OscMessage:
    b = OscMessageBuilder(address)
    for t in tags:
        b.add_arg(0.0 if t == "f" else 0, t)
    return b.build()


class JointBundle:
    """The bundle template of one stream: ``encode(frame, positions[J,3], rotations[J,4], quality[J], t_s)``."""

    def __init__(self, prefix: str, kind: str, name: str, joints: list[str], send_missing: bool = False) -> None:
        base = f"/{address_part(prefix)}/{address_part(kind)}/{address_part(name)}"
        self.joints = list(joints)
        self.send_missing = send_missing
        self.addresses = {"frame": f"{base}/frame"}
        parts: list[OscMessage] = []
        kinds: list[tuple[str, int]] = []  # (kind, joint) of each element
        parts.append(_message(self.addresses["frame"], "i"))
        kinds.append(("frame", -1))
        for j, joint in enumerate(joints):
            jb = f"{base}/{address_part(joint)}"
            for kind, tags in (("position", "fff"), ("rotation", "ffff"), ("quality", "i")):
                parts.append(_message(f"{jb}/{kind}", tags))
                kinds.append((kind, j))
        # One bundle with every element; python-osc lays out header, time tag and sizes.
        bb = OscBundleBuilder(0)
        for p in parts:
            bb.add_content(p)
        whole = bb.build().dgram
        self.template = np.frombuffer(whole, np.uint8).copy()
        # Byte spans of each element (its int32 size prefix included) and of its argument values.
        pos = 16
        starts, ends = [], []
        slots: dict[str, list[int]] = {"position": [], "rotation": [], "quality": [], "frame": []}
        for p, (kind, _j) in zip(parts, kinds):
            starts.append(pos)
            pos += 4 + p.size
            ends.append(pos)
            n_args = {"position": 3, "rotation": 4, "quality": 1, "frame": 1}[kind]
            slots[kind].append(pos - 4 * n_args)
        assert pos == len(whole)
        four = np.arange(4)
        self._pos = (np.asarray(slots["position"])[:, None] + np.arange(12)).ravel()
        self._rot = (np.asarray(slots["rotation"])[:, None] + np.arange(16)).ravel()
        self._q = (np.asarray(slots["quality"])[:, None] + four).ravel()
        self._frame = slots["frame"][0] + four
        self._starts = np.asarray(starts)
        self._lengths = np.asarray(ends) - self._starts
        self._kind_joint = np.array([j for _k, j in kinds])
        self._is_pos = np.array([k == "position" for k, _j in kinds])
        self._is_rot = np.array([k == "rotation" for k, _j in kinds])

    def encode(self, frame: int, positions: np.ndarray, rotations: np.ndarray | None, quality: np.ndarray,
               t_s: float) -> bytes:
        """One bundle; rotations None (a source without them) sends no rotation messages."""
        J = len(self.joints)
        buf = self.template.copy()
        secs = t_s + _NTP_EPOCH
        buf[8:16] = np.frombuffer(np.array([int(secs), int((secs % 1) * 2**32)], ">u4").tobytes(), np.uint8)
        buf[self._frame] = np.frombuffer(np.array(frame, ">i4").tobytes(), np.uint8)
        buf[self._pos] = np.ascontiguousarray(positions, ">f4").view(np.uint8).ravel()
        rot = np.full((J, 4), np.nan) if rotations is None else rotations
        buf[self._rot] = np.ascontiguousarray(rot, ">f4").view(np.uint8).ravel()
        buf[self._q] = np.ascontiguousarray(quality, ">i4").view(np.uint8).ravel()
        if self.send_missing:
            return buf.tobytes()
        ok_pos = np.isfinite(positions).all(-1)
        ok_rot = np.isfinite(rot).all(-1)
        if ok_pos.all() and ok_rot.all():
            return buf.tobytes()
        j = np.maximum(self._kind_joint, 0)
        keep = np.where(self._is_pos, ok_pos[j], np.where(self._is_rot, ok_rot[j], True))
        # Bytes of the kept elements: the 16-byte header, then each kept element whole.
        starts, lengths = self._starts[keep], self._lengths[keep]
        idx = np.repeat(starts - np.cumsum(np.r_[0, lengths[:-1]]), lengths) + np.arange(lengths.sum())
        return buf[:16].tobytes() + buf[idx].tobytes()

