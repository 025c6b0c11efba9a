"""Physics tracker as a node: simulated characters following CharacterPose streams on a stage.

Each character named by a ``CharacterInfo`` (latched) gets a body in one shared MuJoCo world
(:mod:`mocapgraph.physics`); its ``CharacterPose`` frames become targets (missing joints filled from
the posture database when one is given) and the world steps by the capture-time span between the
first character's frames. When every stream stops the world keeps stepping in wall time, so the
characters stand and wait (and still react to pushes and balls), and follow again when data
returns. Out every step: ``physics_state`` (every capsule and stage object: pose, tracking error),
``sim_character_pose`` (each simulated character as a CharacterPose named ``NAME/physical``); latched
``physics_scene`` (shapes and sizes), ``sim_character_info`` and ``physics_status`` (figures).

Commands on ``physics_command`` (NodeCommand, target '' or this node, args JSON):
``push {character: 0, joint: ShoulderCenter, force: [x, y, z] N, duration_s: 0.1}``,
``shoot {character: 0, joint: Head}`` or ``shoot {target: [x, y, z], speed: m/s}``,
``hold`` / ``drop`` (held objects), ``dodge {on: true}``, ``reach {character, joint, geom}``,
``release {character, joint}`` (a reach), ``reset`` (every character back onto its target).

The simulated character's joints are flagged estimated (1) in its CharacterPose: the body's
answer to a target, not a measurement.
"""
from __future__ import annotations

import json
import time

import numpy as np

from ..bus import Input, Node, Output, Param
from ..jit import warm_all
from ..bus.node import NodeConfigError
from ..retarget.character import Character, CharacterError, checked_shift
from ..messages import CharacterInfo, CharacterPose, NodeCommand, NodeStatus, PhysicsScene, PhysicsState
from ..messages.commands import PHYSICS_COMMANDS, parse_command
from ..physics.controller import Gains
from ..physics.posture_db import PostureDB, PostureDBError, open_posture_db
from ..physics.stage import EMPTY_STAGE, StageError, load_stage, shifted
from ..physics.tracker import TargetConditioner
from ..physics.world import PhysicsWorld, TrackerParams

SUFFIX = "/physical"
PHYSICS_KERNELS = ("mocapgraph.physics.controller_kernels", "mocapgraph.physics.posture_kernels",
                   "mocapgraph.physics.state_kernels")


def _check_stage_offset(params: dict) -> None:
    """A stage shift that is not a place in the room (1e300) is refused by the check, not by MuJoCo."""
    try:
        checked_shift(params.get("stage_offset", [0.0, 0.0, 0.0]), "parameter 'stage_offset'")
    except CharacterError as exc:
        raise NodeConfigError(str(exc)) from None


class PhysicsTrackerNode(Node):
    """Simulated characters tracking their CharacterPose streams with bounded PD control."""

    summary = "MuJoCo characters tracking CharacterPose streams on a stage -> PhysicsState, CharacterPose"
    character_info = Input("character_info", CharacterInfo, "latched skeleton of each character", latched=True)
    character_pose = Input("character_pose", CharacterPose, "target poses, one stream per character")
    physics_command = Input("physics_command", NodeCommand, ", ".join(PHYSICS_COMMANDS), required=False)
    physics_scene = Output("physics_scene", PhysicsScene, "latched: every body's shape and size")
    physics_state = Output("physics_state", PhysicsState, "every body's pose and tracking error, each step")
    sim_character_pose = Output("sim_character_pose", CharacterPose, "each simulated character (NAME/physical)")
    sim_character_info = Output("sim_character_info", CharacterInfo, "latched skeleton of the simulated character")
    physics_status = Output("physics_status", NodeStatus, "latched figures: frames, forces, resets, step time",
                            latched=True)

    timestep = Param(1.0 / 240.0, "MuJoCo step, s", minimum=1e-4, maximum=0.02)
    kp = Param(2500.0, "Eq 1 elasticity gain Ke, N/m (one for all joints)", minimum=0.0)
    kd = Param(60.0, "Eq 1 damping gain Kd, N·s/m", minimum=0.0)
    kp_rot = Param(400.0, "Eq 2 elasticity gain per unit inertia, 1/s^2", minimum=0.0)
    kd_rot = Param(40.0, "Eq 2 damping gain per unit inertia, 1/s", minimum=0.0)
    max_force = Param(400.0, "bound on each joint's Eq 1 force, N", minimum=0.0)
    foot_max_force = Param(40.0, "bound on the Eq 1 force at the ankles and feet, N (a light foot driven "
                           "harder strikes into the floor)", minimum=0.0)
    trunk_max_force = Param(60.0, "bound on the Eq 1 force at the root, trunk joints and head, N (how hard "
                            "the body is held to its target: a push displaces it)", minimum=0.0)
    max_torque = Param(60.0, "bound on each body's Eq 2 torque, N·m", minimum=0.0)
    gravity_compensation = Param(0.5, "fraction of each body's weight held at its centre of mass", minimum=0.0,
                                 maximum=1.0)
    body_mass = Param(70.0, "mass of each character, kg", minimum=1.0)
    virtual_joints = Param(True, "pin supporting feet to the floor (Shum & Ho 6.1)")
    dodge = Param(False, "raise the forearms around the head when a ball comes at it")
    posture_db = Param("", "posture database (.npz from mocapgraph posture-db build), or synthetic:CLIPS to "
                       "build one at start (e.g. synthetic:gym,reach,turn,kick); empty: none")
    stage = Param("", "stage YAML or shipped stage name (graph_configs/stages: claro_pole, balls, mace); "
                  "empty: the floor only")
    stage_offset = Param([0.0, 0.0, 0.0], "move the whole stage by this much, m (with a retargeter offset)")
    characters = Param([], "character names to simulate, in world order; empty: every one that appears")
    stale_s = Param(0.25, "no frame for this long: keep simulating in wall time (stand and wait), s",
                    minimum=0.01)
    max_lag_s = Param(0.05, "a frame published longer ago than this only updates the target (the node "
                      "was behind: it catches up instead of queueing latency), s", minimum=0.0)

    graph_check = classmethod(lambda cls, params: _check_stage_offset(params))

    def __init__(self, name: str, params: dict | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.graph_check(self.params)
        self.chars: dict[str, Character] = {}
        self.order: list[str] = []
        self.world: PhysicsWorld | None = None
        self.cond: list[TargetConditioner] = []
        self.started_pose: list[bool] = []
        self.last_capture_ns: int | None = None
        self.last_step_wall = time.monotonic()
        self.last_frame_wall = -np.inf
        self.frames = 0
        self.skipped = 0
        self.step_ms: list[float] = []
        self.db: PostureDB | None = None
        self.stage_def = EMPTY_STAGE
        self.failed = ""
        gains = Gains(self.kp, self.kd, self.kp_rot, self.kd_rot, self.max_force, self.max_torque)
        self.tracker_params = TrackerParams(timestep=self.timestep, gains=gains, body_mass=self.body_mass,
                                            virtual_joints=self.virtual_joints, dodge=self.dodge,
                                            gravity_compensation=self.gravity_compensation,
                                            foot_max_force=self.foot_max_force,
                                            trunk_max_force=self.trunk_max_force)
        # load the compiled kernels now (numba's first call in a process costs ~0.5 s even from its
        # cache): on the first frame it would put the node that far behind its stream
        warm_all(PHYSICS_KERNELS)
        try:
            self.db = open_posture_db(self.posture_db)
            if self.stage:
                self.stage_def = shifted(load_stage(self.stage), self.stage_offset)
        except (PostureDBError, StageError, ValueError) as exc:
            self.failed = str(exc)

    def on_start(self) -> None:
        if self.failed:
            self.log.error("%s; simulating without it", self.failed)
        self.add_timer(1.0 / 60.0, self._idle)
        self.add_timer(0.5, self._publish_status)

    # ----- characters ---------------------------------------------------------------------------
    def on_character_info(self, msg: CharacterInfo) -> None:
        name = msg.character
        if name.endswith(SUFFIX) or (self.characters and name not in self.characters):
            return
        n = len(msg.joint_names)
        try:
            rest = msg.rest_rotations if msg.rest_rotations.shape == (n, 4) else np.tile([1.0, 0, 0, 0], (n, 1))
            ch = Character(name, tuple(msg.joint_names), msg.joint_parent.astype(np.int64), msg.rest_offsets, rest)
        except CharacterError as exc:
            self.log.error("character %s refused: %s", name, exc)
            return
        old = self.chars.get(name)
        if old is not None and old.joint_names == ch.joint_names and np.allclose(old.rest_offsets, ch.rest_offsets) \
                and np.allclose(old.rest_rotations, ch.rest_rotations):
            return
        self.chars[name] = ch
        if name not in self.order:
            self.order.append(name)
        if self.characters:
            self.order.sort(key=lambda c: list(self.characters).index(c))
        self._build()

    def _build(self) -> None:
        chars = [self.chars[n] for n in self.order]
        try:
            self.world = PhysicsWorld(chars, self.stage_def, self.tracker_params)
        except ValueError as exc:
            self.log.error("cannot build the physics world: %s", exc)
            self.world = None
            return
        self.cond = []
        for ch in chars:
            db = self.db if self.db is not None and tuple(self.db.joint_names) == ch.joint_names else None
            if self.db is not None and db is None:
                self.log.warning("posture database joints do not match %s: no filling for it", ch.name)
            self.cond.append(TargetConditioner(ch, db))
        self.started_pose = [False] * len(chars)
        # a simulated joint is estimated (1): the body's answer to its target, never a measurement
        self._sim_quality = np.ones(max(c.n_joints for c in chars), dtype=np.int8)
        shapes, sizes = self.world.geom_shapes()
        self.physics_scene.publish(PhysicsScene(body_names=list(self.world.index.geom_names), shapes=list(shapes),
                                                sizes=sizes))
        for ch in chars:
            self.sim_character_info.publish(CharacterInfo(character=ch.name + SUFFIX, joint_names=list(ch.joint_names),
                                                          joint_parent=ch.parents.astype(np.int32),
                                                          rest_offsets=ch.rest_offsets,
                                                          rest_rotations=ch.rest_rotations))
        self.log.info("physics world: %s on stage %s (%d bodies, %d DOF, timestep %.4f s)",
                      ", ".join(self.order), self.stage_def.name, self.world.model.nbody, self.world.model.nv,
                      self.timestep)

    # ----- frames -------------------------------------------------------------------------------
    def on_character_pose(self, msg: CharacterPose) -> None:
        w = self.world
        if w is None or msg.character not in self.order:
            return
        k = self.order.index(msg.character)
        ch = self.chars[msg.character]
        if msg.joint_positions.shape != (ch.n_joints, 3) or msg.local_rotations.shape != (ch.n_joints, 4):
            self.log.warning("frame %d of %s has %d joints, the character %d: skipped", msg.frame_number,
                             msg.character, msg.joint_positions.shape[0], ch.n_joints)
            return
        env = self.character_pose.envelope
        q = msg.joint_quality if msg.joint_quality.shape == (ch.n_joints,) else None
        c = self.cond[k].condition(msg.joint_positions, msg.local_rotations, msg.root_position, q)
        if not self.started_pose[k] and not c.held and np.isfinite(msg.local_rotations).all() \
                and np.isfinite(msg.root_position).all():
            w.set_pose(k, msg.local_rotations, msg.root_position)
            self.started_pose[k] = True
        t = env.capture_ns * 1e-9
        if not c.held:
            w.set_target(k, c.positions, c.orientations, t)
        self.last_frame_wall = time.monotonic()
        if k == 0:
            if time.time_ns() - env.publish_ns > self.max_lag_s * 1e9:
                self.skipped += 1  # behind: take the target, step on a fresh frame
                return
            dt = 1.0 / 120.0 if self.last_capture_ns is None else (env.capture_ns - self.last_capture_ns) * 1e-9
            self.last_capture_ns = env.capture_ns
            if not 0.0 < dt < 0.1:  # a replay looped or a gap: one nominal frame, never a leap
                dt = 1.0 / 120.0
            # after skipped frames, catch up on their time too (bounded: a starved node may lag)
            self._step(min(dt, 4.0 / 120.0), env.capture_ns)

    def _idle(self) -> None:
        if self.world is None:
            return
        now = time.monotonic()
        if now - self.last_frame_wall > self.stale_s and now - self.last_step_wall > 1.0 / 90.0:
            self._step(min(now - self.last_step_wall, 0.05), None)

    def _step(self, dt: float, capture_ns: int | None) -> None:
        w = self.world
        t0 = time.perf_counter()
        resets = w.resets
        w.step(dt)
        if w.resets != resets:
            self.log.warning("the simulation went unstable (gains too high for the timestep?): every character "
                             "is put back on its next target (%d resets)", w.resets)
            self.started_pose = [False] * len(self.order)
        self.step_ms.append((time.perf_counter() - t0) * 1e3)
        if len(self.step_ms) > 1000:
            del self.step_ms[:500]
        self.last_step_wall = time.monotonic()
        self.frames += 1
        pos, quat, err = w.geom_state()
        self.physics_state.publish(PhysicsState(sim_time_s=float(w.data.time), positions=pos, orientations=quat,
                                                tracking_error=err), capture_ns)
        for k, name in enumerate(self.order):
            local, root = w.local_rotations(k)
            self.sim_character_pose.publish(CharacterPose(character=name + SUFFIX, frame_number=self.frames,
                                                          root_position=root, local_rotations=local,
                                                          joint_positions=w.joint_positions(k),
                                                          joint_quality=self._sim_quality), capture_ns)

    def _publish_status(self) -> None:
        w = self.world
        data = {"characters": self.order, "frames": self.frames, "skipped_behind": self.skipped}
        if w is not None:
            err = w.tracking_error()
            data.update(max_force_n=w.control.max_applied_force, max_torque_nm=w.control.max_applied_torque,
                        force_bound_n=self.max_force, torque_bound_nm=self.max_torque, resets=w.resets,
                        mean_error_m=float(np.nanmean(err)) if np.isfinite(err).any() else None,
                        finite=bool(np.isfinite(w.data.qpos).all()), sim_time_s=float(w.data.time),
                        step_ms_median=float(np.median(self.step_ms)) if self.step_ms else None,
                        pins=[bool(x) for x in w.pins.on], filled_frames=[c.filled_frames for c in self.cond],
                        held_frames=[c.held_frames for c in self.cond])
        state = "tracking" if w is not None and time.monotonic() - self.last_frame_wall < self.stale_s else "waiting"
        self.physics_status.publish(NodeStatus(node=self.name, state=state, detail=self.failed,
                                               progress=float("nan"), data_json=json.dumps(data)))

    # ----- commands -----------------------------------------------------------------------------
    def on_physics_command(self, cmd: NodeCommand) -> None:
        if cmd.target not in ("", self.name) or self.world is None:
            return
        w = self.world
        try:
            args = parse_command(cmd.command, cmd.args_json, PHYSICS_COMMANDS)
            k = int(args.get("character", 0))
            if not 0 <= k < len(self.order):
                raise ValueError(f"character {k}: the world has {len(self.order)}")
            c = cmd.command
            if c == "push":
                w.push(k, args.get("joint", "ShoulderCenter"), np.asarray(args["force"], float),
                       float(args.get("duration_s", 0.1)))
            elif c == "shoot":
                if "target" in args:
                    target = np.asarray(args["target"], float)
                else:
                    j = self.chars[self.order[k]].index(args.get("joint", "Head"))
                    target = w.joint_positions(k)[j]
                w.shoot(target, args.get("speed"))
            elif c in ("hold", "drop"):
                w.set_held(c == "hold")
            elif c == "dodge":
                w.params.dodge = bool(args.get("on", True))
            elif c == "reach":
                w.reach(k, args["joint"], f"stage/{args['geom']}")
            elif c == "release":
                w.set_override(k, args["joint"], None)
            elif c == "reset":
                self.started_pose = [False] * len(self.order)
        except (KeyError, ValueError, TypeError) as exc:
            self.log.warning("physics command %r refused: %s", cmd.command, exc)
