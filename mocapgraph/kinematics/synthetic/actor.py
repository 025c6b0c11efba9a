"""Synthetic actor: labelled marker trajectories of a scripted human with exact ground truth.

The embedded default data source. A parametric body (:mod:`synthetic_body`, height and segment
ratios) moves through a scripted session (:mod:`synthetic_motion`: base-pose hold, range-of-motion
gym, a walk / reach / turn / kick performance) and carries the markers of a layout
(:class:`SkeletonDefinition`), placed rigidly on each limb 3-13 cm off the bone axis in varied
directions so rigid fits are well conditioned.

Frames and units: metres, seconds, world Z up, X forward, Y left; quaternions (w, x, y, z). The base
pose is a T-pose; limb orientations are world rotations relative to the base pose (identity there).

Ground truth (never touched by noise, wobble, occlusion or swaps):

- ``joint_centres[t, j]`` joint centres; ``limb_quat[t, l]``; ``joint_quat[t, j]`` (child limb
  relative to parent limb, base-pose frame);
- ``joint_offsets[j, k]`` = base joint centre minus base centroid of limb ``joint_limbs[j, k]``'s
  fit-set markers (``limb_marker_index``, shared markers included), so that
  ``joint_centres[t, j] == limb_centroids[t, l] + R_l(t) @ joint_offsets[j, k]`` to rounding.

Markers shared across a hinge joint sit on that hinge's axis, so they are rigid with both limbs.
A marker shared across a ball joint rides its owner only; the borrowing limb then has
``limb_exact[l] == False`` (its marker centroid is not rigid with it).

Layouts bind to the body through limb names (``upper_leg_l``, ``thigh_l``, ``forearm_r``...; see
:func:`synthetic_body.segment_for_limb`). Body joints between two layout limbs that the layout
skips (the clavicle when the upper arm hangs from the thorax) are frozen, and a layout hinge on a
body ball joint keeps only its flexion DOF, so every layout joint stays a fixed point of both limbs.

Every frame is a closed-form function of its index: ``capture(start, stop)`` on any range equals
the same slice of the whole capture, noise included (Gaussian noise is drawn per 1024-frame block
from the seed; dropout, shadow and swap events are drawn once for the whole session).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.kinematics.layout import LayoutError
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.kinematics.synthetic.body import (
    CANON_JOINTS,
    SEGMENT_NAMES,
    SEGMENT_PARENT,
    SEGMENT_SIDE,
    BodyParams,
    build_geometry,
    joint_dofs,
    segment_for_limb,
)
from mocapgraph.kinematics.synthetic.motion import MotionScript

_NOISE_BLOCK = 1024


@dataclass(frozen=True)
class CaptureOptions:
    """Measurement imperfections; all off by default (exact data)."""

    noise_mm: float = 0.0          # Gaussian marker noise, std per axis, millimetres
    wobble_mm: float = 0.0         # soft-tissue wobble, RMS per axis in the limb frame, millimetres
    wobble_hz: tuple[float, float] = (0.2, 2.0)   # frequency band of the wobble
    dropout_rate_hz: float = 0.0   # random single-marker dropouts per marker per second
    dropout_mean_s: float = 0.08   # mean dropout length (exponential)
    shadow_rate_hz: float = 0.0    # limb-shadowing events per second (whole limb or some markers)
    shadow_s: tuple[float, float] = (0.2, 1.0)
    swap_rate_hz: float = 0.0      # label swaps (two markers of one limb or joined limbs) per second
    swap_s: tuple[float, float] = (0.1, 0.5)
    clean_base: bool = True        # keep the base-pose hold free of occlusions and swaps

    @property
    def exact(self) -> bool:
        return not (self.noise_mm or self.wobble_mm or self.dropout_rate_hz or self.shadow_rate_hz
                    or self.swap_rate_hz)


@dataclass(frozen=True, eq=False)
class SyntheticCapture:
    """Frames ``frames[0]..frames[-1]`` of a synthetic session with its exact ground truth."""

    skeleton: SkeletonDefinition
    rate: float                    # Hz
    frames: np.ndarray             # int64[T] frame numbers in the session (time = frame / rate)
    times: np.ndarray              # float64[T] seconds
    markers: np.ndarray            # float64[T, M, 3] m, NaN where not valid (measured: noise etc.)
    valid: np.ndarray              # bool[T, M]
    joint_centres: np.ndarray      # float64[T, J, 3] m, ground truth
    limb_quat: np.ndarray          # float64[T, L, 4] wxyz, world rotation relative to base pose
    joint_quat: np.ndarray         # float64[T, J, 4] wxyz, child relative to parent (base frame)
    limb_centroids: np.ndarray     # float64[T, L, 3] m, noise-free centroid of each limb's fit set
    base_markers: np.ndarray       # float64[M, 3] m, base pose (T-pose)
    base_joint_centres: np.ndarray  # float64[J, 3] m
    joint_offsets: np.ndarray      # float64[J, 2, 3] m, joint minus base limb centroid, base frame
    joint_dof_axes: np.ndarray     # float64[J, 3, 3] unit DOF axes (rows), base frame; NaN unused
    joint_dof_count: np.ndarray    # int64[J] 1 for hinges, 3 for ball joints
    joint_dof_names: tuple[tuple[str, ...], ...]
    joint_major: np.ndarray        # bool[J] joints the gym must turn >= 45 deg per DOF
    limb_exact: np.ndarray         # bool[L] False where a ball-joint-shared marker breaks rigidity
    phases: dict[str, tuple[int, int]]   # session phase -> [start, stop) frame numbers
    swaps: np.ndarray              # int64[K, 4] (start, stop, m1, m2) swap events in this chunk
    options: CaptureOptions = field(default_factory=CaptureOptions)
    seed: int = 0

    @property
    def stamps_ns(self) -> np.ndarray:
        """int64[T] capture time stamps, nanoseconds from session start."""
        return np.round(self.frames.astype(np.float64) * (1e9 / self.rate)).astype(np.int64)

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    def phase_slice(self, name: str) -> slice:
        """Indices into this capture's arrays covering session phase ``name`` (may be empty)."""
        a, b = self.phases[name]
        f0 = int(self.frames[0]) if self.n_frames else 0
        return slice(int(np.clip(a - f0, 0, self.n_frames)), int(np.clip(b - f0, 0, self.n_frames)))


class SyntheticActor:
    """A scripted actor wearing a marker layout; produce captures whole or in chunks.

    ``layout``: a layout name under graph_configs/marker_layouts, a path, or a SkeletonDefinition.
    ``duration_s``: session length; default one pass (base + gym + one performance loop, 37.5 s
    at the default script); longer sessions repeat the performance loop.
    """

    def __init__(self, layout: str | Path | SkeletonDefinition = "kiip_full_body", *,
                 rate: float = 120.0, duration_s: float | None = None, seed: int = 0,
                 body: BodyParams | None = None, proportion_jitter: float = 0.0,
                 script: MotionScript | None = None, options: CaptureOptions | None = None) -> None:
        self.skeleton = layout if isinstance(layout, SkeletonDefinition) else SkeletonDefinition.from_layout_file(layout)
        if rate <= 0:
            raise ValueError(f"synthetic actor: rate must be > 0 Hz, got {rate}")
        self.rate = float(rate)
        self.seed = int(seed)
        self.script = script or MotionScript()
        self.options = options or CaptureOptions()
        self.duration_s = float(duration_s) if duration_s is not None else self.script.one_pass_s
        self.n_frames = int(round(self.duration_s * self.rate))
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 1]))
        params = body or BodyParams()
        if proportion_jitter:
            params = params.scaled(proportion_jitter, rng)
        self.body = params
        self.geometry = build_geometry(params)
        self._bind_layout(rng)
        self._build_phases()
        self._draw_events()

    # ------------------------------------------------------------------ binding
    def _bind_layout(self, rng: np.random.Generator) -> None:
        sk = self.skeleton
        geo = self.geometry
        self.limb_segment = _limb_segments(sk)
        dof_mask, axes, counts, names, major = _joint_dofs(sk, self.limb_segment)
        self._dof_mask = dof_mask
        self.joint_dof_axes, self.joint_dof_count = axes, counts
        self.joint_dof_names, self.joint_major = tuple(names), major
        base, ball_shared_limbs = _place_markers(sk, geo, self.limb_segment, axes, rng)
        self.base_markers = base
        owner_seg = self.limb_segment[sk.marker_limb]
        self._marker_seg = owner_seg
        self.limb_exact = np.array([l not in ball_shared_limbs for l in range(sk.n_limbs)])

        fit = [list(sk.limb_markers(l)) for l in range(sk.n_limbs)]
        self.base_centroids = np.array([base[f].mean(axis=0) for f in fit])
        self.base_joint_centres = geo.proximal[self.limb_segment[sk.joint_limbs[:, 1]]] if sk.n_joints else np.zeros((0, 3))
        self.joint_offsets = (self.base_joint_centres[:, None, :]
                              - self.base_centroids[sk.joint_limbs]) if sk.n_joints else np.zeros((0, 2, 3))
        self._fit_sets = fit

        # Wobble: three sinusoids per marker and axis, fixed by the seed.
        w = self.options
        self._wob_f = rng.uniform(*w.wobble_hz, size=(sk.n_markers, 3, 3))
        self._wob_p = rng.uniform(0, 2 * np.pi, size=(sk.n_markers, 3, 3))
        self._wob_a = rng.uniform(0.5, 1.5, size=(sk.n_markers, 3, 3))
        rms = np.sqrt(0.5 * (self._wob_a ** 2).sum(axis=2, keepdims=True))
        self._wob_a = self._wob_a / rms  # unit RMS per axis

    def _build_phases(self) -> None:
        ph: dict[str, tuple[int, int]] = {}
        fr = lambda t: int(min(self.n_frames, np.ceil(t * self.rate - 1e-9)))
        for name, a, b in self.script.timeline(self.duration_s):
            if fr(a) < self.n_frames:
                ph[name] = (fr(a), fr(b))
        g0 = self.script.base_s
        ph["gym"] = (fr(g0), fr(g0 + self.script.gym_s))
        ph["performance"] = (fr(g0 + self.script.gym_s), self.n_frames)
        self.phases = ph

    def _draw_events(self) -> None:
        o = self.options
        sk = self.skeleton
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 2]))
        n, rate = self.n_frames, self.rate
        lo = self.phases["base"][1] if o.clean_base else 0
        occ: list[tuple[int, int, int]] = []
        if o.dropout_rate_hz > 0:
            cnt = rng.poisson(o.dropout_rate_hz * self.duration_s, size=sk.n_markers)
            for m in range(sk.n_markers):
                st = rng.integers(lo, max(lo + 1, n), size=cnt[m])
                ln = np.maximum(1, np.round(rng.exponential(o.dropout_mean_s, size=cnt[m]) * rate)).astype(int)
                occ.extend((int(a), int(min(n, a + b)), m) for a, b in zip(st, ln))
        if o.shadow_rate_hz > 0:
            limb_sets = [list(np.flatnonzero(sk.marker_limb == l)) for l in range(sk.n_limbs)]
            for _ in range(rng.poisson(o.shadow_rate_hz * self.duration_s)):
                l = int(rng.integers(sk.n_limbs))
                ms = limb_sets[l]
                if not ms:
                    continue
                if rng.random() >= 0.5 and len(ms) > 1:
                    ms = list(rng.choice(ms, size=int(rng.integers(1, len(ms))), replace=False))
                a = int(rng.integers(lo, max(lo + 1, n)))
                b = int(min(n, a + max(1, round(rng.uniform(*o.shadow_s) * rate))))
                occ.extend((a, b, int(m)) for m in ms)
        self._occ = np.array(occ, dtype=np.int64).reshape(-1, 3)
        swaps = []
        if o.swap_rate_hz > 0 and sk.n_markers > 1:
            near = {l: {l} for l in range(sk.n_limbs)}
            for p, c in sk.joint_limbs:
                near[int(p)].add(int(c))
                near[int(c)].add(int(p))
            for _ in range(rng.poisson(o.swap_rate_hz * self.duration_s)):
                m1 = int(rng.integers(sk.n_markers))
                cand = [int(m) for m in np.flatnonzero(np.isin(sk.marker_limb, list(near[int(sk.marker_limb[m1])])))
                        if m != m1]
                m2 = int(rng.choice(cand))
                a = int(rng.integers(lo, max(lo + 1, n)))
                b = int(min(n, a + max(1, round(rng.uniform(*o.swap_s) * rate))))
                swaps.append((a, b, m1, m2))
        self._swaps = np.array(sorted(swaps), dtype=np.int64).reshape(-1, 4)

    # ------------------------------------------------------------------ evaluation
    def pose(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Body segment transforms at ``frames``: R [T,S,3,3] and t [T,S,3] with x_world = R x_base + t."""
        t = np.asarray(frames, dtype=np.float64) / self.rate
        ms = self.script.evaluate(t)
        ang = ms.angles * self._dof_mask[None]
        n = t.shape[0]
        S = len(SEGMENT_NAMES)
        geo = self.geometry
        R = np.empty((n, S, 3, 3))
        T = np.empty((n, S, 3))
        if n == 0:
            return R, T
        z, x, y = np.eye(3)[2], np.eye(3)[0], np.eye(3)[1]
        root = (Rotation.from_rotvec((ms.root_yaw + ms.root_local[:, 2])[:, None] * z)
                * Rotation.from_rotvec(ms.root_local[:, 1][:, None] * x)
                * Rotation.from_rotvec(ms.root_local[:, 0][:, None] * y))
        R[:, 0] = root.as_matrix()
        c0 = geo.proximal[0]
        T[:, 0] = c0 + ms.root_offset - R[:, 0] @ c0
        for s in range(1, S):
            p = SEGMENT_PARENT[s]
            dofs = joint_dofs(CANON_JOINTS[s - 1])
            q = Rotation.identity(n)
            for d in range(len(dofs)):
                q = Rotation.from_rotvec(ang[:, s - 1, d][:, None] * dofs[d].axis) * q
            R[:, s] = R[:, p] @ q.as_matrix()
            c = geo.proximal[s]
            J = R[:, p] @ c + T[:, p]
            T[:, s] = J - R[:, s] @ c
        return R, T

    def capture(self, start: int = 0, stop: int | None = None) -> SyntheticCapture:
        """Frames [start, stop) of the session (default: all of it)."""
        stop = self.n_frames if stop is None else int(stop)
        start = int(start)
        if not (0 <= start <= stop <= self.n_frames):
            raise ValueError(f"synthetic actor: frame range [{start}, {stop}) outside [0, {self.n_frames})")
        sk = self.skeleton
        frames = np.arange(start, stop, dtype=np.int64)
        n = frames.shape[0]
        R, T = self.pose(frames)
        Rl = R[:, self.limb_segment]
        Tl = T[:, self.limb_segment]
        jseg = self.limb_segment[sk.joint_limbs[:, 1]] if sk.n_joints else np.zeros(0, dtype=np.int64)
        joints = np.einsum("tjab,jb->tja", R[:, jseg], self.base_joint_centres) + T[:, jseg]
        cents = np.einsum("tlab,lb->tla", Rl, self.base_centroids) + Tl
        Rm = R[:, self._marker_seg]
        clean = np.einsum("tmab,mb->tma", Rm, self.base_markers) + T[:, self._marker_seg]
        limb_quat = _quat(Rl)
        local = np.einsum("tjba,tjbc->tjac", Rl[:, sk.joint_limbs[:, 0]], Rl[:, sk.joint_limbs[:, 1]])
        joint_quat = _quat(local)

        meas, valid, swaps = self._measure(frames, clean, Rm)
        return SyntheticCapture(
            skeleton=sk, rate=self.rate, frames=frames, times=frames / self.rate, markers=meas,
            valid=valid, joint_centres=joints, limb_quat=limb_quat, joint_quat=joint_quat,
            limb_centroids=cents, base_markers=self.base_markers.copy(),
            base_joint_centres=self.base_joint_centres.copy(), joint_offsets=self.joint_offsets.copy(),
            joint_dof_axes=self.joint_dof_axes.copy(), joint_dof_count=self.joint_dof_count.copy(),
            joint_dof_names=self.joint_dof_names, joint_major=self.joint_major.copy(),
            limb_exact=self.limb_exact.copy(), phases=dict(self.phases), swaps=swaps,
            options=self.options, seed=self.seed,
        )

    def chunks(self, chunk_frames: int) -> Iterator[SyntheticCapture]:
        """The whole session as consecutive captures of ``chunk_frames`` frames."""
        for a in range(0, self.n_frames, int(chunk_frames)):
            yield self.capture(a, min(self.n_frames, a + int(chunk_frames)))

    def _measure(self, frames, clean, Rm):
        o = self.options
        n, M = clean.shape[:2]
        X = clean.copy()
        if n == 0:
            return X, np.ones((0, M), bool), np.zeros((0, 4), np.int64)
        if o.wobble_mm:
            t = frames / self.rate
            ph = 2 * np.pi * self._wob_f[None] * t[:, None, None, None] + self._wob_p[None]
            w = (self._wob_a[None] * np.sin(ph)).sum(axis=3) * (o.wobble_mm * 1e-3)
            X += np.einsum("tmab,tmb->tma", Rm, w)
        if o.noise_mm:
            X += self._noise(int(frames[0]), int(frames[-1]) + 1) * (o.noise_mm * 1e-3)
        a0, b0 = int(frames[0]), int(frames[-1]) + 1
        valid = np.ones((n, M), dtype=bool)
        if len(self._occ):
            ev = self._occ[(self._occ[:, 0] < b0) & (self._occ[:, 1] > a0)]
            if len(ev):
                cnt = np.zeros((n + 1, M), dtype=np.int64)
                np.add.at(cnt, (np.clip(ev[:, 0] - a0, 0, n), ev[:, 2]), 1)
                np.add.at(cnt, (np.clip(ev[:, 1] - a0, 0, n), ev[:, 2]), -1)
                valid = np.cumsum(cnt, axis=0)[:n] == 0
        sw = self._swaps[(self._swaps[:, 0] < b0) & (self._swaps[:, 1] > a0)] if len(self._swaps) else np.zeros((0, 4), np.int64)
        for a, b, m1, m2 in sw:   # a handful of events per chunk, each a whole slice
            sl = slice(max(a, a0) - a0, min(b, b0) - a0)
            X[sl, [m1, m2]] = X[sl, [m2, m1]]
            valid[sl, [m1, m2]] = valid[sl, [m2, m1]]
        X[~valid] = np.nan
        return X, valid, sw.copy()

    def _noise(self, a: int, b: int) -> np.ndarray:
        """Unit Gaussian noise for frames [a, b), identical however the session is chunked."""
        M = self.skeleton.n_markers
        out = []
        for blk in range(a // _NOISE_BLOCK, (b - 1) // _NOISE_BLOCK + 1):
            g = np.random.default_rng(np.random.SeedSequence([self.seed, 3, blk]))
            z = g.standard_normal((_NOISE_BLOCK, M, 3))
            lo = max(a, blk * _NOISE_BLOCK) - blk * _NOISE_BLOCK
            hi = min(b, (blk + 1) * _NOISE_BLOCK) - blk * _NOISE_BLOCK
            out.append(z[lo:hi])
        return np.concatenate(out, axis=0)


def _limb_segments(sk: SkeletonDefinition) -> np.ndarray:
    """The body segment (index into SEGMENT_NAMES) each layout limb stands for, told by its name;
    LayoutError when a name says none or two limbs say one."""
    seg = []
    for name in sk.limb_names:
        s = segment_for_limb(name)
        if s is None:
            raise LayoutError(f"{sk.source}: limb `{name}`: the synthetic actor cannot tell which body "
                              "segment this is (use names like pelvis, thorax, head, clavicle_l, "
                              "upper_arm_l, forearm_l, hand_l, thigh_l, shank_l, foot_l)")
        if s in seg:
            raise LayoutError(f"{sk.source}: limb `{name}` maps to body segment `{s}` already used by "
                              f"`{sk.limb_names[seg.index(s)]}`")
        seg.append(s)
    return np.array([SEGMENT_NAMES.index(s) for s in seg], dtype=np.int64)


def _joint_dofs(sk: SkeletonDefinition, limb_segment: np.ndarray) -> tuple:
    """Which body DOFs each layout joint moves: (mask [canonical joint, 3] of the DOFs that move,
    axes [J,3,3], DOF count [J], DOF names per joint, major [J]); body joints between a layout
    joint's two segments are frozen (LayoutError when the segments do not hang from each other)."""
    n_cj = len(SEGMENT_NAMES) - 1
    dof_mask = np.ones((n_cj, 3))
    for k in range(n_cj):
        dof_mask[k, len(joint_dofs(CANON_JOINTS[k])):] = 0.0
    axes = np.full((sk.n_joints, 3, 3), np.nan)
    counts = np.zeros(sk.n_joints, dtype=np.int64)
    names: list[tuple[str, ...]] = []
    major = np.zeros(sk.n_joints, dtype=bool)
    for j in range(sk.n_joints):
        p, c = sk.joint_limbs[j]
        sp, sc = limb_segment[p], limb_segment[c]
        chain = []
        a = sc
        while a != sp and a >= 0:
            chain.append(a)
            a = SEGMENT_PARENT[a]
        if a != sp:
            raise LayoutError(f"{sk.source}: joint `{sk.joint_names[j]}`: body segment "
                              f"`{SEGMENT_NAMES[sc]}` does not hang from `{SEGMENT_NAMES[sp]}`")
        for frozen in chain[1:]:
            dof_mask[frozen - 1] = 0.0
        dofs = joint_dofs(CANON_JOINTS[sc - 1])
        ndof = 1 if sk.joint_hinge[j] else len(dofs)
        dof_mask[sc - 1, ndof:] = 0.0
        counts[j] = ndof
        names.append(tuple(d.name for d in dofs[:ndof]))
        for d in range(ndof):
            axes[j, d] = dofs[d].axis
        major[j] = dofs[0].major
    return dof_mask, axes, counts, names, major


def _place_markers(sk: SkeletonDefinition, geo: Any, limb_segment: np.ndarray, axes: np.ndarray,
                   rng: np.random.Generator) -> tuple[np.ndarray, set[int]]:
    """Base-pose marker positions (world frame, m) drawn on each limb's segment, hinge-shared ones on
    the hinge axis; and the limbs sharing a marker across a ball joint (their fit is not exact)."""
    # Marker placement (base pose, world frame).
    base = np.full((sk.n_markers, 3), np.nan)
    on_axis: dict[int, tuple[int, int]] = {}   # marker -> (layout joint, rank on that axis)
    ball_shared_limbs = set()
    joint_of_pair = {(int(p), int(c)): j for j, (p, c) in enumerate(sk.joint_limbs)}
    for l in range(sk.n_limbs):
        for m in (sk.limb_shared[l] if sk.limb_shared else ()):
            o = int(sk.marker_limb[m])
            j = joint_of_pair.get((o, l), joint_of_pair.get((l, o)))
            if sk.joint_hinge[j]:
                if m not in on_axis:
                    rank = sum(1 for v in on_axis.values() if v[0] == j)
                    on_axis[m] = (j, rank)
            else:
                ball_shared_limbs.add(l)
    for m, (j, rank) in on_axis.items():
        c = sk.joint_limbs[j, 1]
        s = limb_segment[c]
        axis = axes[j, 0]
        lateral = float(np.sign(axis[1] * SEGMENT_SIDE[s])) or 1.0
        sign = lateral if rank % 2 == 0 else -lateral
        r = rng.uniform(0.03, 0.055)
        base[m] = geo.proximal[s] + sign * r * axis
    for l in range(sk.n_limbs):
        s = limb_segment[l]
        own = [int(m) for m in np.flatnonzero(sk.marker_limb == l) if int(m) not in on_axis]
        if not own:
            continue
        P, D = geo.proximal[s], geo.distal[s]
        u = (D - P) / np.linalg.norm(D - P)
        ref = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(u, ref)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(u, e1)
        e2 *= np.sign(e2[2]) or 1.0
        k = len(own)
        along = rng.permutation(np.linspace(0.2, 0.85, k)) if k > 1 else np.array([0.5])
        az = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(k) / k + rng.uniform(-0.35, 0.35, k)
        rad = rng.uniform(*geo.radius[s], size=k)
        if SEGMENT_NAMES[s].startswith("foot"):
            az = np.arctan2(np.abs(np.sin(az)), np.cos(az))   # on the dorsum, never under the sole
        pos = P + along[:, None] * (D - P) + rad[:, None] * (np.cos(az)[:, None] * e1 + np.sin(az)[:, None] * e2)
        base[own] = pos
    return base, ball_shared_limbs


def _quat(mats: np.ndarray) -> np.ndarray:
    """wxyz quaternions (w >= 0) of rotation matrices [..., 3, 3]."""
    lead = mats.shape[:-2]
    if mats.size == 0:
        return np.zeros(lead + (4,))
    q = Rotation.from_matrix(mats.reshape(-1, 3, 3)).as_quat(scalar_first=True).reshape(lead + (4,))
    return np.where(q[..., :1] < 0, -q, q)


def synthesize(layout: str | Path | SkeletonDefinition = "kiip_full_body", **kwargs) -> SyntheticCapture:
    """Whole synthetic session in one call; keyword arguments as for :class:`SyntheticActor`."""
    return SyntheticActor(layout, **kwargs).capture()
