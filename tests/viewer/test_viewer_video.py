"""The video panel: a local file chosen in the page plays on the back of the stage, with its controls."""
from __future__ import annotations

import base64

import pytest
from viewer_support import TESTING, free_port, image_stats, save_artifact, viewer_url, wait_until

# A 2 s WebM made by the browser's own encoder: a canvas turning from red to blue with a moving bar.
MAKE_VIDEO = """async () => {
  const c = document.createElement("canvas"); c.width = 320; c.height = 180;
  const g = c.getContext("2d");
  const rec = new MediaRecorder(c.captureStream(30), {mimeType: "video/webm"});
  const chunks = [];
  rec.ondataavailable = (e) => chunks.push(e.data);
  const done = new Promise((r) => rec.onstop = r);
  rec.start(100);
  const t0 = performance.now();
  await new Promise((resolve) => {
    const draw = () => {
      const t = (performance.now() - t0) / 2000;
      g.fillStyle = `rgb(${Math.round(255 * (1 - t))}, 60, ${Math.round(255 * t)})`;
      g.fillRect(0, 0, 320, 180);
      g.fillStyle = "#fff"; g.fillRect(Math.round(300 * t), 60, 20, 60);
      if (t < 1) requestAnimationFrame(draw); else resolve();
    };
    draw();
  });
  rec.stop();
  await done;
  const buf = new Uint8Array(await new Blob(chunks, {type: "video/webm"}).arrayBuffer());
  let s = ""; for (let i = 0; i < buf.length; i += 8192) s += String.fromCharCode(...buf.subarray(i, i + 8192));
  return btoa(s);
}"""


def test_video_file_plays_on_the_stage_with_controls(launch_graph, open_page, tmp_path):
    port = free_port()
    g = launch_graph(f"""
nodes:
  - name: alice
    type: {TESTING}:StagePerformer
    params: {{actor: alice, rate_hz: 60.0, publish: [markers, actor]}}
  - name: viz
    type: visualizer
    params: {{port: {port}}}
""")
    g.wait_ready()
    page = open_page(viewer_url(g))
    page.wait("s.connected && s.framesDrawn > 2", timeout=15)
    p = page.page
    assert p.locator("#video-play").is_disabled()  # nothing to play before a file is chosen
    try:
        data = base64.b64decode(p.evaluate(MAKE_VIDEO))
    except Exception as exc:  # pragma: no cover - depends on the browser build's encoders
        pytest.skip(f"this Chromium cannot record WebM: {exc}")
    video = tmp_path / "clip.webm"
    video.write_bytes(data)

    p.set_input_files("#video-file", str(video))
    st = page.wait("s.video.ready && s.video", timeout=15)
    assert (st["width"], st["height"]) == (320, 180) and 1.5 < st["duration"] < 2.6
    assert "clip.webm" in p.locator("#video-status").inner_text()

    p.click("#video-play")
    page.wait("s.video.playing && s.video.currentTime > 0.3", timeout=10)
    uploaded = page.stats()["video"]["framesUploaded"]
    page.wait(f"s.video.framesUploaded > {uploaded} + 5")  # frames reach the texture on the stage
    p.click("#video-pause")
    t = page.wait("!s.video.playing && s.video.currentTime")
    page.page.wait_for_timeout(400)
    assert page.stats()["video"]["currentTime"] == pytest.approx(t, abs=1e-3)

    p.evaluate("""() => { const s = document.getElementById('video-seek'); s.value = '1.2';
                          s.dispatchEvent(new Event('input')); }""")
    page.wait("Math.abs(s.video.currentTime - 1.2) < 0.05")
    p.click("#video-stop")
    page.wait("!s.video.playing && s.video.currentTime === 0")

    p.check("#video-loop")
    page.wait("s.video.loop")
    p.evaluate("""() => { const s = document.getElementById('video-volume'); s.value = '0.3';
                          s.dispatchEvent(new Event('input')); }""")
    page.wait("Math.abs(s.video.volume - 0.3) < 1e-6")
    p.click("#video-mute")
    page.wait("s.video.muted")
    assert p.locator("#video-mute").inner_text() == "Unmute"
    p.click("#video-mute")
    page.wait("!s.video.muted")

    # Looping: played from near the end it wraps round and keeps playing.
    p.evaluate("() => { window.mocapgraphViewer.video.video.currentTime = 1.6; }")
    p.click("#video-play")
    page.wait("s.video.playing && s.video.currentTime < 1.0 && s.video.currentTime > 0", timeout=10)

    # The panel shows the clip: seen from the front, the back wall is mostly the clip's colours.
    p.click('[data-view="front"]')
    p.wait_for_function("() => Math.abs(window.mocapgraphViewer.camera.cur.az) < 0.01")
    shot = tmp_path / "viewer_video.png"
    png = p.screenshot(path=str(shot))
    save_artifact(shot, "viewer_video.png")
    img = image_stats(p, png)
    assert img["std"] > 10 and img["colours"] > 60
    assert page.errors() == []
    assert page.stats()["errors"] == []
