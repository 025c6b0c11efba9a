"""The video panel: a local file chosen in the page plays on the back of the stage, with its controls."""
from __future__ import annotations

import base64

import pytest
from viewer_support import TESTING, free_port, save_artifact, viewer_url

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


def paused_frame_colour(page, t: float) -> list[float]:
    """Seek the paused clip to ``t`` s and return its frame's background colour, as the browser's
    decoder gives it (the video element drawn into a 2D canvas), times the panel's dimming."""
    p = page.page
    before = page.stats()["video"]["framesUploaded"]
    p.evaluate(f"""() => {{ const s = document.getElementById('video-seek'); s.value = '{t}';
                           s.dispatchEvent(new Event('input')); }}""")
    page.wait(f"!s.video.playing && Math.abs(s.video.currentTime - {t}) < 0.05")
    page.wait(f"s.video.framesUploaded > {before}")  # the seeked frame reached the texture
    p.wait_for_timeout(200)  # and a few frames were drawn with it
    return p.evaluate("""() => {
        const v = window.mocapgraphViewer.video;
        const c = new OffscreenCanvas(v.video.videoWidth, v.video.videoHeight);
        const g = c.getContext("2d");
        g.drawImage(v.video, 0, 0);
        const d = g.getImageData(0, 0, c.width, 50).data;  // above the moving bar (y 60-120)
        const sum = [0, 0, 0];
        for (let i = 0; i < d.length; i += 4) for (let k = 0; k < 3; k++) sum[k] += d[i + k];
        const dim = v.frame().dim;
        return sum.map((x) => x / (d.length / 4) * dim);
    }""")


def pixels_near(p, png: bytes, colour: list[float], tol: float = 14.0) -> list[int]:
    """[pixels of the screenshot within ``tol`` of ``colour`` per channel, pixels near the colour of
    the clip's other end (red <-> blue swapped), all pixels]."""
    return p.evaluate("""async ([b64, c, tol]) => {
        const bytes = Uint8Array.from(atob(b64), (x) => x.charCodeAt(0));
        const bmp = await createImageBitmap(new Blob([bytes], {type: "image/png"}));
        const cv = new OffscreenCanvas(bmp.width, bmp.height);
        const g = cv.getContext("2d");
        g.drawImage(bmp, 0, 0);
        const d = g.getImageData(0, 0, bmp.width, bmp.height).data;
        const other = [c[2], c[1], c[0]];
        let near = 0, nearOther = 0;
        const close = (i, k) => Math.abs(d[i] - k[0]) <= tol && Math.abs(d[i + 1] - k[1]) <= tol && Math.abs(d[i + 2] - k[2]) <= tol;
        for (let i = 0; i < d.length; i += 4) { if (close(i, c)) near++; else if (close(i, other)) nearOther++; }
        return [near, nearOther, d.length / 4];
    }""", [base64.b64encode(png).decode(), colour, tol])


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
    # 2 s recorded; on a busy machine the encoder keeps fewer frames (1.1 s seen at load 18)
    assert (st["width"], st["height"]) == (320, 180) and 0.8 < st["duration"] < 2.6
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

    # The panel shows the clip's own frames: paused at two moments, the stage seen from the front
    # holds a large area of the colour the browser's decoder gives for that very frame (the clip
    # fades from red to blue, so the two moments' colours are far apart), and little of the other.
    p.click("#video-pause")
    p.click('[data-view="front"]')
    p.wait_for_function("() => Math.abs(window.mocapgraphViewer.camera.cur.az) < 0.01")
    area = {}
    moments = (round(0.1 * st["duration"], 2), round(0.9 * st["duration"], 2))
    for when in moments:
        own = paused_frame_colour(page, when)
        png = p.screenshot()
        area[when] = (own, pixels_near(p, png, own))
    (c1, n11), (c2, n22) = area[moments[0]], area[moments[1]]
    print(f"clip colours {c1} and {c2}: {n11[0]} and {n22[0]} matching pixels; "
          f"{n11[1]} and {n22[1]} of the other moment's colour (of {n11[2]})")
    assert max(abs(a - b) for a, b in zip(c1, c2)) > 60  # the two frames really differ
    assert n11[0] > 0.02 * n11[2] and n22[0] > 0.02 * n22[2]  # the panel is a sizeable part of the view
    assert n11[1] < 0.1 * n11[0] and n22[1] < 0.1 * n22[0]  # and it changed with the frame
    shot = tmp_path / "viewer_video.png"
    png = p.screenshot(path=str(shot))
    save_artifact(shot, "viewer_video.png")
    assert page.errors() == []
    assert page.stats()["errors"] == []
