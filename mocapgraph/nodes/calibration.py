"""Actor calibration as a node, following Kiip's task states, driven by commands on the bus.

States (``calibration_status``, a NodeStatus on every change and at ``status_rate_hz``)::

    idle -> finding_base_pose -> base_pose_found -> capturing_gym (progress 0..1)
         -> gym_captured -> processing -> calibrated          (any step may end in: error)

Commands (``calibration_command``, NodeCommand with target "" or this node's name):
``find_base_pose``, ``capture_gym {"seconds": T, "rate_hz": F}``, ``process``, ``reset``,
``save {"path": P}``, ``load {"path": P}`` (paths default to the ``model_file`` param).

Time is capture time (the capture stamps of the MarkerFrames, which readers space as the file
is, whatever the replay speed), so a replay faster or slower than real time captures the same
frames. The base pose is the first frame in which every
layout marker is visible; ``base_pose_timeout_s`` of capture without one is an error naming the
markers never seen (or those missing from the most complete frame). The gym is the ``T`` s after
the base pose, sampled at ``F`` frames/s (0: every frame). Processing runs
:func:`mocapgraph.kinematics.calibration.calibrate` on base pose + gym; the result is published
latched on ``skeleton_model`` in its file form (what ``model_file`` holds), so a session
calibrated now and one loaded from the file later solve identically.
"""
from __future__ import annotations

import json
from collections import deque
import time
import warnings
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..bus import Input, Node, Output, Param
from ..kinematics.calibration import CalibrationError, CalibrationWarning, calibrate
from ..kinematics.layout import LayoutError, layout_path
from ..kinematics.capture_steps import FOUND, TIMED_OUT, BasePoseFinder, GymSampler
from ..kinematics.labels import missing_labels, place_labels
from ..kinematics.model import ActorModel, ModelFileError, load_model, save_model
from ..kinematics.skeleton import SkeletonDefinition
from ..messages.commands import CALIBRATION_COMMANDS
from ..kinematics.subject import SubjectError, read_vsk
from ..messages import MarkerFrame, MarkerLayout, NodeCommand, NodeStatus
from ..messages import SkeletonModel
from ..adapters.model_messages import jsonable, model_to_message, quality_report

IDLE = "idle"
FINDING = "finding_base_pose"
BASE_FOUND = "base_pose_found"
CAPTURING = "capturing_gym"
CAPTURED = "gym_captured"
PROCESSING = "processing"
CALIBRATED = "calibrated"
ERROR = "error"


EARLY_FRAMES = 64  # frames held while the latched layout is still on its way


class CalibrationNode(Node):
    """Base pose, gym capture and calibration of one actor; publishes a latched SkeletonModel."""

    summary = "actor calibration (base pose, gym, per-joint quality) -> latched SkeletonModel"
    markers = Input("markers", MarkerFrame, "labelled markers, m, world, in marker_layout order")
    marker_layout = Input("marker_layout", MarkerLayout, "latched labels of the marker stream", latched=True)
    calibration_command = Input("calibration_command", NodeCommand,
                                "find_base_pose, capture_gym {seconds, rate_hz}, process, reset, "
                                "save {path}, load {path}; target '' or this node", required=False)
    skeleton_model = Output("skeleton_model", SkeletonModel, "latched calibrated model")
    calibration_status = Output("calibration_status", NodeStatus,
                                "state, progress, per-joint quality (data_json)", latched=True)

    layout = Param("", "marker layout name or YAML path; empty: the layout the marker stream names")
    gym_seconds = Param(16.0, "gym capture length, s of capture time", minimum=0.1)
    gym_rate_hz = Param(60.0, "frames/s kept from the gym capture; 0 keeps every frame", minimum=0.0)
    base_pose_timeout_s = Param(10.0, "capture time to search for a base pose before giving up, s",
                                minimum=0.1)
    model_file = Param("", "model JSON: loaded at start if it exists, written after processing")
    auto = Param(False, "on start (without a model file to load): find base pose, capture gym, process")
    min_rom_deg = Param(25.0, "joints moving less than this are reported unreliable, deg", minimum=0.0)
    status_rate_hz = Param(2.0, "periodic status rate, Hz", minimum=0.1)
    centres = Param("functional,anatomical,regression", "joint-centre methods in order of preference")
    subject_file = Param("", "Vicon VSK with the subject's measurements (regression centres); '' none")

    # ----- life cycle ---------------------------------------------------------------------------
    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        # State lives from construction: the latched layout may arrive before on_start.
        self.state, self.detail, self.progress, self.data = IDLE, "", float("nan"), {}
        self.definition: SkeletonDefinition | None = None
        self._layout_error = ""
        self.where: np.ndarray | None = None      # layout marker -> stream index
        self.stream: MarkerLayout | None = None
        self.model: ActorModel | None = None
        self._auto_running = False
        self._early: deque = deque(maxlen=EARLY_FRAMES)
        self._reset_capture()
        if self.layout:
            try:
                self.definition = SkeletonDefinition.from_layout_file(self.layout)
            except LayoutError as exc:
                self._layout_error = str(exc)

    def on_start(self) -> None:
        if self._layout_error:
            self._error(self._layout_error)
        elif self.state != ERROR:
            loaded = False
            if self.model_file and Path(self.model_file).exists():
                loaded = self._load(self.model_file)
            if not loaded and self.auto and self.state != ERROR:
                self._auto_running = True
                self._begin_find()
        self._publish_status()
        self.add_timer(1.0 / self.status_rate_hz, self._publish_status)

    def _reset_capture(self) -> None:
        self.base: np.ndarray | None = None
        self.base_frame = -1
        self.finder = BasePoseFinder(self.base_pose_timeout_s)
        self.sampler = GymSampler(self.gym_seconds, self.gym_rate_hz)
        self._t_first: float | None = None
        self._wall0 = time.monotonic()
        self._frames_used = 0

    # ----- status -------------------------------------------------------------------------------
    def _publish_status(self) -> None:
        if self.state == FINDING and self._frames_used == 0 \
                and time.monotonic() - self._wall0 > self.base_pose_timeout_s:
            why = ("no marker_layout received" if self.stream is None else
                   "no marker frames received")
            self._error(f"no base pose: {why} within {self.base_pose_timeout_s:g} s")
            return
        self.calibration_status.publish(NodeStatus(
            node=self.name, state=self.state, detail=self.detail, progress=self.progress,
            data_json=json.dumps(jsonable(self.data))))

    def _set(self, state: str, detail: str = "", progress: float = float("nan"),
             data: dict[str, Any] | None = None) -> None:
        self.state, self.detail, self.progress = state, detail, progress
        self.data = data if data is not None else {}
        self._publish_status()

    def _error(self, detail: str, data: dict[str, Any] | None = None) -> None:
        self.log.error("%s", detail)
        self._auto_running = False
        self._set(ERROR, detail, data=data)

    def _note(self, detail: str, problem: bool = True) -> None:
        """Report something about a command without changing state."""
        (self.log.warning if problem else self.log.info)("%s", detail)
        self.detail = detail
        self._publish_status()

    # ----- layout -------------------------------------------------------------------------------
    def on_marker_layout(self, msg: MarkerLayout) -> None:
        self.stream = msg
        if self._bind():
            early, self._early = list(self._early), deque(maxlen=EARLY_FRAMES)
            for frame, ns in early:
                if self.state in (FINDING, CAPTURING):
                    self._take(frame, ns)
        if self.model is not None and self.definition is not None and self.where is not None:
            try:
                self.model.check_layout(self.definition.name, self.definition.marker_labels,
                                        source=self.model_file or "model")
            except ModelFileError as exc:
                self._error(str(exc))

    def _bind(self) -> bool:
        """Place the layout's markers in the stream; False (with an error state) if impossible."""
        if self.stream is None or self._layout_error:
            return False
        if self.definition is None:
            if not self.stream.name:
                self._error("no `layout` param and the marker stream names no layout")
                return False
            try:
                self.definition = SkeletonDefinition.from_layout_file(layout_path(self.stream.name))
            except LayoutError as exc:
                self._error(f"layout '{self.stream.name}' of the marker stream: {exc}")
                return False
        where, _ = place_labels(self.definition.marker_labels, list(self.stream.labels))
        missing = missing_labels(self.definition.marker_labels, where)
        if missing:
            self.where = None
            self._error(f"layout '{self.definition.name}' names markers the marker stream "
                        f"('{self.stream.name or self.stream.source}') lacks: {', '.join(missing)}",
                        {"missing_markers": missing})
            return False
        self.where = where
        return True

    # ----- frames -------------------------------------------------------------------------------
    def on_markers(self, frame: MarkerFrame) -> None:
        if self.state not in (FINDING, CAPTURING):
            return
        ns = self.markers.envelope.capture_ns
        if self.where is None:
            # The latched layout travels on its own socket and may land just after the first
            # frames: hold a few, so that frame 0 can still be the base pose.
            if self.stream is None:
                self._early.append((frame, ns))
            return
        self._take(frame, ns)

    def _take(self, frame: MarkerFrame, ns: int) -> None:
        pos = frame.positions
        if pos.shape[0] != len(self.stream.labels):
            return  # a frame that does not fit the layout is never a base pose or a gym sample
        x = pos[self.where]
        ok = np.isfinite(x).all(1)
        if frame.valid.shape == (pos.shape[0],):
            ok &= frame.valid[self.where]
        x[~ok] = np.nan
        if self._t_first is None:
            self._t_first, self._ns0 = 0.0, ns
        t = (ns - self._ns0) * 1e-9
        self._frames_used += 1
        if self.state == FINDING:
            self._find_step(x, ok, t, frame.frame_number)
        else:
            self._gym_step(x, t, frame.rate_hz)

    @property
    def gym(self) -> list[np.ndarray]:
        """The gym frames kept so far (layout order, metres, NaN unseen)."""
        return self.sampler.frames

    def _find_step(self, x: np.ndarray, ok: np.ndarray, t: float, frame_number: int) -> None:
        found = self.finder.step(ok, t - self._t_first)
        if found == FOUND:
            self.base, self.base_frame = x, frame_number
            self._set(BASE_FOUND, f"base pose at frame {frame_number}",
                      data={"base_frame": frame_number, "markers": len(ok)})
            if self._auto_running:
                self._begin_capture(self.gym_seconds, self.gym_rate_hz)
        elif found == TIMED_OUT:
            labels = self.definition.marker_labels
            never = [labels[m] for m in np.flatnonzero(self.finder.never_seen)]
            worst = [labels[m] for m in np.flatnonzero(self.finder.best_missing)]
            span = f"{self.base_pose_timeout_s:g} s of capture"
            if never:
                self._error(f"no base pose in {span}: markers never visible: {', '.join(never)}",
                            {"never_visible": never})
            else:
                self._error(f"no base pose in {span}: no frame shows all markers at once "
                            f"(the best lacks {', '.join(worst)})", {"best_frame_missing": worst})
        else:
            self.progress = self.finder.progress

    def _gym_step(self, x: np.ndarray, t: float, stream_rate: float) -> None:
        if self.sampler.step(x, t - self._t_first):
            self._finish_capture()
            return
        self.progress = self.sampler.progress
        self.data = {"frames": len(self.gym), "seconds": self.sampler.seconds,
                     "rate_hz": self.sampler.rate_hz or stream_rate}

    # ----- steps --------------------------------------------------------------------------------
    def _begin_find(self) -> None:
        self._reset_capture()
        if self.stream is not None and self.where is None and not self._bind():
            return
        self._set(FINDING, "waiting for a frame with every marker visible", 0.0)

    def _begin_capture(self, seconds: float, rate_hz: float) -> None:
        self.sampler = GymSampler(seconds, rate_hz)
        self._t_first = None
        self._set(CAPTURING, f"capturing {seconds:g} s of gym at "
                             f"{rate_hz:g} frames/s" if rate_hz else f"capturing {seconds:g} s of gym", 0.0,
                  {"frames": 0, "seconds": seconds, "rate_hz": rate_hz})

    def _finish_capture(self) -> None:
        seconds, rate = self.sampler.seconds, self.sampler.rate_hz
        self._set(CAPTURED, f"{len(self.gym)} gym frames over {seconds:g} s", 1.0,
                  {"frames": len(self.gym), "seconds": seconds, "rate_hz": rate})
        if self._auto_running:
            self._begin_process()

    def _begin_process(self) -> None:
        self._set(PROCESSING, f"calibrating from base pose + {len(self.gym)} gym frames")
        # Run on the next loop turn: the "processing" status leaves before the work blocks.
        self.call_later(0.0, self._process)

    def _process(self) -> None:
        self._auto_running = False
        frames = np.concatenate([self.base[None], np.asarray(self.gym)]) if self.gym else self.base[None]
        rate = self.sampler.rate_hz or None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", CalibrationWarning)
            try:
                subject = read_vsk(self.subject_file) if self.subject_file else None
                model = calibrate(self.definition, frames, base_frame=0, rate_hz=rate,
                                  min_rom_deg=self.min_rom_deg, source="gym capture", subject=subject,
                                  centre_order=tuple(m.strip() for m in self.centres.split(",") if m.strip()))
            except (CalibrationError, SubjectError) as exc:
                self._error(str(exc))
                return
        # The published model is the file form (rounded as saved), so a later run that loads the
        # file interprets the session exactly as this one does.
        model = ActorModel.from_dict(json.loads(json.dumps(model.to_dict())), source="calibration")
        saved = ""
        if self.model_file:
            try:
                save_model(model, self.model_file)
                saved = self.model_file
            except OSError as exc:
                self.log.error("cannot save the model to %s: %s", self.model_file, exc)
        self._publish_model(model, "calibration", saved,
                            [str(w.message) for w in caught if issubclass(w.category, CalibrationWarning)])

    def _publish_model(self, model: ActorModel, origin: str, path: str, warns: list[str]) -> None:
        self.model = model
        ml = self.definition.marker_limb if (self.definition is not None
                                             and self.definition.name == model.layout) else None
        self.skeleton_model.publish(model_to_message(model, ml))
        report = quality_report(model, self.min_rom_deg)
        report.update(origin=origin, model_file=path, base_frame=self.base_frame)
        weak = [j["joint"] for j in report["joints"] if not j["reliable"]]
        detail = f"{origin}: {len(model.joint_names)} joints" + (f", saved to {path}" if path and
                                                                  origin == "calibration" else "")
        if weak:
            detail += f"; unreliable (too little motion): {', '.join(weak)}"
        for w in warns:
            self.log.warning("%s", w)
        self._set(CALIBRATED, detail, 1.0, report)

    def _load(self, path: str) -> bool:
        try:
            if self.definition is not None:
                model = load_model(path, self.definition)
            else:
                model = load_model(path)
        except ModelFileError as exc:
            self._error(str(exc))
            return False
        self._publish_model(model, "loaded " + path, path, [])
        return True

    # ----- commands -----------------------------------------------------------------------------
    def on_calibration_command(self, cmd: NodeCommand) -> None:
        if cmd.target not in ("", self.name):
            return
        try:
            args = json.loads(cmd.args_json or "{}")
            if not isinstance(args, dict):
                raise ValueError("not a JSON object")
        except ValueError as exc:
            self._note(f"command {cmd.command!r}: bad args_json ({exc})")
            return
        handler = self._HANDLERS.get(cmd.command)
        if handler is None:
            self._note(f"unknown command {cmd.command!r} (expected one of {', '.join(CALIBRATION_COMMANDS)})")
            return
        self._auto_running = False
        handler(self, args)

    def _cmd_find_base_pose(self, args: dict[str, Any]) -> None:
        self._begin_find()

    def _cmd_capture_gym(self, args: dict[str, Any]) -> None:
        if self.base is None:
            self._note("capture_gym: no base pose yet (send find_base_pose first)")
            return
        try:
            seconds = float(args.get("seconds", self.gym_seconds))
            rate = float(args.get("rate_hz", self.gym_rate_hz))
            if not (seconds > 0 and rate >= 0):
                raise ValueError
        except (TypeError, ValueError):
            self._note(f"capture_gym: seconds must be > 0 and rate_hz >= 0, got {args}")
            return
        self._begin_capture(seconds, rate)

    def _cmd_process(self, args: dict[str, Any]) -> None:
        if self.base is None or self.state in (FINDING, CAPTURING, PROCESSING):
            self._note(f"process: nothing captured to process (state {self.state})")
            return
        self._begin_process()

    def _cmd_reset(self, args: dict[str, Any]) -> None:
        self._reset_capture()
        self._set(IDLE, "reset")

    def _cmd_save(self, args: dict[str, Any]) -> None:
        path = str(args.get("path") or self.model_file)
        if self.model is None or not path:
            self._note("save: " + ("no model yet" if self.model is None else "no path given"))
            return
        try:
            save_model(self.model, path)
        except OSError as exc:
            self._note(f"save: cannot write {path}: {exc.strerror or exc}")
            return
        self.data["model_file"] = path
        self._note(f"saved to {path}", problem=False)

    def _cmd_load(self, args: dict[str, Any]) -> None:
        path = str(args.get("path") or self.model_file)
        if not path:
            self._note("load: no path given")
            return
        self._load(path)

    #: the command table (filled below the class): one handler per name in CALIBRATION_COMMANDS
    _HANDLERS: dict[str, Callable[["CalibrationNode", dict[str, Any]], None]] = {}


CalibrationNode._HANDLERS = {name: getattr(CalibrationNode, f"_cmd_{name}") for name in CALIBRATION_COMMANDS}
