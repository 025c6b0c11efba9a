"""Random virtual limb chains for accuracy tests: varied clusters, joint types and ranges of motion.

A generalisation of :mod:`mocapgraph.testing.arm_jig` (issue 27's "virtual arm a new user would
try"): four rigid segments in a chain (clavicle, upper arm, forearm, hand by default), each with
2-5 markers placed at random (a cluster of a given size off the segment's long axis, or nearly
in a line), ball or hinge joints, a range-of-motion trial sweeping every joint by a given angle
and held test poses. Pure forward kinematics with exact joint positions (metres, world Z up).
A hinge turns about its child segment's local z, which is normal to both bones (so the
shoulder-elbow-wrist plane rule of the calibration holds, as for an anatomical hinge).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

NAMES = ("clavicle", "upper_arm", "forearm", "hand")
JOINTS = ("shoulder", "elbow", "wrist")
BONES = (0.17, 0.29, 0.255, 0.09)
ORIGIN = np.array([0.0, 0.2, 1.4])


@dataclass
class Jig:
    """One random chain: markers in each segment's frame, joint kinds and base rotations."""

    bones: np.ndarray          # float[S] m, along each segment's local x
    local: list[np.ndarray]    # per segment float[K_s,3] m, marker positions in its frame
    hinge: np.ndarray          # bool[S-1]: joint s (between segment s and s+1) is a hinge
    base: np.ndarray           # float[S,3,3] world rotations of the base pose
    collinear: np.ndarray      # bool[S]: this segment's cluster is nearly a line

    def layout(self) -> dict:
        """The marker layout dict of this jig (markers S<s>M<k>)."""
        limbs = []
        for s, name in enumerate(NAMES[: len(self.bones)]):
            limb = {"name": name, "markers": [f"S{s}M{k}" for k in range(len(self.local[s]))]}
            if s:
                limb["parent"] = NAMES[s - 1]
                limb["joint"] = {"name": JOINTS[s - 1], "type": "hinge" if self.hinge[s - 1] else "ball"}
            if len(self.local[s]) < 3:
                # Two markers cannot fix a segment: the layout names a joint whose centre, seen from
                # the neighbour, is its third fit point (the neighbour has three or more markers).
                near = [s - 1] if s > 0 and len(self.local[s - 1]) >= 3 else []
                near += [s] if s + 1 < len(self.local) and len(self.local[s + 1]) >= 3 else []
                limb["joint_points"] = [JOINTS[near[0]]]
            limbs.append(limb)
        return {"name": "random_jig", "description": "random virtual limb chain", "limbs": limbs}

    def chain(self, local_rot: np.ndarray) -> np.ndarray:
        """World rotations [T,S,3,3] from each segment's rotation in its own frame [T,S,3,3]."""
        world = np.empty_like(local_rot)
        world[:, 0] = self.base[0] @ local_rot[:, 0]
        for s in range(1, len(self.bones)):
            world[:, s] = world[:, s - 1] @ (self.base[s - 1].T @ self.base[s]) @ local_rot[:, s]
        return world

    def forward(self, world: np.ndarray, origin: np.ndarray = ORIGIN) -> tuple[np.ndarray, np.ndarray]:
        """Markers [T,M,3] (layout order) and joints [T,S-1,3] from world rotations [T,S,3,3]."""
        T, S = world.shape[:2]
        starts = np.zeros((T, S + 1, 3))
        starts[:, 0] = origin
        for s in range(S):
            starts[:, s + 1] = starts[:, s] + world[:, s] @ np.array([self.bones[s], 0.0, 0.0])
        pts = [starts[:, s, None, :] + np.einsum("tij,kj->tki", world[:, s], self.local[s]) for s in range(S)]
        return np.concatenate(pts, axis=1), starts[:, 1:S].copy()

    def _axes(self) -> np.ndarray:
        axes = np.ones((len(self.bones), 3))
        axes[1:][self.hinge] = [0.0, 0.0, 1.0]
        return axes

    def rom_trial(self, rng: np.random.Generator, n: int, rom_deg: np.ndarray | float) -> np.ndarray:
        """World rotations [n,S,3,3] sweeping each segment about each free local axis by
        ``rom_deg`` peak to peak (per segment or one value), from the base pose at frame 0."""
        S = len(self.bones)
        amp = np.radians(np.broadcast_to(np.asarray(rom_deg, dtype=float), (S,)))[:, None] / 2.0
        t = np.linspace(0.0, 1.0, n)[:, None, None]
        freq = rng.uniform(1.0, 3.0, size=(S, 3))
        phase = rng.uniform(0.0, 2.0 * np.pi, size=(S, 3))
        # amp * (sin - sin(phase)): frame 0 is the base pose; the sweep covers 2 * amp.
        ang = amp * (np.sin(2 * np.pi * freq * t + phase) - np.sin(phase)) * self._axes()
        local = Rotation.from_rotvec(ang.reshape(-1, 3)).as_matrix().reshape(n, S, 3, 3)
        return self.chain(local)

    def test_poses(self, rng: np.random.Generator, n: int, max_deg: float = 40.0) -> np.ndarray:
        """World rotations [n,S,3,3]: every segment turned by 15..max_deg about a random (free) axis."""
        S = len(self.bones)
        ang = np.radians(rng.uniform(15.0, max_deg, size=(n, S)))
        ax = rng.normal(size=(n, S, 3)) * self._axes()
        ax /= np.linalg.norm(ax, axis=-1, keepdims=True)
        local = Rotation.from_rotvec((ax * ang[..., None]).reshape(-1, 3)).as_matrix().reshape(n, S, 3, 3)
        return self.chain(local)


def _cluster(rng: np.random.Generator, bone: float, n: int, size: float | None, collinear: bool) -> np.ndarray:
    """n marker positions [n,3] in a segment frame. ``size`` None: spread along the segment
    (10-90 % of its length), each 4-7 cm off its long axis in a random direction (issue 27's
    arm); a size (m): a cluster that wide centred 4-7 cm off the axis; ``collinear``: on a line
    6 cm long and 4 mm wide, 4-7 cm off the axis."""
    d = rng.normal(size=2)
    d = d / np.linalg.norm(d)
    centre = np.array([rng.uniform(0.3, 0.8) * bone, *(rng.uniform(0.04, 0.07) * d)])
    if collinear:
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        t = np.linspace(-0.5, 0.5, n) * 0.06
        perp = rng.normal(size=(n, 3))
        perp -= np.outer(perp @ u, u)
        perp *= 0.002 / np.maximum(np.linalg.norm(perp, axis=1, keepdims=True), 1e-12)
        return centre + t[:, None] * u + perp
    if size is None:
        x = (np.sort(rng.uniform(0.1, 0.9, size=n)) * 0.5 + np.linspace(0.05, 0.45, n)) * bone
        ang = rng.uniform(0.0, 2.0 * np.pi, size=n)
        r = rng.uniform(0.04, 0.07, size=n)
        return np.stack([x, r * np.cos(ang), r * np.sin(ang)], axis=1)
    while True:
        pts = centre + rng.uniform(-0.5, 0.5, size=(n, 3)) * size
        gaps = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(n)
        if gaps.min() > 0.25 * size:  # markers apart: no two on one spot
            return pts


def random_jig(rng: np.random.Generator, n_markers: int | tuple[int, int] = 3,
               size: float | tuple[float, float] | None = None, hinge_share: float | tuple[bool, ...] = 0.0,
               collinear: int | None = None, bones: tuple[float, ...] = BONES) -> Jig:
    """A random chain: ``n_markers`` per segment (or a range), cluster sizes (m, or a range;
    None: markers along the segment as in issue 27's arm),
    each joint a hinge with probability ``hinge_share`` (or the joints named hinges by a tuple of bools); ``collinear``: the segment whose
    cluster is nearly a line (None: none)."""
    S = len(bones)
    lo_n, hi_n = (n_markers, n_markers) if isinstance(n_markers, int) else n_markers
    lo_s, hi_s = (size, size) if size is None or isinstance(size, float) else size
    hinge = (np.array(hinge_share, dtype=bool) if isinstance(hinge_share, tuple)
             else rng.random(S - 1) < hinge_share)
    coll = np.zeros(S, dtype=bool)
    if collinear is not None:
        coll[collinear] = True
    local = []
    counts = rng.integers(lo_n, hi_n + 1, size=S)
    for s in range(1, S):   # no two two-marker segments side by side (neither could frame the other)
        if counts[s] < 3 and counts[s - 1] < 3:
            counts[s] = 3
    for s in range(S):
        n = int(counts[s])
        sz = None if lo_s is None else float(rng.uniform(lo_s, hi_s))
        local.append(_cluster(rng, bones[s], n, sz, bool(coll[s])))
    rel = [Rotation.random(random_state=rng).as_matrix()]
    for s in range(1, S):
        if hinge[s - 1]:
            rel.append(Rotation.from_euler("z", rng.uniform(-80, -20), degrees=True).as_matrix())
        else:
            rel.append(Rotation.from_euler("xyz", rng.uniform(-40, 40, size=3), degrees=True).as_matrix())
    base = np.empty((S, 3, 3))
    base[0] = rel[0]
    for s in range(1, S):
        base[s] = base[s - 1] @ rel[s]
    return Jig(np.asarray(bones, dtype=float), local, hinge, base, coll)


def true_model(model, base_markers: np.ndarray, base_joints: np.ndarray, noise: float):
    """A calibrated ActorModel with a jig's true geometry in its place (base markers [M,3] and
    joints [J,3] of the base pose: frame 0 of a trial) and every limb's RMS at the true marker
    noise (m): the global fit is then the maximum-likelihood fit, the floor of a per-frame fit."""
    idx = np.asarray(model.limb_markers)
    cen = np.array([base_markers[r[r >= 0]].mean(0) for r in idx])
    return dataclasses.replace(model, base_markers=base_markers.copy(), limb_centroid=cen,
                               joint_base=base_joints.copy(), offsets=base_joints[:, None] - cen[model.joint_limbs],
                               limb_rms=np.full(len(idx), float(noise)))


@dataclass
class ArmErrors:
    """Per-frame joint errors (m) on one of issue 27's arms, global fit, each float[frames,J]."""

    poses: np.ndarray          # five held poses, one frame each, calibrated model
    trial: np.ndarray          # a fresh 240-frame 60-degree trial, calibrated model
    poses_ml: np.ndarray       # the same five frames by the true model at maximum-likelihood weights
    trial_ml: np.ndarray       # the same trial by the true model: the floor of any one-frame fit
    held_lowpass: np.ndarray   # each pose held 0.5 s (60 frames), low-passed per hold, calibrated model
    trial_lowpass: np.ndarray  # the trial low-passed (cutoff by cross-validation), calibrated model
    trial_lowpass_unc: np.ndarray  # the uncertainty the solver reported on the low-passed trial (m)
    cutoff_hz: tuple[float, float]  # the cutoffs chosen: held poses (median), trial


def issue_arm(seed: int, collinear: int | None = None, hold_frames: int = 60) -> ArmErrors:
    """Issue 27's arm (1 mm noise, calibrated on a 1440-frame 70-degree gym) solved frame by frame
    and after a zero-lag low-pass of its markers (:mod:`mocapgraph.kinematics.solving.lowpass`)."""
    import warnings

    from mocapgraph.kinematics.calibration.calibrate import CalibrationWarning, calibrate
    from mocapgraph.kinematics.skeleton import SkeletonDefinition
    from mocapgraph.kinematics.solving.lowpass import lowpass_markers
    from mocapgraph.kinematics.solving.solver import FrameSolver

    rng = np.random.default_rng(seed)
    jig = random_jig(rng, collinear=collinear)
    definition = SkeletonDefinition.from_layout_dict(jig.layout(), "random_jig")
    clean, joints = jig.forward(jig.rom_trial(rng, 1440, 70.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        model = calibrate(definition, clean + rng.normal(scale=0.001, size=clean.shape), rate_hz=120.0)
    pose_clean, pose_j = jig.forward(jig.test_poses(rng, 5), origin=np.array([0.3, -0.1, 1.2]))
    pose_m = pose_clean + rng.normal(scale=0.001, size=pose_clean.shape)
    c2, j2 = jig.forward(jig.rom_trial(rng, 240, 60.0))
    c2 = c2 + rng.normal(scale=0.001, size=c2.shape)
    held = np.repeat(pose_clean, hold_frames, axis=0)
    held = held + rng.normal(scale=0.001, size=held.shape)

    def errors(m, x, j, noise_scale=1.0):
        res = FrameSolver(m, max_gap_s=0, fit="global", noise_scale=noise_scale).solve(x)
        return np.linalg.norm(res.joints - j, axis=-1), res.joint_uncertainty

    ml = true_model(model, clean[0], joints[0], 0.001)
    holds = [lowpass_markers(h, 120.0) for h in np.split(held, len(pose_clean))]
    trial_lp, report = lowpass_markers(c2, 120.0)
    trial_lp_err, trial_lp_unc = errors(model, trial_lp, j2, report.noise_gain)
    return ArmErrors(
        poses=errors(model, pose_m, pose_j)[0], trial=errors(model, c2, j2)[0],
        poses_ml=errors(ml, pose_m, pose_j)[0], trial_ml=errors(ml, c2, j2)[0],
        held_lowpass=np.concatenate([errors(model, h, np.repeat(pose_j[k:k + 1], hold_frames, axis=0), r.noise_gain)[0]
                                     for k, (h, r) in enumerate(holds)]),
        trial_lowpass=trial_lp_err, trial_lowpass_unc=trial_lp_unc,
        cutoff_hz=(float(np.median([r.cutoff_hz for _, r in holds])), float(report.cutoff_hz)))
