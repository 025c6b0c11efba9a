"""Live cameras' frames grouped by capture time (FrameGrouper, pure): synchronised cameras give
one group per instant; a camera that skips, lags or stops is counted and named, the rest continue."""
from __future__ import annotations

import numpy as np

from mocapgraph.video.live import FrameGrouper

MS = 1_000_000
PERIOD_NS = 33 * MS


def _frame(k: int) -> tuple[np.ndarray, np.ndarray]:
    return np.full((3, 2), float(k)), np.full(3, 0.9)


def _run(schedule, n_frames: int = 30, wait_s: float = 0.2, stall_s: float = 0.5):
    """schedule(cam, i) -> (capture offset ns, arrival delay ns) or None (frame not sent); the
    grouper polled every 5 ms of simulated time. Returns (groups, notes, grouper)."""
    g = FrameGrouper(["a", "b", "c", "d"], 3, PERIOD_NS / 1e9, wait_s=wait_s, stall_s=stall_s)
    events = []
    for i in range(n_frames):
        for cam in range(4):
            s = schedule(cam, i)
            if s is not None:
                cap = 1_000 * MS + i * PERIOD_NS + s[0]
                events.append((cap + s[1], cam, cap, i))
    events.sort()
    groups, notes, e = [], [], 0
    end = events[-1][0] + int(wait_s * 1e9) + 20 * MS          # the last group out, before the end looks a stall
    for now in range(events[0][0], end, 5 * MS):
        while e < len(events) and events[e][0] <= now:
            _, cam, cap, i = events[e]
            notes += g.add(cam, cap, i, *_frame(i), now)
            e += 1
        out, n = g.ready(now)
        groups += out
        notes += n
    return groups, notes, g


def test_synchronised_cameras_with_jitter_make_one_group_per_instant() -> None:
    rng = np.random.default_rng(0)
    jitter = rng.integers(-8 * MS, 8 * MS, (4, 30))        # any two within half a period (16.5 ms)
    groups, notes, g = _run(lambda c, i: (int(jitter[c, i]), 40 * MS + int(jitter[c, i] % (20 * MS))))
    assert len(groups) == 30 and all(gr.present.all() for gr in groups)
    assert all((gr.frames == i).all() for i, gr in enumerate(groups))
    np.testing.assert_array_equal(groups[7].uv[2], np.full((3, 2), 7.0))
    assert [s["grouped"] for s in g.status().values()] == [30] * 4


def test_a_skipping_camera_is_counted_missed_and_the_others_grouped() -> None:
    groups, _, g = _run(lambda c, i: None if (c == 1 and i % 3 == 0) else (0, 50 * MS))
    assert len(groups) == 30
    assert [int(gr.present.sum()) for gr in groups[:3]] == [3, 4, 4]
    st = g.status()["b"]
    assert st["missed"] == 10 and st["grouped"] == 20 and st["lagging"] == 0


def test_a_lagging_camera_is_counted_and_its_late_frames_dropped() -> None:
    # camera c's frames arrive 0.4 s after capture (the group waits 0.2 s): every group goes without it
    groups, _, g = _run(lambda c, i: (0, 400 * MS if c == 2 else 30 * MS))
    assert len(groups) == 30 and not any(gr.present[2] for gr in groups)
    st = g.status()["c"]
    assert st["lagging"] == 30 and st["late"] == 30 and st["grouped"] == 0


def test_a_camera_that_stops_is_named_once_and_the_others_continue() -> None:
    # camera d silent for 30 frames (1 s); stall_s 0.5 s
    groups, notes, g = _run(lambda c, i: None if (c == 3 and 10 <= i < 40) else (0, 30 * MS), n_frames=60)
    assert len(groups) == 60
    assert all(gr.present[:3].all() for gr in groups)
    assert [i for i, gr in enumerate(groups) if not gr.present[3]] == list(range(10, 40))
    stalls = [n for n in notes if "stalled" in n]
    assert len(stalls) == 1 and stalls[0].startswith("camera d stalled: no frame for 0.5 s")
    assert "camera d is back (frame 40)" in notes
    # waited for (lagging) until it was named stalled, then not: the rest of the gap went out at once
    st = g.status()["d"]
    assert st["lagging"] <= 16 and st["missed"] >= 14 and st["lagging"] + st["missed"] == 30


def test_a_camera_offset_by_more_than_half_a_period_joins_the_others_nearest_frame() -> None:
    # camera a captures 20 ms after the others (period 33 ms): 13 ms before their next frame
    groups, _, g = _run(lambda c, i: (20 * MS if c == 0 else 0, 30 * MS))
    assert len(groups) == 31
    assert groups[0].frames.tolist() == [-1, 0, 0, 0] and groups[-1].frames.tolist() == [29, -1, -1, -1]
    assert all(gr.frames.tolist() == [i, i + 1, i + 1, i + 1] for i, gr in enumerate(groups[1:-1]))


def test_a_camera_far_off_the_others_is_named_from_its_median_reprojection_error() -> None:
    from mocapgraph.video.multiview import off_cameras
    names = ["a", "b", "c", "d"]
    assert off_cameras(names, np.array([12.0, 9.0, 14.0, 11.0])) == []
    assert off_cameras(names, np.array([12.0, 280.0, 14.0, 11.0])) == [
        "camera b: median reprojection error 280.0 px, the others 12.0 px: check its calibration"]
    assert off_cameras(names, np.array([12.0, np.nan, 30.0, 11.0])) == [
        "camera c: median reprojection error 30.0 px, the others 11.5 px: check its calibration"]
