"""Foot planting (Kiip 3.5.6): contact from height and speed, planted targets, two-bone leg IK.

World frame, metres, seconds. A foot is in contact while its ankle is within ``height_m`` of its
rest height above the floor and moves slower than ``speed_mps`` horizontally. While in contact the
ankle's horizontal position stays where the contact began; at every frame the ankle and toe stay at
or above their rest heights (the sole on the floor); after a contact ends the planted offset fades
out over ``release_s``. The hip-knee-ankle chain reaches the target by two-bone IK in the leg's
current bend plane; the foot keeps its world orientation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .quaternion import quat_between, quat_to_matrix


@dataclass
class PlantState:
    """Carried between calls (live frames or batches): per foot [2]."""

    planted: np.ndarray          # bool, in contact at the last frame
    anchor: np.ndarray           # [2, 2] planted ankle xy, m
    offset: np.ndarray           # [2, 2] target minus ankle xy at the last frame, m (fades after release)
    last_xy: np.ndarray          # [2, 2] ankle xy at the last frame (NaN: none yet)
    history_t: list = None       # recent frame times, s (the speed window)
    history_xy: list = None      # recent ankle xy [2, 2] per frame
    last_t: float = float("nan")

    @classmethod
    def fresh(cls) -> "PlantState":
        return cls(np.zeros(2, bool), np.zeros((2, 2)), np.zeros((2, 2)), np.full((2, 2), np.nan), [], [])


def two_bone_ik(hip: np.ndarray, knee: np.ndarray, ankle: np.ndarray, target: np.ndarray,
                l1: np.ndarray, l2: np.ndarray, pole: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotations [..., 3, 3] of the thigh (about the hip) and of the shin (about the new knee), and
    the reached ankle [..., 3]: the knee stays in the plane of hip, current knee and target (``pole``
    [..., 3] is used where that plane is degenerate, a straight leg). Targets out of reach are
    approached along the hip-target line."""
    to = target - hip
    dist = np.linalg.norm(to, axis=-1, keepdims=True)
    u = to / np.maximum(dist, 1e-12)
    d = np.clip(dist, np.abs(l1 - l2)[..., None] + 1e-6, (l1 + l2)[..., None] - 1e-6)
    cos_a = np.clip((l1[..., None] ** 2 + d ** 2 - l2[..., None] ** 2) / (2 * l1[..., None] * d), -1.0, 1.0)
    sin_a = np.sqrt(1.0 - cos_a ** 2)
    k = knee - hip
    perp = k - np.sum(k * u, axis=-1, keepdims=True) * u
    pole_perp = pole - np.sum(pole * u, axis=-1, keepdims=True) * u
    n = np.linalg.norm(perp, axis=-1, keepdims=True)
    v = np.where(n > 1e-6 * l1[..., None], perp, pole_perp)
    v = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)
    knee_new = hip + l1[..., None] * (cos_a * u + sin_a * v)
    reach = hip + d * u
    s1 = quat_to_matrix(quat_between(k, knee_new - hip))
    ankle_after = knee_new + (s1 @ (ankle - knee)[..., None])[..., 0]
    s2 = quat_to_matrix(quat_between(ankle_after - knee_new, reach - knee_new))
    return s1, s2, reach


def plant_targets(ankle: np.ndarray, rest_height: np.ndarray, times_s: np.ndarray, state: PlantState, *,
                  floor_z: float, height_m: float, speed_mps: float, release_s: float,
                  toe_lift: np.ndarray | None = None, window_s: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Ankle targets [F, 2, 3] and contact flags [F, 2] for ankle positions [F, 2, 3] (NaN: no data).

    ``rest_height`` [2]: ankle height above the floor at rest. ``toe_lift`` [F, 2]: how far the toe
    is below its own rest height (lifts the whole foot so the toe clears the floor). Sequential over
    frames (a plant begins where the previous frame's contact did), vectorised over the two feet.
    """
    F = ankle.shape[0]
    target = ankle.copy()
    contact = np.zeros((F, 2), bool)
    min_z = floor_z + rest_height
    for f in range(F):
        a = ankle[f]
        ok = np.isfinite(a).all(axis=1)
        t = float(times_s[f])
        dt = t - state.last_t if np.isfinite(state.last_t) else np.nan
        # marker noise makes frame-to-frame speeds of a standing foot reach 0.5 m/s: the speed is the
        # least-squares slope over the last ``window_s`` (noise averages out, lag is half the window),
        # and a plant is kept with hysteresis (twice the speed, 1.5 times the height): no chatter
        state.history_t.append(t)
        state.history_xy.append(np.where(ok[:, None], a[:, :2], np.nan))
        while len(state.history_t) > 2 and t - state.history_t[0] > window_s:
            state.history_t.pop(0)
            state.history_xy.pop(0)
        speed = _slope_speed(np.array(state.history_t), np.array(state.history_xy))
        h = a[:, 2] - min_z
        enter = (h < height_m) & (speed < speed_mps)
        stay = state.planted & (h < 1.5 * height_m) & (speed < 2.0 * speed_mps)
        c = ok & (enter | stay)
        new = c & ~state.planted
        # a plant begins where the foot is drawn now (a fading offset included): no jump
        state.anchor[new] = a[new, :2] + np.where(np.isfinite(dt), 1.0, 0.0) * state.offset[new]
        xy = a[:, :2].copy()
        xy[c] = state.anchor[c]
        # released: fade the last offset out over release_s
        fade = ~c & ok
        if release_s > 0 and np.isfinite(dt):
            state.offset[fade] *= max(0.0, 1.0 - dt / release_s)
        else:
            state.offset[fade] = 0.0
        xy[fade] += state.offset[fade]
        state.offset[c] = state.anchor[c] - a[c, :2]
        z = np.maximum(a[:, 2], min_z)
        if toe_lift is not None:
            z = np.maximum(z, a[:, 2] + np.maximum(toe_lift[f], 0.0))
        target[f, :, :2] = np.where(ok[:, None], xy, a[:, :2])
        target[f, :, 2] = np.where(ok, z, a[:, 2])
        contact[f] = c
        state.planted = c
        state.last_xy = np.where(ok[:, None], a[:, :2], state.last_xy)
        state.last_t = t
    return target, contact


def _slope_speed(t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Horizontal speed [2] (m/s) from a least-squares line through samples xy [N, 2, 2] at t [N];
    0 with fewer than 2 finite samples (a first frame is judged by its height alone)."""
    if len(t) < 2:
        return np.zeros(2)
    ok = np.isfinite(xy).all(axis=2)                       # [N, 2]
    w = ok.astype(float)
    n = w.sum(0)
    tc = np.where(ok, t[:, None], 0.0)
    tm = tc.sum(0) / np.maximum(n, 1)
    dt = np.where(ok, t[:, None] - tm, 0.0)
    x = np.where(ok[..., None], xy, 0.0)
    xm = x.sum(0) / np.maximum(n, 1)[:, None]
    num = (dt[..., None] * (x - xm)).sum(0)
    den = (dt ** 2).sum(0)
    v = num / np.where(den > 0, den, 1.0)[:, None]
    return np.where((n >= 2) & (den > 0), np.linalg.norm(v, axis=1), 0.0)
