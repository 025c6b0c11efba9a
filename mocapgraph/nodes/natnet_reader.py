"""OptiTrack NatNet reader node: Motive's labelled markers, unlabelled markers and rigid bodies on the bus.

Sockets and the command channel are :mod:`mocapgraph.net.natnet_link`; bytes are decoded by
:mod:`mocapgraph.formats.natnet`; labels and body order by :mod:`mocapgraph.formats.natnet_model`.
This node wires them to the event loop and publishes.
"""
from __future__ import annotations

import math
import struct
import time
from typing import Any

import numpy as np

from ..bus import Output, Param
from ..formats import natnet as nn
from ..formats.device_file import DeviceConfig, device_or_default
from ..bus.diagnostics import ClockRecord, device_clock
from ..formats.natnet_model import (NatNetModel, SkeletonBones, bone_poses, device_time_ns, local_to_global,
                                    rotation_quat, skeleton_bones, unlabelled)
from ..kinematics.quaternion import quat_multiply
from ..messages import MarkerFrame, RigidBodyFrame, RigidBodyLayout, SkeletonInfo, SkeletonPose
from ..messages.clock_sync import ClockSync
from ..net.natnet_link import LinkConfig, NatNetLink
from .marker_source import UP_AXIS_CHOICES, LayoutMap, MarkerSourceNode, check_device_param
from .source_base import INPUT_ERRORS

TICK_S = 0.05
#: a frame number this far below the last one means the numbering started over (Motive restarted)
RESTART_STEP = 10


def _reason(exc: nn.NatNetError) -> str:
    """The diagnostics bucket of a refused packet."""
    text = str(exc)
    for key, words in (("oversized", ("oversized",)), ("wrong_version", ("not supported", "byte count says")),
                       ("truncated", ("truncated", "header says", "shorter than", "does not fit"))):
        if any(w in text for w in words):
            return key
    return "malformed"


class NatNetReader(MarkerSourceNode):
    """Connects to a NatNet server (OptiTrack Motive) and publishes ``markers`` (labelled markers,
    names from the model definitions, latched ``marker_layout``), ``unlabelled_markers`` (a point
    cloud: count varies per frame, no layout) and ``rigid_bodies`` (latched ``rigid_body_layout``).

    The server is ``server`` ('' = discovery by broadcast); frames come unicast (to the command
    socket) or, with ``multicast_group``, on ``data_port`` of that group. Occluded markers and
    untracked rigid bodies are NaN with valid False / quality 0. A frame with an id the model
    definitions lack (a new rigid body or marker set in Motive) makes the reader ask for them again
    and publish the new layouts; frames with the 'models changed' flag do too. A server silent for
    ``silence_s``, or frame numbers starting over, is one reconnect (logged, counted), never loss.
    Malformed, truncated, oversized and wrong-version packets are counted by reason and skipped.
    Capture stamps: arrival minus the latency the server reports (mid-exposure to transmit).
    A skeleton asset's bones publish on ``skeleton_pose`` (latched ``skeleton_info``: bone names,
    parents, offsets), untracked bones NaN with tracking state 0; the last SMPTE timecode is in
    the status (``timecode``).
    Axes: Motive streams Y up (``up_axis: y``); a device file's ``to_world`` may say otherwise.
    """

    summary = "OptiTrack Motive over NatNet: labelled + unlabelled markers, rigid bodies (unicast or multicast)"
    unlabelled_markers = Output("unlabelled_markers", MarkerFrame, "unlabelled markers: m, world; a point cloud "
                                "whose count varies per frame (no layout), all valid")
    rigid_bodies = Output("rigid_bodies", RigidBodyFrame, "rigid body poses in rigid_body_layout order: m, wxyz, "
                          "world; NaN with quality 0 where not tracked")
    rigid_body_layout = Output("rigid_body_layout", RigidBodyLayout, "latched: rigid body names, NatNet ids, parents")
    skeleton_pose = Output("skeleton_pose", SkeletonPose, "bone origins (m, world) and orientations (wxyz, world) of "
                           "one Motive skeleton, skeleton_info order; NaN with state 0 where not tracked")
    skeleton_info = Output("skeleton_info", SkeletonInfo, "latched: bone names, parents and offsets of that skeleton")
    skeleton = Param("", "which Motive skeleton to publish on skeleton_pose ('' = the first with bones)")
    skeleton_coordinates = Param("global", "Motive's streaming setting for skeletons: bones 'global', or 'local' "
                                           "(relative to the parent bone: composed here)", choices=["global", "local"])
    server = Param("127.0.0.1", "address of the NatNet server (Motive); '' = discover one by broadcast")
    command_port = Param(1510, "the server's command port", minimum=1, maximum=65535)
    data_port = Param(1511, "the server's data port (multicast frames)", minimum=1, maximum=65535)
    multicast_group = Param("", "multicast group to join for frames (Motive's default 239.255.42.99); "
                                "'' = unicast (Motive's 'Transmission Type: Unicast')")
    discovery_address = Param("255.255.255.255", "where discovery is sent when server is '' (a subnet's "
                                                  "broadcast address, e.g. 192.168.0.255)")
    local_address = Param("0.0.0.0", "address of the network interface to bind and join the multicast group on "
                                     "(the interface facing Motive)")
    natnet_version = Param("", "NatNet version of the frames, e.g. '3.0'; '' = the server's, from its server info")
    device = Param("", "device file (graph_configs/devices name or path): device-to-world transform; "
                       "'' = Motive's frame with up_axis")
    up_axis = Param("y", "the Motive axis that points up, made world Z (Motive's default is Y up); "
                         "'auto' = the device file's to_world", choices=UP_AXIS_CHOICES)
    rate_hz = Param(0.0, "nominal frame rate written into frames, Hz; 0 = the server's (asked), "
                         "else measured", minimum=0.0)
    silence_s = Param(1.0, "no frame for this long while streaming = the server went away: reconnect", minimum=0.05)
    retry_s = Param(1.0, "how often unanswered requests (connect, model definitions) are sent again, s",
                    minimum=0.05)

    @classmethod
    def graph_check(cls, params: dict[str, Any]) -> None:
        """The graph check refuses a device file this reader would refuse (the node itself reports it)."""
        check_device_param(params)

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.config_error = ""
        self.forced: nn.Version | None = None
        try:
            self.dev: DeviceConfig = device_or_default(self.device, self.up_axis)
            if self.natnet_version:
                major, minor = (int(x) for x in self.natnet_version.split(".")[:2])
                self.forced = (major, minor)
        except INPUT_ERRORS as exc:
            self.config_error = str(exc)
            self.dev = DeviceConfig()
        except ValueError:
            self.config_error = f"natnet_version {self.natnet_version!r}: expected MAJOR.MINOR such as 3.0"
            self.dev = DeviceConfig()
        self._dev_q = rotation_quat(self.dev.rotation)
        cfg = LinkConfig(self.server, self.command_port, self.data_port, self.multicast_group, self.local_address,
                         retry_s=self.retry_s, silence_s=self.silence_s, discovery_to=self.discovery_address)
        self.link = NatNetLink(cfg, self.log)
        self.version: nn.Version | None = self.forced
        self.unsupported = ""  # the server's NatNet version when this reader cannot read it
        self.clock_hz = 0
        self.clock = ClockSync()   # the server's clock onto ours (offset and drift, restarts re-seeded)
        self.app = ""
        self.model: NatNetModel | None = None
        self.bones: SkeletonBones | None = None
        self.last_timecode = ""
        self._rate = 0.0
        self._server_rate = False
        self._last_number: int | None = None
        self._last_ts = 0.0
        self.counts: dict[str, int] = dict(packets=0, frames=0, gaps=0, out_of_order=0, restarts=0,
                                           model_updates=0, unknown_id_frames=0, before_server_info=0,
                                           before_model_defs=0, other_messages=0, skipped_items=0)
        self.rejected: dict[str, int] = {}

    # ----- start and stop ------------------------------------------------------------------
    def on_start(self) -> None:
        if self.config_error:
            self.fail(self.config_error)
            return
        try:
            self.link.open()
        except OSError as exc:
            self.link.close()
            self.fail(f"natnet {self.link.where}: cannot open the sockets ({exc.strerror or exc})")
            return
        for sock in self.link.sockets():
            self.add_reader(sock.fileno(), lambda s=sock: self._read(s))
        self.add_timer(TICK_S, self._tick, first_delay_s=0.0)
        mode = f"multicast {self.multicast_group}:{self.data_port}" if self.multicast_group else "unicast"
        self.log.info("natnet: connecting to %s (%s)", self.link.where, mode)
        self.set_state("connecting", f"natnet {self.link.where}, {mode}")

    def on_stop(self) -> None:
        for sock in self.link.sockets():
            self.remove_reader(sock.fileno())
        self.link.close()

    def _tick(self) -> None:
        before = self.link.state
        self.link.tick(time.monotonic())
        if self.link.state != before and self.link.state == "reconnecting":
            self._last_number = None
            self.set_state("reconnecting", f"natnet {self.link.where}: no frames for {self.silence_s:g} s")

    # ----- packets ---------------------------------------------------------------------------
    def _read(self, sock) -> None:
        for data, sender, arrival_ns in self.link.receive(sock):
            self.counts["packets"] += 1
            try:
                self._packet(data, sender, arrival_ns)
            except nn.NatNetError as exc:
                why = _reason(exc)
                self.rejected[why] = self.rejected.get(why, 0) + 1
                self.warn_limited("bad", "natnet %s: packet skipped: %s", self.link.where, exc)

    def _packet(self, data: bytes, sender: tuple[str, int], arrival_ns: int) -> None:
        msg = nn.message_id(data)
        if msg not in nn.MESSAGE_NAMES and len(data) >= 4:
            raise nn.NatNetError(f"message id {msg}: not a NatNet message ({len(data)} bytes)")
        if len(data) >= 4:
            extra = len(data) - 4 - struct.unpack_from("<H", data, 2)[0]
            if extra > 4:  # a 4-byte end tag left out of the count is tolerated; more is not NatNet
                raise nn.NatNetError(f"{nn.MESSAGE_NAMES.get(msg, msg)}: oversized: {extra} bytes after "
                                     "what its header counts")
        if msg == nn.NAT_FRAMEOFDATA:
            self._frame(data, arrival_ns)
        elif msg == nn.NAT_SERVERINFO:
            self._server_info(nn.decode_server_info(data), sender)
        elif msg == nn.NAT_MODELDEF:
            self._model_defs(data)
        elif msg == nn.NAT_RESPONSE:
            rate = self.link.got_response(data[4:])
            if rate:
                self._rate, self._server_rate = rate, True
        else:
            self.counts["other_messages"] += 1

    def _server_info(self, info: nn.ServerInfo, sender: tuple[str, int]) -> None:
        self.link.got_server_info(sender)
        self.clock_hz, self.app = info.clock_hz, f"{info.app_name} {'.'.join(map(str, info.app_version))}"
        version = self.forced or info.version
        if version < (3, 0):
            self.version, self.unsupported = None, f"NatNet {version[0]}.{version[1]}"
            self.warn_limited("version", "natnet %s: the server streams NatNet %d.%d; this reader reads 3.0 and "
                              "later (update Motive, or set its streaming bitstream to 3.0+)", self.link.where,
                              *version)
            return
        self.version, self.unsupported = version, ""
        self.log.info("natnet %s: %s, NatNet %d.%d, clock %d Hz%s", self.link.where, self.app, *version,
                      info.clock_hz, f", multicast {info.multicast_group}:{info.data_port}" if info.multicast else "")
        if self.state == "connecting":
            self.set_state("waiting", f"natnet {self.link.where}: {self.app}, waiting for model definitions")

    def _model_defs(self, data: bytes) -> None:
        if self.version is None:
            self.counts["before_server_info"] += 1
            return
        model = NatNetModel(nn.decode_model_defs(data, self.version))
        self.link.need_defs = False
        old = self.model
        if old is not None and old.labels == model.labels and old.body_names == model.body_names \
                and np.array_equal(old.body_ids, model.body_ids) and _same_bones(self.bones, model, self.skeleton):
            self.model = model
            return
        try:
            lmap = LayoutMap.build(self.layout, model.labels, f"natnet {self.link.where}")
        except INPUT_ERRORS as exc:
            if old is None:
                self.fail(str(exc))
            else:
                self.warn_limited("layout", "natnet %s: new model definitions refused, keeping the old: %s",
                                  self.link.where, exc)
            return
        self.model = model
        self.counts["model_updates"] += old is not None
        d = model.defs
        self.log.info("natnet %s: model definitions: %d marker set(s) (%d labelled markers), %d rigid "
                      "body(ies), %d skeleton(s)%s", self.link.where, len(d.marker_sets), model.n_labels,
                      len(model.body_names), len(d.skeletons), " (updated mid-stream)" if old else "")
        source = f"natnet {self.app} {self.link.where}"
        self.publish_layout(lmap, f"NatNet metres; {self.dev.describe()}", source)
        self.rigid_body_layout.publish(RigidBodyLayout(
            names=model.body_names, ids=model.body_ids.astype(np.int32), parent=model.body_parents,
            units_note=f"NatNet metres, quaternions xyzw -> wxyz; {self.dev.describe()}", source=source))
        self.bones = skeleton_bones(model.defs, self.skeleton)     # the skeleton to publish, if any
        if self.bones is not None:
            self.skeleton_info.publish(_skeleton_info(self.bones, self.dev))
        elif self.skeleton:
            self.warn_limited("skeleton", "natnet %s: no skeleton %r (Motive has %s)", self.link.where,
                              self.skeleton, ", ".join(model.defs.skeletons) or "none")

    def _frame(self, data: bytes, arrival_ns: int) -> None:
        if self.unsupported:
            raise nn.NatNetError(f"frame of data: {self.unsupported} is not supported (3.0 and later are)")
        if self.version is None:
            self.counts["before_server_info"] += 1
            return
        f = nn.decode_frame(data, self.version)
        back = self.link.got_frame(time.monotonic())
        if back:
            self.log.info("natnet %s: frames again from frame %d (reconnect %d done)", self.link.where,
                          f.frame_number, self.link.reconnects)
        if self.model is None:
            self.counts["before_model_defs"] += 1
            self.link.request_model_defs()
            return
        if not self._number(f.frame_number, back):
            return
        if f.models_changed:
            self.link.request_model_defs()
        if not self._server_rate:       # the rate from Motive's timestamps, until the server tells it
            self._rate = _smoothed_rate(self._rate, self._last_ts, f.timestamp)
        self._last_ts = f.timestamp
        self.counts["skipped_items"] += f.skipped_items
        device_ns, latency_ns = device_time_ns(f, self.clock_hz)
        self._publish(f, self.clock.update(device_ns, arrival_ns, latency_ns))
        if self.state != "streaming":
            self.set_state("streaming", f"natnet {self.link.where}: {self.app}, NatNet {self.version[0]}."
                                        f"{self.version[1]}")

    def _number(self, n: int, back: bool) -> bool:
        """Frame number bookkeeping: gaps, late frames (skipped), numbering that started over."""
        last, self._last_number = self._last_number, n
        if last is None or back:
            return True
        step = n - last
        if step > 1:
            self.counts["gaps"] += step - 1
        elif step <= 0 and step > -RESTART_STEP:
            self.counts["out_of_order"] += 1
            self._last_number = last
            return False
        elif step <= -RESTART_STEP:
            self.counts["restarts"] += 1
            self.link.reconnects += 1
            self.link.request_model_defs()
            self.log.warning("natnet %s: frame numbers started over (%d after %d): server restarted; "
                             "reconnect %d", self.link.where, n, last, self.link.reconnects)
        return True

    def _publish(self, f: nn.Frame, capture_ns: int) -> None:
        model, dev = self.model, self.dev
        lab = model.labelled(f)
        bodies = model.bodies(f)
        if lab.unknown or bodies.unknown:
            self.counts["unknown_id_frames"] += 1
            self.link.request_model_defs()
        rate = self.rate_hz or self._rate
        pos = self.lmap.positions(dev.points_to_world(lab.positions))
        self.publish_frame(f.frame_number, rate, pos, capture_ns, residual=self.lmap.values(lab.residual, math.nan))
        upos, ures = unlabelled(f)
        self.unlabelled_markers.publish(MarkerFrame(frame_number=f.frame_number, rate_hz=rate,
                                                    positions=dev.points_to_world(upos),
                                                    valid=np.ones(len(upos), bool), residual=ures),
                                        capture_ns=capture_ns)
        self.rigid_bodies.publish(RigidBodyFrame(frame_number=f.frame_number, positions=dev.points_to_world(
            bodies.positions), orientations=quat_multiply(self._dev_q, bodies.quat_wxyz), error=bodies.error,
            quality=np.where(bodies.valid, 2, 0).astype(np.int8)), capture_ns=capture_ns)
        if self.bones is not None:
            self.skeleton_pose.publish(_skeleton_pose(f, self.bones, dev, self._dev_q, self.skeleton_coordinates),
                                       capture_ns=capture_ns)
        self.last_timecode = f.timecode_text() if f.timecode else self.last_timecode
        self.counts["frames"] += 1

    # ----- reporting -------------------------------------------------------------------------
    def status_data(self) -> dict[str, Any]:
        d: dict[str, Any] = dict(self.counts)
        d.update(rejected=dict(self.rejected), rejected_total=sum(self.rejected.values()),
                 reconnects=self.link.reconnects, server=self.link.where, app=self.app, timecode=self.last_timecode,
                 natnet_version=".".join(map(str, self.version)) if self.version else "",
                 rate_hz=self.rate_hz or self._rate, connect_requests=self.link.connect_sent,
                 clock=self.clock.stats().as_dict(),
                 last_frame_age_s=(time.monotonic() - self.link.last_frame) if self.link.last_frame else None)
        return d

    def clock_records(self) -> list[ClockRecord]:
        return super().clock_records() + device_clock(f"natnet:{self.link.where}", self.clock)

    def device_edges(self) -> list[dict[str, Any]]:
        return [{"topic": f"natnet:{self.link.where}", "sender": self.app or "?", "rate_hz": self.rate_hz or self._rate,
                 "received": self.counts["frames"], "gaps": self.counts["gaps"],
                 "rejected": sum(self.rejected.values())}]


def _same_bones(bones: SkeletonBones | None, model: NatNetModel, name: str) -> bool:
    """Whether the model definitions' skeleton to publish is the one already latched."""
    new = skeleton_bones(model.defs, name)
    if bones is None or new is None:
        return bones is new
    return bones.names == new.names and np.array_equal(bones.ids, new.ids) and bones.id == new.id


def _skeleton_info(b: SkeletonBones, dev: DeviceConfig) -> SkeletonInfo:
    """A skeleton's latched description, bone offsets turned to world axes."""
    return SkeletonInfo(source=f"natnet skeleton {b.name}", joint_names=b.names, joint_parent=b.parents,
                        rest_offsets=b.offsets @ dev.rotation.T,
                        units_note=f"NatNet metres, bone poses as streamed (global), xyzw -> wxyz; {dev.describe()}")


def _skeleton_pose(f: nn.Frame, b: SkeletonBones, dev: DeviceConfig, dev_q: np.ndarray,
                   coordinates: str = "global") -> SkeletonPose:
    """One frame's bones of skeleton ``b`` in world axes (``coordinates`` 'local': composed from
    parent-relative poses first); untracked bones, and with 'local' bones under one, NaN with state 0."""
    bones = bone_poses(f, b)
    pos, quat = bones.positions, bones.quat_wxyz
    if coordinates == "local":
        pos, quat = local_to_global(pos, quat, b.parents, b.levels)
    ok = bones.valid & np.isfinite(pos).all(axis=1) & np.isfinite(quat).all(axis=1)
    return SkeletonPose(source_id=b.name, frame_number=f.frame_number,
                        joint_positions=dev.points_to_world(np.where(ok[:, None], pos, np.nan)),
                        joint_orientations=quat_multiply(dev_q, np.where(ok[:, None], quat, np.nan)),
                        tracking_state=np.where(ok, 2, 0).astype(np.int8))


def _smoothed_rate(rate: float, last_ts: float, ts: float) -> float:
    """The frame rate estimate ``rate`` updated by one frame's timestamp (s) after ``last_ts``."""
    if not last_ts or ts <= last_ts:
        return rate
    inst = 1.0 / (ts - last_ts)
    return inst if not rate else 0.95 * rate + 0.05 * inst
