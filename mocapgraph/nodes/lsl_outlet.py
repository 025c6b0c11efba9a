"""LabStreamingLayer outlet node (pylsl): markers, joint centres and character poses as LSL streams.

So that LabRecorder records them time-synchronised with EEG, EMG or eye tracking. One stream per
source: ``<prefix>Markers`` (per marker X, Y, Z), ``<prefix>Joints_<actor>`` (per joint X, Y, Z and
a quality code 0 missing / 1 estimated / 2 good), ``<prefix>Character_<name>`` (per joint world
X, Y, Z, the local rotation W, X, Y, Z and a quality code). Channel format double64; positions in metres,
world frame Z up X forward; NaN where missing. Every channel carries ``label``, ``type``
(``PositionX``..., ``OrientationW``..., ``Quality``), ``unit`` and the ``marker``/``joint`` it
belongs to, following the XDF mocap meta-data; the description also has ``setup/markers`` (or
``joints``), ``acquisition`` and ``reference`` (frame and units). Sample stamps are the
capture stamps on LSL's clock, so the recording lines up with the other devices.

A stream is created once its names are known (the latched MarkerLayout, SkeletonModel or
CharacterInfo); frames that arrive before are held (bounded) and sent in order once it is.
"""
from __future__ import annotations

import time
from collections import deque
from typing import Any

import numpy as np
import pylsl

from ..bus import Input, Node, Param
from ..messages import ActorPose, CharacterInfo, CharacterPose, MarkerFrame, MarkerLayout, SkeletonModel
from ..messages.codec import Envelope
from ..messages.pose_quality import character_quality

HOLD = 2000  # frames per stream held while its names are not yet known
AXES = ("X", "Y", "Z")
QUAT = ("W", "X", "Y", "Z")


def _channels(info: pylsl.StreamInfo, channels: list[dict[str, str]]) -> None:
    chans = info.desc().append_child("channels")
    for ch in channels:
        c = chans.append_child("channel")
        for k, v in ch.items():
            c.append_child_value(k, v)


def _position_channels(names: list[str], kind: str) -> list[dict[str, str]]:
    return [{"label": f"{n}_{a}", kind: n, "type": f"Position{a}", "unit": "meters"} for n in names for a in AXES]


def stream_info(name: str, kind: str, rate_hz: float, source_id: str, channels: list[dict[str, str]],
                setup: tuple[str, str, list[str]], note: str) -> pylsl.StreamInfo:
    """A described StreamInfo: channels, setup/<group>/<item>/label, acquisition and reference."""
    info = pylsl.StreamInfo(name, kind, len(channels), rate_hz, "double64", source_id)
    _channels(info, channels)
    group, item, labels = setup
    g = info.desc().append_child("setup").append_child(group)
    for lab in labels:
        g.append_child(item).append_child_value("label", lab)
    acq = info.desc().append_child("acquisition")
    acq.append_child_value("manufacturer", "mocapgraph")
    acq.append_child_value("model", note)
    ref = info.desc().append_child("reference")
    ref.append_child_value("frame", "world: right-handed, Z up, X forward")
    ref.append_child_value("units", "positions in meters; rotations as unit quaternions (w, x, y, z)")
    ref.append_child_value("missing", "NaN")
    return info


class _Stream:
    """One outlet, or the frames waiting for the names that let it be described."""

    def __init__(self) -> None:
        self.outlet: pylsl.StreamOutlet | None = None
        self.held: deque[tuple[np.ndarray, float]] = deque(maxlen=HOLD)
        self.n_values = 0
        self.sent = 0


class LSLOutlet(Node):
    """Publishes markers, joint centres and character poses as described LSL streams."""

    summary = "LabStreamingLayer outlets for markers, joint centres and character poses (labels, units)"

    markers = Input("markers", MarkerFrame, "labelled markers", required=False, queue=5000)
    marker_layout = Input("marker_layout", MarkerLayout, "marker labels", latched=True, required=False)
    actor_pose = Input("actor_pose", ActorPose, "solved actors (one stream per actor)", required=False,
                       queue=5000)
    skeleton_model = Input("skeleton_model", SkeletonModel, "joint names of the actors", latched=True,
                           required=False)
    character_pose = Input("character_pose", CharacterPose, "retargeted characters (one stream each)",
                           required=False, queue=5000)
    character_info = Input("character_info", CharacterInfo, "character joint names", latched=True,
                           required=False)

    prefix = Param("mocapgraph", "stream name prefix (streams: <prefix>Markers, <prefix>Joints_<actor>, ...)")
    stream_type = Param("Mocap", "LSL content type of every stream")
    rate_hz = Param(0.0, "nominal rate announced, Hz; 0 takes the markers' rate_hz (irregular if unknown)",
                    minimum=0.0)

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring: Any = None) -> None:
        super().__init__(name, params, wiring)
        self.streams: dict[str, _Stream] = {}
        self.layout: MarkerLayout | None = None
        self.models: list[SkeletonModel] = []
        self.characters: dict[str, CharacterInfo] = {}
        self._rate = float(self.rate_hz)
        self._warned: dict[str, float] = {}
        # LSL clock = wall clock - offset (both tick at the same rate); capture stamps are wall ns
        self._wall_minus_lsl = time.time() - pylsl.local_clock()

    # ----- names ---------------------------------------------------------------------------------
    def on_marker_layout(self, msg: MarkerLayout) -> None:
        if self.layout is not None and self.layout.labels != msg.labels:
            self._drop("markers")  # a new layout is a new stream: LabRecorder sees the change
        self.layout = msg
        self._flush("markers")

    def on_skeleton_model(self, msg: SkeletonModel) -> None:
        J = len(msg.joint_names)
        old = next((m for m in self.models if len(m.joint_names) == J), None)
        if old is not None and old.joint_names != msg.joint_names:
            for key in [k for k, st in self.streams.items() if k.startswith("joints/") and st.n_values == 4 * J]:
                self._drop(key)  # same size, other joints: a new stream, not relabelled samples
        self.models = [m for m in self.models if len(m.joint_names) != J] + [msg]
        for key in [k for k in self.streams if k.startswith("joints/")]:
            self._flush(key)

    def on_character_info(self, msg: CharacterInfo) -> None:
        old = self.characters.get(msg.character)
        if old is not None and old.joint_names != msg.joint_names:
            self._drop(f"character/{msg.character}")
        self.characters[msg.character] = msg
        self._flush(f"character/{msg.character}")

    # ----- frames ---------------------------------------------------------------------------------
    def on_markers(self, msg: MarkerFrame) -> None:
        if not self._rate and msg.rate_hz > 0:
            self._rate = float(msg.rate_hz)
        self._send("markers", msg.positions.ravel(), self._env("markers"))

    def on_actor_pose(self, msg: ActorPose) -> None:
        sample = np.concatenate([msg.joint_positions, msg.joint_quality[:, None].astype(float)], axis=1).ravel()
        self._send(f"joints/{msg.actor}", sample, self._env("actor_pose"))

    def on_character_pose(self, msg: CharacterPose) -> None:
        q = character_quality(msg).astype(float)[:, None]
        sample = np.concatenate([msg.joint_positions, msg.local_rotations, q], axis=1).ravel()
        self._send(f"character/{msg.character}", sample, self._env("character_pose"))

    def _env(self, port: str) -> Envelope:
        return self._ports[port].envelope

    def _warn(self, key: str, message: str, *args: Any) -> None:
        """Log ``message`` at most once per 5 s per ``key`` (a per-frame fault must not flood the log)."""
        now = time.monotonic()
        if now - self._warned.get(key, -1e9) >= 5.0:
            self._warned[key] = now
            self.log.warning(message, *args)

    def _send(self, key: str, sample: np.ndarray, env: Envelope) -> None:
        st = self.streams.get(key)
        if st is None:
            st = self.streams[key] = _Stream()
        stamp = env.capture_ns * 1e-9 - self._wall_minus_lsl
        if st.outlet is not None and st.n_values != len(sample):
            self._drop(key)  # the source changed shape (another layout or model): describe it anew
            st = self.streams[key] = _Stream()
        if st.outlet is None:
            st.outlet = self._open(key, len(sample))
            st.n_values = len(sample)
        if st.outlet is None:
            if len(st.held) == st.held.maxlen:
                self._warn(f"held-{key}", "%s: names still unknown, oldest held frames dropped", key)
            st.held.append((np.array(sample, dtype=np.float64), stamp))
            return
        st.outlet.push_sample(np.ascontiguousarray(sample, dtype=np.float64), stamp)
        st.sent += 1

    def _flush(self, key: str) -> None:
        st = self.streams.get(key)
        if st is None or st.outlet is not None or not st.held:
            return
        st.n_values = len(st.held[-1][0])
        st.outlet = self._open(key, st.n_values)
        if st.outlet is None:
            return
        st.held = deque((h for h in st.held if len(h[0]) == st.n_values), maxlen=HOLD)
        while st.held:
            sample, stamp = st.held.popleft()
            st.outlet.push_sample(sample, stamp)
            st.sent += 1

    def _drop(self, key: str) -> None:
        st = self.streams.pop(key, None)
        if st is not None and st.outlet is not None:
            self.log.info("closing LSL stream for %s (its names changed)", key)
            del st.outlet

    # ----- describing -----------------------------------------------------------------------------
    def _open(self, key: str, n_values: int) -> pylsl.StreamOutlet | None:
        """An outlet for ``key`` once its names are known and agree with the sample size."""
        kind, _, who = key.partition("/")
        if kind == "markers":
            if self.layout is None:
                return None
            labels = list(self.layout.labels)
            if 3 * len(labels) != n_values:
                self._warn("markers-count", "markers: %d values per frame but layout %s has %d labels",
                                  n_values, self.layout.name, len(labels))
                return None
            info = stream_info(f"{self.prefix}Markers", self.stream_type, self._rate, f"{self.prefix}-markers",
                               _position_channels(labels, "marker"), ("markers", "marker", labels),
                               f"markers of layout {self.layout.name or '?'} from {self.layout.source or '?'}")
        elif kind == "joints":
            J = n_values // 4
            model = next((m for m in reversed(self.models) if len(m.joint_names) == J), None)
            if model is None:
                return None
            names = list(model.joint_names)
            chans = []
            for n in names:
                chans += _position_channels([n], "joint")
                chans.append({"label": f"{n}_Quality", "joint": n, "type": "Quality",
                              "unit": "0 missing, 1 estimated, 2 good"})
            info = stream_info(f"{self.prefix}Joints_{who}", self.stream_type, self._rate,
                               f"{self.prefix}-joints-{who}", chans, ("joints", "joint", names),
                               f"joint centres of actor {who}, layout {model.layout_name or '?'}")
        else:
            ch = self.characters.get(who)
            if ch is None or 8 * len(ch.joint_names) != n_values:
                return None
            names = list(ch.joint_names)
            chans = []
            for n in names:
                chans += _position_channels([n], "joint")
                chans += [{"label": f"{n}_Q{a}", "joint": n, "type": f"Orientation{a}",
                           "unit": "quaternion, relative to the rest pose in the parent frame"} for a in QUAT]
                chans.append({"label": f"{n}_Quality", "joint": n, "type": "Quality",
                              "unit": "0 missing, 1 estimated, 2 good"})
            info = stream_info(f"{self.prefix}Character_{who}", self.stream_type, self._rate,
                               f"{self.prefix}-character-{who}", chans, ("joints", "joint", names),
                               f"retargeted character {who}")
        outlet = pylsl.StreamOutlet(info)
        self.log.info("LSL stream %s: %d channels at %g Hz", info.name(), info.channel_count(), info.nominal_srate())
        return outlet

    def on_stop(self) -> None:
        for key, st in self.streams.items():
            self.log.info("%s: %d samples sent", key, st.sent)
        self.streams.clear()
