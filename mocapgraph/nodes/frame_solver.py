"""Frame solver as a node: one ActorPose per MarkerFrame from a calibrated SkeletonModel.

The model comes from the latched ``skeleton_model`` topic (a calibration node), or from
``model_file`` at start; a model arriving on the topic later replaces it. Markers are placed on
the model's markers by label through the latched ``marker_layout`` (case-insensitive, Vicon
prefix ignored) once, then per frame by one fancy index and one :meth:`FrameSolver.step`.

A model whose markers the stream lacks (another layout) is refused with one logged error and
nothing is published until a matching model arrives. Frames with NaN or invalid markers give
joints marked missing (or estimated over gaps up to ``max_gap_s``), never garbage; a frame of the
wrong size gives an all-missing pose. Time is the capture stamp of each frame (readers keep the
file's spacing whatever the replay speed); when it goes backwards the temporal state starts afresh.
With ``lowpass_hz`` the markers are low-passed with no phase lag at a fixed delay
(:class:`~mocapgraph.kinematics.solving.lowpass.FixedLagLowpass`): each pose comes out
``lowpass_lag_s`` late, with its own frame number and capture stamp.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..bus import Input, Node, Output, Param
from ..bus.file_places import PathRefused, own_folder_path
from ..kinematics.model import ActorModel, ModelFileError, load_model
from ..messages import ActorPose, MarkerFrame, MarkerLayout
from ..messages import SkeletonModel
from ..adapters.model_messages import marker_index, missing_pose, model_from_message, pose_message

if TYPE_CHECKING:   # imported when the node is built (see __init__)
    from ..kinematics.solving.solver import FrameSolver

SOLVER_KERNELS = ("mocapgraph.kinematics.solving.global_fit_kernels", "mocapgraph.kinematics.solving.joint_kernels",
                  "mocapgraph.kinematics.solving.rigid_kernels")

FILTERS = ("", "one_euro", "constant_velocity")


class FrameSolverNode(Node):
    """Joint centres, limb orientations and per-joint/limb quality every frame."""

    summary = "joint centres every frame from labelled markers and a calibrated model -> ActorPose"
    markers = Input("markers", MarkerFrame, "labelled markers, m, world, in marker_layout order")
    marker_layout = Input("marker_layout", MarkerLayout, "latched labels of the marker stream", latched=True)
    skeleton_model = Input("skeleton_model", SkeletonModel, "latched calibrated model", latched=True,
                           required=False)
    actor_pose = Output("actor_pose", ActorPose, "solved joints in the order of skeleton_model")

    max_gap_s = Param(0.1, "longest gap a joint is predicted over (constant velocity), s; 0: none",
                      minimum=0.0)
    filter = Param("", "temporal filter on joints: '', one_euro, constant_velocity", choices=FILTERS)
    enforce_lengths = Param(True, "keep calibrated bone lengths (Kiip), outward from the root")
    actor = Param("actor", "actor name carried in every ActorPose")
    fit = Param("segment", "limb poses: segment (each by itself) or global (together under the joints)",
                choices=("segment", "global"))
    model_file = Param("", "model JSON loaded at start instead of waiting for skeleton_model")
    lowpass_hz = Param(0.0, "zero-lag low-pass of the markers at this cutoff, Hz, at a delay of lowpass_lag_s "
                            "(kinematics.solving.lowpass); 0: off", minimum=0.0)
    lowpass_lag_s = Param(0.1, "delay of the low-pass: each pose comes out this late, s (at least 8 frames)",
                          minimum=0.0)
    lowpass_rate_hz = Param(0.0, "the marker stream's rate for the low-pass, Hz; 0: the model's capture rate",
                            minimum=0.0)

    def __init__(self, name: str, params: dict | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        # State lives from construction: a latched model or layout may arrive before on_start.
        self.model: ActorModel | None = None
        self.model_source = ""
        self.solver: FrameSolver | None = None
        self._lowpass = None
        self.where: np.ndarray | None = None
        self.n_stream = 0
        self.identity = False
        self._last_t = -np.inf
        self._t0_ns: int | None = None  # capture-time origin, so float seconds stay precise
        self._skipped = 0
        # the solver and its compiled kernels now, not at the first frame (numba's first call costs
        # ~0.5 s even from its cache: at 240 Hz that queued a hundred frames behind it); not with this
        # module, which the launcher imports to check a graph against the declarations above (scipy
        # and numba would cost every check of a graph with a solver ~0.3 s)
        from ..jit import warm_all
        from ..kinematics.solving.solver import FrameSolver

        self._new_solver = FrameSolver
        warm_all(SOLVER_KERNELS)
        self._bad_frames = 0
        self._failures = 0
        self._refused: tuple[str, str] | None = None

    def on_start(self) -> None:
        if not self.model_file or self.model is not None:
            return  # a model from the topic came first and wins
        if not Path(self.model_file).exists():
            self.log.error("model_file %s does not exist; waiting for skeleton_model", self.model_file)
            return
        try:
            self._use_model(load_model(own_folder_path(self.model_file, "model_file")), self.model_file)
        except (ModelFileError, PathRefused) as exc:
            self.log.error("%s; waiting for skeleton_model", exc)

    # ----- model and layout ---------------------------------------------------------------------
    def on_skeleton_model(self, msg: SkeletonModel) -> None:
        try:
            model = model_from_message(msg, source=f"skeleton_model from {self.skeleton_model.envelope.sender}")
        except ModelFileError as exc:
            self.log.error("%s; keeping the previous model", exc)
            return
        self._use_model(model, f"skeleton_model from {self.skeleton_model.envelope.sender}")

    def on_marker_layout(self, msg: MarkerLayout) -> None:
        self._bind()

    def _use_model(self, model: ActorModel, source: str) -> None:
        self.model, self.model_source = model, source
        self._bind()

    def _bind(self) -> None:
        """Match the model to the stream's labels and (re)build the solver; refuse a mismatch."""
        layout = self.marker_layout.latest
        self.solver = None
        if self.model is None or layout is None:
            return
        try:
            where = marker_index(self.model, layout.name, layout.labels,
                                 source=f"marker stream of {layout.source or layout.name!r} (model: {self.model_source})")
        except ModelFileError as exc:
            key = (self.model.marker_fingerprint, layout.name + "\n" + "\n".join(layout.labels))
            if self._refused != key:  # once per model/layout pair, not per frame
                self.log.error("%s; publishing nothing until a matching model arrives", exc)
                self._refused = key
            return
        self._refused = None
        if layout.name and layout.name != self.model.layout:
            self.log.warning("model layout '%s' used on marker layout '%s' (every marker found by label)",
                             self.model.layout, layout.name)
        self.where = where
        self.absent = where < 0  # static-only markers the stream does not carry
        self.n_stream = len(layout.labels)
        self.identity = bool(len(where) == self.n_stream and (where == np.arange(len(where))).all())
        self._lowpass = self._new_lowpass(len(where))
        self.solver = self._new_solver(self.model, max_gap_s=self.max_gap_s, enforce_lengths=self.enforce_lengths,
                                       filter=self.filter or None, fit=self.fit,
                                       noise_scale=self._lowpass.noise_gain if self._lowpass else 1.0)
        self._last_t = -np.inf
        self.log.info("solving %d joints of layout '%s' (%s) from %d markers", len(self.model.joint_names),
                      self.model.layout, self.model_source, len(where))

    def _new_lowpass(self, n_markers: int):
        """The fixed-lag marker low-pass the params ask for, or None (off, or refused with a line)."""
        if self.lowpass_hz <= 0:
            return None
        from ..kinematics.solving.lowpass import FixedLagLowpass

        rate = float(self.lowpass_rate_hz or self.model.rate_hz or 0.0)
        if rate <= 0:
            self.log.error("lowpass needs the stream's rate: the model carries none, so set lowpass_rate_hz; "
                           "solving unfiltered frames")
            return None
        try:
            lp = FixedLagLowpass(n_markers, rate, self.lowpass_hz, round(self.lowpass_lag_s * rate))
        except ValueError as exc:
            self.log.error("lowpass at %g Hz with a %g s lag on a %g Hz stream: %s; solving unfiltered frames",
                           self.lowpass_hz, self.lowpass_lag_s, rate, exc)
            return None
        self.log.info("markers low-passed at %g Hz, poses %d frames (%.3f s) late", self.lowpass_hz, lp.lag,
                      lp.lag / rate)
        return lp

    # ----- frames -------------------------------------------------------------------------------
    def on_markers(self, frame: MarkerFrame) -> None:
        solver = self.solver
        if solver is None:
            self._skipped += 1
            return
        env = self.markers.envelope
        number, capture_ns = frame.frame_number, env.capture_ns
        x = self._placed(frame)
        if x is None:
            if self._lowpass is None:
                self.actor_pose.publish(missing_pose(self.model, self.actor, number), capture_ns)
                return
            x = np.full((len(self.where), 3), np.nan)   # keeps its place in the delayed stream
        if self._t0_ns is None:
            self._t0_ns = capture_ns
        t = (capture_ns - self._t0_ns) * 1e-9
        if t < self._last_t:
            solver.reset()  # a replay looped: old velocities and filter state do not apply
            if self._lowpass is not None:
                self._lowpass.reset()
        self._last_t = t
        if self._lowpass is not None:
            got = self._lowpass.push(x, (number, capture_ns, t))
            if got is None:
                return
            x, (number, capture_ns, t) = got
        try:
            res = solver.step(x, t)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            self._failures += 1
            if self._failures <= 5 or self._failures % 1000 == 0:
                self.log.error("frame %d could not be solved (%s): joints marked missing", number, exc)
            self.actor_pose.publish(missing_pose(self.model, self.actor, number), capture_ns)
            return
        self.actor_pose.publish(pose_message(res, self.actor, number), capture_ns)

    def _placed(self, frame: MarkerFrame) -> np.ndarray | None:
        """float[M,3] in the model's marker order (NaN unseen or invalid); None: a frame of the wrong size."""
        pos = frame.positions
        if pos.shape[0] != self.n_stream:
            self._bad_frames += 1
            if self._bad_frames <= 5 or self._bad_frames % 1000 == 0:
                self.log.warning("frame %d has %d markers, the marker layout %d: joints marked missing "
                                 "(%d such frames)", frame.frame_number, pos.shape[0], self.n_stream,
                                 self._bad_frames)
            return None
        x = pos if self.identity else pos[self.where]
        seen = np.isfinite(x).all(1) & ~self.absent
        if frame.valid.shape == (pos.shape[0],):
            seen &= frame.valid if self.identity else frame.valid[self.where]
        if not seen.all():
            x = np.where(seen[:, None], x, np.nan)
        return x
