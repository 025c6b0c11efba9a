"""Motion script of the synthetic actor: per-frame local joint angles as analytic functions of time.

Every channel is a closed-form, C1 function of time (raised-cosine bumps and smoothstep ramps, which
have zero slope where they start and stop), so any frame range can be evaluated on its own and
chunks join exactly. Script (seconds at the defaults):

- ``base``   1 s     hold the T-pose (base pose, every marker visible)
- ``gym``    16 s    four blocks of 4 s: ``gym_dof0`` moves every joint's DOF 0 (flexion) to its
  upper then lower limit twice, ``gym_dof1`` / ``gym_dof2`` the same for DOF 1 / 2 of ball joints,
  ``gym_circle`` circles DOF 0 and 1 together with a swaying, turning pelvis (conditioning)
- ``performance`` 20.5 s, repeated until the requested duration: ``walk`` forward 5 s, ``reach``
  3 s, ``turn`` 180 deg 2.5 s, ``walk_back`` 5 s, ``kick`` 2.5 s, ``turn_back`` 2.5 s; a loop ends
  where it began (same place, heading + 360 deg), so loops join smoothly.

Angles are radians on the canonical joints of :mod:`synthetic_body` (``angles[t, k, d]`` is DOF
``d`` of joint ``CANON_JOINTS[k]``); the root (pelvis) gets a yaw, pitch/roll/twist and a
translation offset in metres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapgraph.kinematics.synthetic.body import CANON_JOINTS, joint_dofs

_JI = {n: k for k, n in enumerate(CANON_JOINTS)}
DEG = np.pi / 180.0


def smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def bump(x: np.ndarray) -> np.ndarray:
    """(1 - cos 2 pi x) / 2 on [0, 1], zero elsewhere: C1 everywhere, peak 1 at x = 0.5."""
    inside = (x >= 0.0) & (x <= 1.0)
    return np.where(inside, 0.5 * (1.0 - np.cos(2.0 * np.pi * np.clip(x, 0.0, 1.0))), 0.0)


def envelope(s: np.ndarray, d: float, r: float) -> np.ndarray:
    """1 on [r, d - r], smoothstep ramps of length r at both ends."""
    return smoothstep(s / r) * smoothstep((d - s) / r)


def envelope_integral(s: np.ndarray, d: float, r: float) -> np.ndarray:
    """Integral of :func:`envelope` from 0 to s (needs d >= 2 r)."""
    s = np.clip(s, 0.0, d)
    ramp = lambda x: r * (x ** 3 - 0.5 * x ** 4)  # integral of smoothstep(u / r), x = s / r
    up = ramp(np.clip(s / r, 0.0, 1.0))
    mid = np.clip(s - r, 0.0, d - 2 * r)
    down = np.where(s > d - r, 0.5 * r - ramp(np.clip((d - s) / r, 0.0, 1.0)), 0.0)
    return up + mid + down


@dataclass(frozen=True)
class MotionSample:
    angles: np.ndarray       # [T, Jc, 3] rad, canonical joint DOF angles
    root_yaw: np.ndarray     # [T] rad, heading about world Z
    root_local: np.ndarray   # [T, 3] rad, pelvis pitch (about Y), roll (about X), twist (about Z)
    root_offset: np.ndarray  # [T, 3] m, pelvis translation from its base position (world)


@dataclass(frozen=True)
class MotionScript:
    """Timing and sizes of the scripted motion (seconds, metres, m/s)."""

    base_s: float = 1.0
    gym_block_s: float = 4.0
    walk_s: float = 5.0
    reach_s: float = 3.0
    turn_s: float = 2.5
    kick_s: float = 2.5
    walk_speed: float = 1.1
    stride_s: float = 1.1
    gym_scale: float = 1.0    # multiplies every gym range (1.0: at least 45 deg per major DOF)

    @property
    def gym_s(self) -> float:
        return 4 * self.gym_block_s

    def performance_clips(self) -> tuple[tuple[str, float], ...]:
        return (("walk", self.walk_s), ("reach", self.reach_s), ("turn", self.turn_s),
                ("walk_back", self.walk_s), ("kick", self.kick_s), ("turn_back", self.turn_s))

    @property
    def loop_s(self) -> float:
        return sum(d for _, d in self.performance_clips())

    @property
    def one_pass_s(self) -> float:
        return self.base_s + self.gym_s + self.loop_s

    def timeline(self, duration_s: float) -> list[tuple[str, float, float]]:
        """(name, start, stop) seconds of every clip up to ``duration_s`` (repeat loops get ``#k``)."""
        out = [("base", 0.0, self.base_s)]
        t = self.base_s
        for name in ("gym_dof0", "gym_dof1", "gym_dof2", "gym_circle"):
            out.append((name, t, t + self.gym_block_s))
            t += self.gym_block_s
        k = 0
        while t < duration_s:
            for name, d in self.performance_clips():
                out.append((name if k == 0 else f"{name}#{k + 1}", t, t + d))
                t += d
            k += 1
        return out

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, t: np.ndarray) -> MotionSample:
        """All channels at times ``t`` (seconds, any order, any subset of the script)."""
        t = np.asarray(t, dtype=float)
        n = t.shape[0]
        ang = np.zeros((n, len(CANON_JOINTS), 3))
        yaw = np.zeros(n)
        loc = np.zeros((n, 3))
        off = np.zeros((n, 3))
        gym0 = self.base_s
        for b in range(4):
            t0 = gym0 + b * self.gym_block_s
            m = (t >= t0) & (t < t0 + self.gym_block_s)
            if m.any():
                self._gym_block(b, t[m] - t0, ang, loc, off, m)
        perf0 = gym0 + self.gym_s
        m = t >= perf0
        if m.any():
            self._performance(t[m] - perf0, ang, yaw, loc, off, m)
        return MotionSample(ang, yaw, loc, off)

    def _gym_block(self, b, s, ang, loc, off, m) -> None:
        d = self.gym_block_s
        g = self.gym_scale * DEG
        if b < 3:
            # DOF b of every joint: bump to hi, bump to lo, twice.
            u = s / (d / 4.0)
            k = np.floor(u).astype(int)
            shape = bump(u - k)
            for j, name in enumerate(CANON_JOINTS):
                dofs = joint_dofs(name)
                if b < len(dofs):
                    lim = np.where(k % 2 == 0, dofs[b].hi_deg, dofs[b].lo_deg)
                    ang[m, j, b] += g * lim * shape
        else:
            e = envelope(s, d, 0.8)
            ph = 2.0 * np.pi * 2.0 * s / d
            for j, name in enumerate(CANON_JOINTS):
                dofs = joint_dofs(name)
                if len(dofs) == 1:
                    ang[m, j, 0] += g * dofs[0].hi_deg * 0.5 * e * (1 - np.cos(ph))
                else:
                    for dd in (0, 1):
                        mid = 0.5 * (dofs[dd].hi_deg + dofs[dd].lo_deg)
                        amp = 0.35 * (dofs[dd].hi_deg - dofs[dd].lo_deg)
                        wave = np.sin(ph) if dd == 0 else np.cos(ph) - 1.0
                        ang[m, j, dd] += g * e * (mid * (1 - np.cos(ph)) * 0.5 + amp * wave)
            loc[m, 2] += e * 20 * DEG * np.sin(ph)
            loc[m, 1] += e * 8 * DEG * np.sin(2 * ph)
            off[m, 0] += e * 0.05 * np.sin(ph)
            off[m, 1] += e * 0.04 * np.sin(2 * ph)

    def _performance(self, s_all, ang, yaw, loc, off, m) -> None:
        idx = np.flatnonzero(m)
        L = self.loop_s
        k_loop = np.floor(s_all / L)
        s_loop = s_all - k_loop * L
        yaw[idx] += 2.0 * np.pi * k_loop
        # Arms come down from the T-pose for the whole loop, and go back up at its end.
        arms = envelope(s_loop, L, 1.0)
        for sd in ("l", "r"):
            ang[idx, _JI[f"shoulder_{sd}"], 1] += -75 * DEG * arms
            ang[idx, _JI[f"elbow_{sd}"], 0] += 20 * DEG * arms
        t0 = 0.0
        heading = 0.0
        for name, d in self.performance_clips():
            mm = (s_loop >= t0) & (s_loop < t0 + d)
            sel = idx[mm]
            s = s_loop[mm] - t0
            if name in ("walk", "walk_back"):
                self._walk(s, d, heading, sel, ang, loc, off)
                dist = self.walk_speed * envelope_integral(s_loop - t0, d, 0.8)
                # Distance covered so far by this walk, applied to every later frame of the loop.
                later = s_loop >= t0
                off[idx[later], 0] += np.cos(heading) * dist[later]
                off[idx[later], 1] += np.sin(heading) * dist[later]
            elif name == "reach":
                e = smoothstep(s / 1.0) * smoothstep((d - s) / 1.0)
                ang[sel, _JI["shoulder_r"], 0] += 85 * DEG * e
                ang[sel, _JI["shoulder_r"], 1] += 60 * DEG * e   # cancels most of the arms-down
                ang[sel, _JI["elbow_r"], 0] += -15 * DEG * e
                ang[sel, _JI["wrist_r"], 0] += -20 * DEG * e
                ang[sel, _JI["waist"], 0] += 20 * DEG * e
                ang[sel, _JI["waist"], 2] += 15 * DEG * e
                ang[sel, _JI["neck"], 0] += -10 * DEG * e
                ang[sel, _JI["shoulder_l"], 2] += 20 * DEG * e
            elif name in ("turn", "turn_back"):
                yaw_later = s_loop >= t0
                yaw[idx[yaw_later]] += np.pi * smoothstep((s_loop[yaw_later] - t0) / d)
                for sd, a in (("l", 0.0), ("r", 0.5)):
                    st = bump((s / d - a) * 2.0)
                    ang[sel, _JI[f"hip_{sd}"], 0] += 25 * DEG * st
                    ang[sel, _JI[f"knee_{sd}"], 0] += 45 * DEG * st
                    ang[sel, _JI[f"ankle_{sd}"], 0] += 10 * DEG * st
            elif name == "kick":
                ang[sel, _JI["hip_r"], 0] += 80 * DEG * bump(s / d)
                ang[sel, _JI["knee_r"], 0] += 80 * DEG * bump(s / (0.55 * d))
                ang[sel, _JI["ankle_r"], 0] += -25 * DEG * bump(s / d)
                ang[sel, _JI["knee_l"], 0] += 15 * DEG * bump(s / d)
                for sd in ("l", "r"):
                    ang[sel, _JI[f"shoulder_{sd}"], 1] += 35 * DEG * bump(s / d)
                ang[sel, _JI["waist"], 0] += -12 * DEG * bump(s / d)
                loc[sel, 0] += -8 * DEG * bump(s / d)
            t0 += d
            heading += np.pi if name.startswith("turn") else 0.0

    def _walk(self, s, d, heading, sel, ang, loc, off) -> None:
        e = envelope(s, d, 0.8)
        ph = 2.0 * np.pi * s / self.stride_s
        for sd, p in (("l", 0.0), ("r", np.pi)):
            q = ph + p
            ang[sel, _JI[f"hip_{sd}"], 0] += e * (10 + 25 * np.sin(q)) * DEG
            ang[sel, _JI[f"hip_{sd}"], 1] += e * 4 * np.sin(q + 0.5) * DEG
            ang[sel, _JI[f"hip_{sd}"], 2] += e * 6 * np.sin(q) * DEG
            ang[sel, _JI[f"knee_{sd}"], 0] += e * (5 + 55 * (0.5 + 0.5 * np.sin(q + 1.2)) ** 2) * DEG
            ang[sel, _JI[f"ankle_{sd}"], 0] += e * 12 * np.sin(q - 0.8) * DEG
            # Arms swing opposite to the legs (DOF 2 swings a lowered arm in the sagittal plane).
            ang[sel, _JI[f"shoulder_{sd}"], 2] += e * 20 * np.sin(q) * DEG * (1 if sd == "l" else -1)
            ang[sel, _JI[f"elbow_{sd}"], 0] += e * 10 * (1 + np.sin(q + np.pi)) * DEG
        ang[sel, _JI["waist"], 2] += e * -6 * np.sin(ph) * DEG
        loc[sel, 2] += e * 5 * np.sin(ph) * DEG
        loc[sel, 1] += e * 3 * np.sin(2 * ph) * DEG
        bob = -0.015 * e * 0.5 * (1 - np.cos(2 * ph))
        sway = 0.02 * e * np.sin(ph)
        off[sel, 0] += -np.sin(heading) * sway
        off[sel, 1] += np.cos(heading) * sway
        off[sel, 2] += bob
