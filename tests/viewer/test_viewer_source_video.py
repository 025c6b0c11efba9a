"""The video panel plays a video reader's own clip in step with its skeleton: the viewer serves only
the file the graph's reader names (token-checked, byte ranges), and in headless Chromium the
video's time stays within one frame of the media time of the pose the reader published at that
moment (taken from the bus, not from the page)."""
from __future__ import annotations

import bisect
import time
import urllib.error
import urllib.request

import numpy as np
import pytest

from viewer_support import BusTap, free_port, viewer_url

SCALE = 0.25     # the reader's rate_scale: the 100-frame clip (60 fps) takes 6.7 s a pass
SAMPLE_JS = """() => { const p = window.mocapgraphViewer.video, v = p.video;
    return {wall: Date.now(), t: v.currentTime, seeking: v.seeking, paused: v.paused, rate: v.playbackRate,
            seeks: p.following.seeks}; }"""


def _get(url: str, **headers) -> tuple[int, dict, bytes]:
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=10) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers), exc.read()


@pytest.mark.timing  # the page follows the reader in real time
def test_the_source_video_follows_the_skeleton_within_a_frame(launch_graph, open_page, shared_data):
    pytest.importorskip("mediapipe", reason="the video extra is not installed")
    clip = shared_data / "video" / "pose2sim_demo" / "cam01.mp4"
    if not clip.exists():
        pytest.skip(f"{clip} is not there")
    port = free_port()
    g = launch_graph(f"""
nodes:
  - name: reader
    type: video_pose_reader
    params: {{file: "{clip}", rate_scale: 0.25, loop: true}}
  - name: viz
    type: visualizer
    params: {{port: {port}}}
""")
    url = viewer_url(g)
    base, _, query = url.partition("?")
    g.wait_for("video panel can follow reader", 20)
    # only the reader's own clip, only with the token, in byte ranges
    size = clip.stat().st_size
    assert _get(f"{base}source_video?node=reader")[0] == 403
    assert _get(f"{base}source_video?{query}&node=viz")[0] == 404
    status, head, body = _get(f"{base}source_video?{query}&node=reader", Range="bytes=100-199")
    assert status == 206 and head["Content-Range"] == f"bytes 100-199/{size}" and body == clip.read_bytes()[100:200]
    assert _get(f"{base}source_video?{query}&node=reader", Range=f"bytes={size}-")[0] == 416
    g.wait_for("converted:", 120)                      # mediapipe estimated the clip: playback begins
    tap = BusTap(g.master, ["skeleton_pose"])
    try:
        page = open_page(url)
        page.wait("s.connected && s.skeletonJointsDrawn > 0", timeout=30)
        page.page.click("#video-follow")
        page.wait("s.video.following === 'reader' && s.video.playing", timeout=20)
        time.sleep(2.0)
        samples = []
        for _ in range(80):
            samples.append(page.page.evaluate(SAMPLE_JS))
            time.sleep(0.05)
        fps = 60.0
        poses = sorted((env.publish_ns / 1e6, msg.frame_number) for env, msg in tap.of("skeleton_pose"))
    finally:
        tap.close()
    stamps = [p[0] for p in poses]
    wraps = [stamps[i] for i in range(1, len(poses)) if poses[i][1] < poses[i - 1][1]]
    off, skipped = [], 0
    for s in samples:
        i = bisect.bisect_right(stamps, s["wall"]) - 1
        settling = any(0 <= s["wall"] - w < 1000 for w in wraps)
        # the media time the reader had reached at this moment: its last frame's, plus the time since
        if i < 1 or s["seeking"] or settling or stamps[i] - stamps[i - 1] > 200:
            skipped += 1                        # before the tap, mid-seek, or within 1 s of a loop's wrap
            continue
        expect = poses[i][1] / fps + (s["wall"] - stamps[i]) / 1000 * SCALE
        off.append((s["t"] - expect) * fps)
    off = np.abs(np.array(off))
    playing = sum(not s["paused"] for s in samples)
    seeks = samples[-1]["seeks"] - samples[0]["seeks"]
    rates = np.array([s["rate"] for s in samples if not s["paused"]])
    print(f"\nsource video vs skeleton media time over {len(off)} samples ({skipped} skipped): median "
          f"{np.median(off):.2f} frames, p90 {np.percentile(off, 90):.2f}, max {off.max():.2f} (1 frame = {1e3 / fps:.1f} ms); "
          f"playing in {playing} of {len(samples)} samples at rate {np.median(rates):.3f} (median), {seeks} seeks")
    assert len(off) >= 30
    assert np.median(off) <= 1.0 and np.percentile(off, 90) <= 1.0
    # it plays along (at the reader's pace), not parked on each frame by a seek
    assert playing >= 0.9 * len(samples) and seeks <= 6 and abs(np.median(rates) - SCALE) < 0.05
    assert not page.errors(), page.errors()
