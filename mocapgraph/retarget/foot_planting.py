"""Foot planting (Kiip 3.5.6): contact from height and speed, planted targets, two-bone leg IK.

World frame, metres, seconds. A foot is in contact while its ankle is within ``height_m`` of its
rest height above the floor (or of the lowest it has been, when it never came down that far) and
moves slower than ``speed_mps`` horizontally. While in contact the ankle's horizontal position
starts where the contact began and then moves only as the source's own ankle does (its xy, scaled
by the root ratio): planting removes the sliding the source lacks (skating) and keeps the foot's
real motion (a heel roll, a pivot), so a source onto its own skeleton is left as it is. Without a
source ankle the plant is held still. At every frame the ankle and toe stay at or above their rest
heights (the sole on the floor); after a contact ends the planted offset fades out over
``release_s``. The hip-knee-ankle chain reaches the target by two-bone IK in the leg's current bend
plane; the foot keeps its world orientation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..kinematics.quaternion import matrix_between, norm

#: A leg whose ankle is within this of its target (m, any axis) is left alone: IK would bend a straight
#: leg by its reach margin, and a plant that follows the source's own ankle differs from the ankle
#: drawn only by rounding (a source onto its own skeleton).
MOVE_M = 1e-12


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
    low: np.ndarray = None       # [2] lowest ankle height above the floor so far, m (NaN: none yet)
    src_last: np.ndarray = None  # [2, 2] the scaled source ankle xy last seen, m (NaN: none yet)

    @classmethod
    def fresh(cls) -> "PlantState":
        return cls(np.zeros(2, bool), np.zeros((2, 2)), np.zeros((2, 2)), np.full((2, 2), np.nan), [], [],
                   low=np.full(2, np.nan), src_last=np.full((2, 2), np.nan))


def _follow(anchor: list, src_last: list, sx: float, sy: float, planted: bool) -> None:
    """Move a held ``anchor`` [x, y] by the source ankle's step since ``src_last`` (both updated in
    place; a NaN source point leaves both as they are)."""
    if not (sx == sx and sy == sy):
        return
    if planted and src_last[0] == src_last[0]:
        anchor[0] += sx - src_last[0]
        anchor[1] += sy - src_last[1]
    src_last[0], src_last[1] = sx, sy


def two_bone_ik(hip: np.ndarray, knee: np.ndarray, ankle: np.ndarray, target: np.ndarray,
                l1: np.ndarray, l2: np.ndarray, pole: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotations [..., 3, 3] of the thigh (about the hip) and of the shin (about the new knee), and
    the reached ankle [..., 3]: the knee stays in the plane of hip, current knee and target (``pole``
    [..., 3] is used where that plane is degenerate, a straight leg). Targets out of reach are
    approached along the hip-target line."""
    to = target - hip
    dist = norm(to, True)
    u = to / np.maximum(dist, 1e-12)
    d = np.clip(dist, np.abs(l1 - l2)[..., None] + 1e-6, (l1 + l2)[..., None] - 1e-6)
    cos_a = np.clip((l1[..., None] ** 2 + d ** 2 - l2[..., None] ** 2) / (2 * l1[..., None] * d), -1.0, 1.0)
    sin_a = np.sqrt(1.0 - cos_a ** 2)
    k = knee - hip
    perp = k - np.sum(k * u, axis=-1, keepdims=True) * u
    pole_perp = pole - np.sum(pole * u, axis=-1, keepdims=True) * u
    n = norm(perp, True)
    v = np.where(n > 1e-6 * l1[..., None], perp, pole_perp)
    v = v / np.maximum(norm(v, True), 1e-12)
    knee_new = hip + l1[..., None] * (cos_a * u + sin_a * v)
    reach = hip + d * u
    s1 = matrix_between(k, knee_new - hip)
    ankle_after = knee_new + (s1 @ (ankle - knee)[..., None])[..., 0]
    s2 = matrix_between(ankle_after - knee_new, reach - knee_new)
    return s1, s2, reach


def plant_targets(ankle: np.ndarray, rest_height: np.ndarray, times_s: np.ndarray, state: PlantState, *,
                  floor_z: float, height_m: float, speed_mps: float, release_s: float,
                  toe_lift: np.ndarray | None = None, window_s: float = 0.05,
                  source_xy: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Ankle targets [F, 2, 3] and contact flags [F, 2] for ankle positions [F, 2, 3] (NaN: no data).

    ``rest_height`` [2]: ankle height above the floor at rest. ``toe_lift`` [F, 2]: how far the toe
    is below its own rest height (lifts the whole foot so the toe clears the floor). ``source_xy``
    [F, 2, 2]: the source's ankles, horizontal, scaled by the root ratio (m; NaN: none), which a
    plant moves with. Sequential over frames (a plant begins where the previous frame's contact
    did), vectorised over the two feet.
    """
    F = ankle.shape[0]
    ok = np.isfinite(ankle).all(axis=2)                                 # [F, 2]
    xy = np.where(ok[..., None], ankle[..., :2], np.nan)
    speed = _window_speeds(state, np.asarray(times_s, dtype=np.float64), xy, window_s)   # [F, 2]
    # height above the lowest the ankle has been (never below its rest height): a character whose
    # retargeted feet never come down to their rest height (a source's rest unlike its stance) still
    # plants them where they stand
    h_rest = ankle[..., 2] - (floor_z + rest_height)
    low = np.fmin.accumulate(np.concatenate([state.low[None], h_rest]), axis=0)[1:]
    state.low = low[-1].copy() if F else state.low
    h = h_rest - np.maximum(np.nan_to_num(low, nan=0.0), 0.0)
    enter = ok & (h < height_m) & (speed < speed_mps)
    keep = ok & (h < 1.5 * height_m) & (speed < 2.0 * speed_mps)
    # sequential part (a plant starts where the last contact did not): plain floats, two feet
    contact = np.zeros((F, 2), bool)
    out_xy = np.where(ok[..., None], ankle[..., :2], 0.0)
    t_prev = state.last_t
    planted = [bool(state.planted[0]), bool(state.planted[1])]
    anchor = state.anchor.tolist()
    offset = state.offset.tolist()
    src_last = state.src_last.tolist()
    src = (np.full((F, 2, 2), np.nan) if source_xy is None else np.asarray(source_xy, np.float64)).tolist()
    en, kp, okl, xyl, tl = enter.tolist(), keep.tolist(), ok.tolist(), out_xy.tolist(), list(map(float, times_s))
    for f in range(F):
        t = tl[f]
        dt = t - t_prev if t_prev == t_prev else float("nan")   # NaN-safe (no previous frame)
        decay = max(0.0, 1.0 - dt / release_s) if release_s > 0 and dt == dt else 0.0
        for i in (0, 1):
            if not okl[f][i]:
                planted[i] = False
                _follow(anchor[i], src_last[i], src[f][i][0], src[f][i][1], False)
                continue
            c = en[f][i] or (planted[i] and kp[f][i])
            x, y = xyl[f][i]
            _follow(anchor[i], src_last[i], src[f][i][0], src[f][i][1], c and planted[i])
            if c:
                if not planted[i]:   # begins where the foot is drawn now (a fading offset included): no jump
                    anchor[i] = [x + (offset[i][0] if dt == dt else 0.0), y + (offset[i][1] if dt == dt else 0.0)]
                offset[i] = [anchor[i][0] - x, anchor[i][1] - y]
                xyl[f][i] = [anchor[i][0], anchor[i][1]]   # a copy: the anchor moves on
            else:                    # released: the last offset fades out over release_s
                offset[i] = [offset[i][0] * decay, offset[i][1] * decay]
                xyl[f][i] = [x + offset[i][0], y + offset[i][1]]
            contact[f, i] = c
            planted[i] = c
        t_prev = t
    state.planted = np.array(planted)
    state.anchor = np.array(anchor, dtype=np.float64).reshape(2, 2)
    state.offset = np.array(offset, dtype=np.float64).reshape(2, 2)
    state.src_last = np.array(src_last, dtype=np.float64).reshape(2, 2)
    state.last_t = float(times_s[-1]) if F else state.last_t
    target = ankle.copy()
    z = np.maximum(ankle[..., 2], floor_z + rest_height)
    if toe_lift is not None:
        z = np.maximum(z, ankle[..., 2] + np.maximum(np.nan_to_num(toe_lift, nan=0.0), 0.0))
    target[..., :2] = np.where(ok[..., None], np.array(xyl, dtype=np.float64).reshape(F, 2, 2), ankle[..., :2])
    target[..., 2] = np.where(ok, z, ankle[..., 2])
    return target, contact


def _window_speeds(state: PlantState, t: np.ndarray, xy: np.ndarray, window_s: float) -> np.ndarray:
    """Least-squares horizontal speed [F, 2] (m/s) of each frame over the samples of the last
    ``window_s`` (at least two; the state's history included): noise averages out, the lag is half
    the window. 0 where fewer than two finite samples (a first frame is judged by its height)."""
    H = len(state.history_t)
    if len(t) == 1 and H >= 1:   # the live case: one least-squares line through the short window
        T = np.append(np.asarray(state.history_t, dtype=np.float64), t[0])
        X = np.concatenate([np.asarray(state.history_xy, dtype=np.float64).reshape(H, 2, 2), xy])
        keep = T >= T[-1] - window_s - 1e-12
        keep[-2:] = True
        T, X = T[keep], X[keep]
        state.history_t, state.history_xy = T.tolist(), list(X)
        ok = np.isfinite(X).all(axis=2)                                  # [N, 2]
        tc = T - T[-1]
        w = ok.astype(np.float64)
        n = w.sum(0)
        tm = (w * tc[:, None]).sum(0) / np.maximum(n, 1)
        d = np.where(ok, tc[:, None] - tm, 0.0)
        Xz = np.where(ok[..., None], X, 0.0)
        xm = Xz.sum(0) / np.maximum(n, 1)[:, None]
        den = (d * d).sum(0)
        v = (d[..., None] * (Xz - xm)).sum(0) / np.where(den > 1e-18, den, 1.0)[:, None]
        return np.where((n >= 2) & (den > 1e-18), norm(v), 0.0)[None]
    T = np.concatenate([np.asarray(state.history_t, dtype=np.float64), t])
    X = np.concatenate([np.asarray(state.history_xy, dtype=np.float64).reshape(H, 2, 2), xy]) if H else xy
    F = len(t)
    k = np.arange(H, H + F)
    start = np.minimum(np.searchsorted(T, T[k] - window_s - 1e-12, side="left"), np.maximum(k - 1, 0))
    t0 = T[0] if len(T) else 0.0
    tt = (T - t0)[:, None]                                               # [N, 1] relative, for precision
    ok = np.isfinite(X).all(axis=2)                                      # [N, 2]
    w = ok.astype(np.float64)
    Xz = np.where(ok[..., None], X, 0.0)

    def csum(a):   # prefix sums with a leading zero row
        return np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a, axis=0)])
    Sw, St, Stt = csum(w), csum(w * tt), csum(w * tt * tt)
    Sx, Stx = csum(Xz), csum((w * tt)[..., None] * Xz)
    lo, hi = start, k + 1
    n = Sw[hi] - Sw[lo]
    st = St[hi] - St[lo]
    stt = Stt[hi] - Stt[lo]
    sx = Sx[hi] - Sx[lo]
    stx = Stx[hi] - Stx[lo]
    den = n * stt - st * st                                              # [F, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        v = (n[..., None] * stx - st[..., None] * sx) / den[..., None]
    speed = np.where((n >= 2) & (den > 1e-18), norm(v), 0.0)
    # keep the window's samples for the next call
    keep = T >= T[-1] - window_s - 1e-12 if len(T) else np.zeros(0, bool)
    keep[max(len(T) - 2, 0):] = True
    state.history_t = T[keep].tolist()
    state.history_xy = list(X[keep])
    return speed


def plant_one(ankle: list, rest_height: list, t: float, state: PlantState, *, floor_z: float, height_m: float,
              speed_mps: float, release_s: float, toe_lift: list | None = None,
              window_s: float = 0.05, source_xy: list | None = None) -> tuple[list, list]:
    """:func:`plant_targets` for one frame in plain floats (the live path): ankle [[x, y, z]] * 2 (m,
    NaN: no data), ``rest_height`` and ``toe_lift`` per foot, ``source_xy`` [[x, y]] * 2 (m, scaled;
    NaN or None: none); returns (targets [[x, y, z]] * 2, contact [bool] * 2). Same state, same
    rules, same numbers to rounding."""
    nan = float("nan")
    ok = [a[0] == a[0] and a[1] == a[1] and a[2] == a[2] and abs(a[0]) + abs(a[1]) + abs(a[2]) < math.inf
          for a in ankle]
    xy = [[a[0], a[1]] if o else [nan, nan] for a, o in zip(ankle, ok)]
    speed = _speed_one(state, float(t), xy, window_s)
    low = state.low.tolist()
    enter, keep = [False, False], [False, False]
    for i in (0, 1):   # the two feet
        if not ok[i]:
            continue
        h_rest = ankle[i][2] - (floor_z + rest_height[i])
        low[i] = h_rest if not low[i] <= h_rest else low[i]      # fmin: a NaN low is none yet
        h = h_rest - max(low[i], 0.0)
        enter[i] = h < height_m and speed[i] < speed_mps
        keep[i] = h < 1.5 * height_m and speed[i] < 2.0 * speed_mps
    state.low = np.array(low)
    t_prev = state.last_t
    planted = [bool(state.planted[0]), bool(state.planted[1])]
    anchor, offset, src_last = state.anchor.tolist(), state.offset.tolist(), state.src_last.tolist()
    src = source_xy if source_xy is not None else [[nan, nan], [nan, nan]]
    dt = t - t_prev if t_prev == t_prev else nan
    decay = max(0.0, 1.0 - dt / release_s) if release_s > 0 and dt == dt else 0.0
    contact = [False, False]
    target = [list(a) for a in ankle]
    for i in (0, 1):
        if not ok[i]:
            planted[i] = False
            _follow(anchor[i], src_last[i], src[i][0], src[i][1], False)
            continue
        c = enter[i] or (planted[i] and keep[i])
        x, y = xy[i]
        _follow(anchor[i], src_last[i], src[i][0], src[i][1], c and planted[i])
        if c:
            if not planted[i]:
                anchor[i] = [x + (offset[i][0] if dt == dt else 0.0), y + (offset[i][1] if dt == dt else 0.0)]
            offset[i] = [anchor[i][0] - x, anchor[i][1] - y]
            target[i][0], target[i][1] = anchor[i][0], anchor[i][1]
        else:
            offset[i] = [offset[i][0] * decay, offset[i][1] * decay]
            target[i][0], target[i][1] = x + offset[i][0], y + offset[i][1]
        contact[i] = planted[i] = c
        z = max(ankle[i][2], floor_z + rest_height[i])
        if toe_lift is not None:
            lift = toe_lift[i] if toe_lift[i] == toe_lift[i] else 0.0
            z = max(z, ankle[i][2] + max(lift, 0.0))
        target[i][2] = z
    state.planted = np.array(planted)
    state.anchor = np.array(anchor, dtype=np.float64).reshape(2, 2)
    state.offset = np.array(offset, dtype=np.float64).reshape(2, 2)
    state.src_last = np.array(src_last, dtype=np.float64).reshape(2, 2)
    state.last_t = float(t)
    return target, contact


def _speed_one(state: PlantState, t: float, xy: list, window_s: float) -> list:
    """:func:`_window_speeds` for one frame in plain floats: least-squares speed per foot over the
    short window (a dozen samples at 240 Hz), the history kept as nested lists."""
    T = [float(x) for x in state.history_t] + [t]
    X = [x.tolist() if isinstance(x, np.ndarray) else x for x in state.history_xy] + [xy]
    lo = t - window_s - 1e-12
    N = len(T)
    first = next((k for k in range(N) if T[k] >= lo), N)     # times ascend: the window is a tail
    first = min(first, max(N - 2, 0))
    T, X = T[first:], X[first:]
    state.history_t, state.history_xy = T, X
    out = [0.0, 0.0]
    if len(T) < 2:
        return out
    tc = [x - t for x in T]
    for i in (0, 1):
        s = [(tk, p[i][0], p[i][1]) for tk, p in zip(tc, X) if p[i][0] == p[i][0] and p[i][1] == p[i][1]]
        n = len(s)
        if n < 2:
            continue
        tm = sum(a for a, _, _ in s) / n
        xm = sum(b for _, b, _ in s) / n
        ym = sum(c for _, _, c in s) / n
        den = sum((a - tm) ** 2 for a, _, _ in s)
        if den > 1e-18:
            vx = sum((a - tm) * (b - xm) for a, b, _ in s) / den
            vy = sum((a - tm) * (c - ym) for a, _, c in s) / den
            out[i] = math.sqrt(vx * vx + vy * vy)
    return out
