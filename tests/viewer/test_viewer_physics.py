"""The viewer draws the physical character (real physics_tracker node): every capsule and stage
object with its shape, coloured by tracking error, seen in a headless Chromium's pixels."""
from __future__ import annotations

import base64
from collections import Counter

import numpy as np

from viewer_support import BusTap, free_port, save_artifact, viewer_url, wait_until

# where each world point lands on the page (the viewer's own last view-projection) and the mean
# colour of the screenshot's 3x3 pixels there (decoded by the browser's image decoder, not WebGL)
SAMPLE_JS = """async ([b64, points]) => {
    const vp = window.mocapgraphViewer.viewProj;
    const canvas = document.querySelector("canvas");
    const rect = canvas.getBoundingClientRect();
    const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    const bmp = await createImageBitmap(new Blob([bytes], {type: "image/png"}));
    const c = new OffscreenCanvas(bmp.width, bmp.height);
    const g = c.getContext("2d");
    g.drawImage(bmp, 0, 0);
    const img = g.getImageData(0, 0, bmp.width, bmp.height);
    const at = (x, y) => {
        const s = [0, 0, 0];
        for (let dy = -1; dy <= 1; dy++) for (let dx = -1; dx <= 1; dx++) {
            const i = 4 * ((y + dy) * bmp.width + (x + dx));
            for (let k = 0; k < 3; k++) s[k] += img.data[i + k] / 9;
        }
        return s;
    };
    const out = points.map((p) => {
        const x = vp[0] * p[0] + vp[4] * p[1] + vp[8] * p[2] + vp[12];
        const y = vp[1] * p[0] + vp[5] * p[1] + vp[9] * p[2] + vp[13];
        const w = vp[3] * p[0] + vp[7] * p[1] + vp[11] * p[2] + vp[15];
        if (w <= 1e-6) return null;
        const px = Math.round(rect.left + (x / w * 0.5 + 0.5) * rect.width);
        const py = Math.round(rect.top + (1 - (y / w * 0.5 + 0.5)) * rect.height);
        if (px < 1 || py < 1 || px >= Math.min(bmp.width - 1, rect.right) || py >= bmp.height - 1) return null;
        return at(px, py);
    });
    return {colours: out, background: at(Math.round(rect.left + 20), 120)};
}"""

# a stage of our own around the standing performer: a box, a pole with a cube, a ball
STAGE = """\
name: viewer_test
objects:
  - {name: crate, shape: box, size: [0.2, 0.2, 0.2], pos: [0.0, 1.0, 0.2], mass: 2.0}
  - {name: pole, shape: cylinder, size: [0.05, 0.5], pos: [0.0, -1.0, 0.5], fixed: true}
  - {name: cube, shape: box, size: [0.08, 0.08, 0.08], pos: [0.0, -1.0, 1.08], mass: 1.0}
  - {name: ball, shape: sphere, size: [0.15], pos: [0.6, 1.2, 0.15], mass: 1.0}
"""


def error_colour(e: float) -> np.ndarray:
    """The viewer's tracking-error colour (scene.js errorColor), RGB 0..1."""
    if not np.isfinite(e):
        return np.array([0.58, 0.63, 0.72])
    t = min(1.0, max(0.0, (e - 0.01) / 0.09))
    a, b, c = np.array([0.25, 0.8, 0.78]), np.array([1.0, 0.7, 0.22]), np.array([1.0, 0.33, 0.33])
    return a + (b - a) * 2 * t if t < 0.5 else b + (c - b) * (2 * t - 1)


def test_physics_bodies_and_stage_objects_drawn_coloured_by_tracking_error(launch_graph, open_page, tmp_path):
    port = free_port()
    stage_file = tmp_path / "stage.yaml"
    stage_file.write_text(STAGE)
    g = launch_graph(f"""
nodes:
  - name: src
    type: synthetic_character
    params: {{start_s: 22.0, stop_s: 22.5, rate_hz: 60.0, loop: false}}
  - name: tracker
    type: physics_tracker
    params: {{stage: "{stage_file}"}}
  - name: viz
    type: visualizer
    params: {{port: {port}}}
""")
    g.wait_ready(60)
    tap = BusTap(g.master, ["physics_scene", "physics_state"])
    try:
        page = open_page(viewer_url(g))
        page.wait("s.connected && s.bodiesDrawn > 0", timeout=40)
        wait_until(lambda: tap.of("physics_scene") and len(tap.of("physics_state")) > 10, timeout=30,
                   what="the tracker's scene and states")
        scene = tap.of("physics_scene")[-1][1]
        # only the physical bodies on the page: characters (input and simulated poses), names and
        # axes off; then the camera fitted to what is drawn
        for box in ("#show-characters", "#show-labels", "#show-axes"):
            page.page.uncheck(box)
        page.wait("s.characterJointsDrawn === 0", timeout=10)
        page.page.click('[data-view="front"]')
        page.page.wait_for_timeout(300)
        page.page.click('[data-view="fit"]')
        # the stream ended after 0.5 s: the character stands and waits on its last target and
        # settles, so the state the page draws and the last one sent carry the same errors
        page.page.wait_for_timeout(1500)
        s = page.stats()
        key = next(k for k in s["streams"] if k.startswith("physics_state|"))
        rec = s["streams"][key]
        names, shapes = list(scene.body_names), list(scene.shapes)
        capsules = [i for i, n in enumerate(names) if n.startswith("c0/")]
        stage = [i for i, n in enumerate(names) if n.startswith("stage/")]
        print(f"\npage draws {rec['points']} of {rec['total']} bodies: {rec['shapes']}, {rec['tracked']} coloured by "
              f"tracking error; the scene has {len(capsules)} capsules and {len(stage)} stage objects")
        # every body of the scene, each with its own shape; the character's coloured by its error
        assert rec["total"] == rec["points"] == len(names)
        assert rec["shapes"] == dict(Counter(shapes))
        assert rec["shapes"]["capsule"] == len(capsules) >= 15
        assert {"box", "cylinder"} <= set(rec["shapes"])
        assert rec["tracked"] == len(capsules)

        state = tap.of("physics_state")[-1][1]
        pos = np.asarray(state.positions, float)
        err = np.asarray(state.tracking_error, float)
        shot = page.page.screenshot()
        (tmp_path / "physics.png").write_bytes(shot)
        save_artifact(tmp_path / "physics.png", "viewer_physics.png")
        got = page.page.evaluate(SAMPLE_JS, [base64.b64encode(shot).decode(), pos.tolist()])
        bg = np.array(got["background"])
        where = [None if c is None else np.array(c) for c in got["colours"]]

        def under(i: int) -> np.ndarray | None:
            return where[i]

        # each capsule shows its own tracking error's colour (the page's errorColor: teal under
        # 1 cm, amber at 5.5 cm, red from 10 cm), compared as chromaticity (lighting scales it)
        chroma = lambda c: np.asarray(c, float) / max(float(np.sum(c)), 1e-9)  # noqa: E731
        seen = [under(i) for i in capsules]
        on_page = sum(c is not None for c in seen)
        dist = [float(np.abs(chroma(c) - chroma(error_colour(err[i]))).sum()) for i, c in zip(capsules, seen)
                if c is not None and np.abs(c - bg).sum() > 60]
        matched = sum(d < 0.02 for d in dist)
        # stage objects are untracked: the viewer's neutral grey-blue
        stage_drawn = sum(1 for i in stage if (c := under(i)) is not None and np.abs(c - bg).sum() > 30
                          and np.abs(chroma(c) - chroma(error_colour(np.nan))).sum() < 0.02)
        print(f"capsule centres on the page {on_page}, showing their error's colour {matched} (chromaticity off by "
              f"{np.round(sorted(dist), 3).tolist()}; errors {np.round(1000 * err[capsules]).astype(int).tolist()} mm); "
              f"stage objects whose centre shows a body {stage_drawn} of {len(stage)}; background {bg.round()}")
        assert on_page == len(capsules)
        # a capsule's centre may lie behind a neighbour (the trunk's behind the arms) showing that
        # one's error instead: most show their own
        assert matched >= 0.6 * len(capsules)
        assert stage_drawn >= len(stage) - 1           # one may hide behind another from this view
        assert not page.errors(), page.errors()
    finally:
        tap.close()
