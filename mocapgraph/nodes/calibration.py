"""Actor calibration as a node, following Kiip's task states, driven by commands on the bus.

States (``calibration_status``, a NodeStatus on every change and at ``status_rate_hz``)::

    idle -> finding_base_pose -> base_pose_found -> capturing_gym (progress 0..1)
         -> gym_captured -> processing -> calibrated          (any step may end in: error)

Commands (``calibration_command``, NodeCommand with target "" or this node's name):
``find_base_pose``, ``capture_gym {"seconds": T, "rate_hz": F}``, ``process``, ``reset``,
``save {"path": P}``, ``load {"path": P}`` (paths default to the ``model_file`` param; a path a
command names must lie in the ``model_file``'s folder, symlinks followed, and name a regular file:
:mod:`mocapgraph.bus.file_places`; anything else is refused in one line and counted in the status's
``commands_refused``, the node carries on).

Time is capture time (the capture stamps of the MarkerFrames, which readers space as the file
is, whatever the replay speed), so a replay faster or slower than real time captures the same
frames. The base pose is the first frame in which every
layout marker is visible; ``base_pose_timeout_s`` of capture without one is an error naming the
markers never seen (or those missing from the most complete frame). The gym is the ``T`` s after
the base pose, sampled at ``F`` frames/s (0: every frame). Processing runs
:func:`mocapgraph.kinematics.calibration.calibrate.calibrate` on base pose + gym; the result is published
latched on ``skeleton_model`` in its file form (what ``model_file`` holds), so a session
calibrated now and one loaded from the file later solve identically.

The node is the command state machine; the capture steps live in
:mod:`mocapgraph.kinematics.calibration.capture_steps`, the stream binding in
:mod:`mocapgraph.adapters.layout_binding`, the status texts in
:mod:`mocapgraph.adapters.calibration_report`, saving and the message form in
:mod:`mocapgraph.adapters.model_store`.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

from ..bus import Input, Node, Output, Param
from ..bus.file_places import PathRefused
from ..kinematics.calibration.capture_steps import FOUND, TIMED_OUT, CaptureSession, GymSampler
from ..kinematics.model import ActorModel, ModelFileError, as_saved, load_model
from ..kinematics.subject import SubjectError, read_vsk
from ..messages.commands import CALIBRATION_COMMANDS, parse_command
from ..messages import MarkerFrame, MarkerLayout, NodeCommand, NodeStatus
from ..messages import SkeletonModel
from ..adapters.calibration_report import (base_pose_failure, gym_detail, model_report, stalled_search,
                                        status_message)
from ..adapters.layout_binding import BindError, StreamBinding
from ..adapters.model_store import model_message, model_path, save_problem

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
    max_uncertainty_mm = Param(2.0, "functional centres with a larger standard error are reported unreliable, mm "
                               "(when the clusters' residuals are noise)", minimum=0.0)
    status_rate_hz = Param(2.0, "periodic status rate, Hz", minimum=0.1)
    centres = Param("functional,anatomical,regression", "joint-centre methods in order of preference")
    subject_file = Param("", "Vicon VSK with the subject's measurements (regression centres); '' none")

    # ----- life cycle ---------------------------------------------------------------------------
    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        # State lives from construction: the latched layout may arrive before on_start.
        self.state, self.detail, self.progress, self.data = IDLE, "", float("nan"), {}
        self.binding = StreamBinding(self.layout, hold=EARLY_FRAMES)
        self.model: ActorModel | None = None
        self._auto_running = False
        self.commands_refused = 0
        self._reset_capture()
        from ..kinematics.calibration import calibrate  # noqa: F401  (its math now: see _process)
        from ..kinematics.solving import solver  # noqa: F401

    def on_start(self) -> None:
        if self.binding.error:
            self._error(self.binding.error)
        elif self.state != ERROR:
            loaded = bool(self.model_file) and Path(self.model_file).exists() and self._load(self.model_file)
            if not loaded and self.auto and self.state != ERROR:
                self._auto_running = True
                self._begin_find()
        self._publish_status()
        self.add_timer(1.0 / self.status_rate_hz, self._publish_status)

    def _reset_capture(self) -> None:
        self.capture = CaptureSession(self.base_pose_timeout_s, self.gym_seconds, self.gym_rate_hz)
        self._wall0 = time.monotonic()

    # ----- status -------------------------------------------------------------------------------
    def _publish_status(self) -> None:
        if self.state == FINDING and self.capture.frames_used == 0 \
                and time.monotonic() - self._wall0 > self.base_pose_timeout_s:
            self._error(stalled_search(self.binding.stream is not None, self.base_pose_timeout_s))
            return
        self.calibration_status.publish(status_message(self.name, self.state, self.detail, self.progress,
                                                       dict(self.data, commands_refused=self.commands_refused)))

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
        self.binding.stream = msg
        if self._bind():
            for frame, ns in self.binding.release():
                if self.state in (FINDING, CAPTURING):
                    self._take(frame, ns)
        if self.model is not None:
            try:
                self.binding.check(self.model, self.model_file or "model")
            except ModelFileError as exc:
                self._error(str(exc))

    def _bind(self) -> bool:
        """Place the layout's markers in the stream; False (with an error state) if impossible."""
        if self.binding.stream is None or self.binding.error:
            return False
        try:
            self.binding.bind()
        except BindError as exc:
            self._error(str(exc), exc.data)
            return False
        return True

    # ----- frames -------------------------------------------------------------------------------
    def on_markers(self, frame: MarkerFrame) -> None:
        if self.state not in (FINDING, CAPTURING):
            return
        ns = self.markers.envelope.capture_ns
        if self.binding.where is None:
            if self.binding.stream is None:  # its latched layout is on its way: hold the frame
                self.binding.early.append((frame, ns))
            return
        self._take(frame, ns)

    def _take(self, frame: MarkerFrame, ns: int) -> None:
        picked = self.binding.pick(frame)
        if picked is None:
            return  # a frame that does not fit the layout is never a base pose or a gym sample
        x, ok = picked
        cap = self.capture
        if self.state == CAPTURING:
            if cap.sample(x, ns):
                self._finish_capture()
                return
            self.progress, self.data = cap.sampler.progress, cap.gym_data(frame.rate_hz)
            return
        found = cap.search(x, ok, ns, frame.frame_number)
        if found == FOUND:
            self._set(BASE_FOUND, f"base pose at frame {cap.base_frame}",
                      data={"base_frame": cap.base_frame, "markers": len(ok)})
            if self._auto_running:
                self._begin_capture(self.gym_seconds, self.gym_rate_hz)
        elif found == TIMED_OUT:
            self._error(*base_pose_failure(cap.finder, self.binding.definition.marker_labels))
        else:
            self.progress = cap.finder.progress

    # ----- steps --------------------------------------------------------------------------------
    def _begin_find(self) -> None:
        self._reset_capture()
        if self.binding.stream is not None and self.binding.where is None and not self._bind():
            return
        self._set(FINDING, "waiting for a frame with every marker visible", 0.0)

    def _begin_capture(self, seconds: float, rate_hz: float) -> None:
        self.capture.start_gym(seconds, rate_hz)
        self._set(CAPTURING, gym_detail(seconds, rate_hz), 0.0, self.capture.gym_data())

    def _finish_capture(self) -> None:
        data = self.capture.gym_data()
        self._set(CAPTURED, f"{data['frames']} gym frames over {data['seconds']:g} s", 1.0, data)
        if self._auto_running:
            self._begin_process()

    def _begin_process(self) -> None:
        self._set(PROCESSING, f"calibrating from base pose + {len(self.capture.gym)} gym frames")
        # Run on the next loop turn: the "processing" status leaves before the work blocks.
        self.call_later(0.0, self._process)

    def _process(self) -> None:
        # the math was loaded by __init__, not here (processing races the stream: frames after it are
        # solved with its model) nor with this module (the launcher's check imports it, declarations only)
        from ..kinematics.calibration.calibrate import CalibrationError
        self._auto_running = False
        try:
            subject = read_vsk(self.subject_file) if self.subject_file else None
            model, warns = self.capture.process(
                self.binding.definition, min_rom_deg=self.min_rom_deg, subject=subject,
                max_uncertainty_mm=self.max_uncertainty_mm,
                centre_order=tuple(m.strip() for m in self.centres.split(",") if m.strip()))
        except (CalibrationError, SubjectError) as exc:
            self._error(str(exc))
            return
        # The published model is the file form (rounded as saved), so a later run that loads the
        # file interprets the session exactly as this one does.
        model = as_saved(model)
        problem = save_problem(model, self.model_file, self.model_file) if self.model_file else ""
        if problem:
            self.log.error("model not saved: %s", problem)
        saved = "" if problem else self.model_file
        self._publish_model(model, "calibration", saved, warns)

    def _publish_model(self, model: ActorModel, origin: str, path: str, warns: list[str]) -> None:
        self.model = model
        self.skeleton_model.publish(model_message(model, self.binding.definition))
        detail, report = model_report(model, self.min_rom_deg, origin, path, self.capture.base_frame)
        for w in warns:
            self.log.warning("%s", w)
        self._set(CALIBRATED, detail, 1.0, report)

    def _load(self, path: str) -> bool:
        try:
            model = load_model(model_path(path, self.model_file), self.binding.definition)
        except (ModelFileError, PathRefused) as exc:
            self._error(str(exc))
            return False
        self._publish_model(model, "loaded " + path, path, [])
        return True

    # ----- commands -----------------------------------------------------------------------------
    def on_calibration_command(self, cmd: NodeCommand) -> None:
        if cmd.target not in ("", self.name):
            return
        try:
            args = parse_command(cmd.command, cmd.args_json, CALIBRATION_COMMANDS)
        except ValueError as exc:
            self.commands_refused += 1
            self._note(str(exc))
            return
        self._auto_running = False
        self._HANDLERS[cmd.command](self, args)

    def _cmd_find_base_pose(self, args: dict[str, Any]) -> None:
        self._begin_find()

    def _cmd_capture_gym(self, args: dict[str, Any]) -> None:
        if self.capture.base is None:
            self._note("capture_gym: no base pose yet (send find_base_pose first)")
            return
        try:
            self._begin_capture(*GymSampler.checked(args.get("seconds", self.gym_seconds),
                                                    args.get("rate_hz", self.gym_rate_hz)))
        except ValueError as exc:
            self._note(f"capture_gym: {exc}")

    def _cmd_process(self, args: dict[str, Any]) -> None:
        if self.capture.base is None or self.state in (FINDING, CAPTURING, PROCESSING):
            self._note(f"process: nothing captured to process (state {self.state})")
            return
        self._begin_process()

    def _cmd_reset(self, args: dict[str, Any]) -> None:
        self._reset_capture()
        self._set(IDLE, "reset")

    #: the command table (filled below the class): one handler per name in CALIBRATION_COMMANDS
    _HANDLERS: dict[str, Callable[["CalibrationNode", dict[str, Any]], None]] = {}


def _file_command(node: CalibrationNode, command: str, args: dict[str, Any]) -> None:
    """``save``/``load {"path"}``: only a file in the folder the graph names (``model_file``'s,
    symlinks followed: :func:`model_path`); anything else is refused in one line and counted."""
    if command == "save" and node.model is None:
        node._note("save: no model yet")
        return
    try:
        path = model_path(args.get("path") or node.model_file, node.model_file, f"{command}: path")
    except PathRefused as exc:
        node.commands_refused += 1
        node._note(f"{exc}; refused")
        return
    if command == "load":
        node._load(path)
        return
    problem = save_problem(node.model, path, node.model_file)
    if not problem:
        node.data["model_file"] = path
    node._note(f"save: {problem}" if problem else f"saved to {path}", problem=bool(problem))


CalibrationNode._HANDLERS = {name: getattr(CalibrationNode, f"_cmd_{name}", None) for name in CALIBRATION_COMMANDS}
CalibrationNode._HANDLERS.update(save=lambda node, args: _file_command(node, "save", args),
                                 load=lambda node, args: _file_command(node, "load", args))
