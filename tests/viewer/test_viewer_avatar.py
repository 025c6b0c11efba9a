"""Characters on the three.js stage as skinned avatars: the viewer serves each character's mannequin
as GLB (token-checked, only for a CharacterInfo stream it holds), the page skins it with three.js
and drives its bones from every CharacterPose; the screenshot's pixels under the pose's projected
joints (positions the node computed, not three.js) are the avatar's; the avatar toggle turns them
to bones. Without three.js installed the page says in one line to run the setup script."""
from __future__ import annotations

import base64
import io
import urllib.error
import urllib.request
from urllib.parse import quote

import numpy as np
import pytest

from viewer_support import TESTING, free_port, save_artifact, viewer_url

AVATAR = np.array([0.92, 0.68, 0.52])      # avatar.js AVATAR_COLOUR

# the frozen frame: the avatar's pose's joints projected with the page's own view-projection, and the
# mean colour of the screenshot's 3x3 pixels there (decoded by the browser's image decoder, not WebGL)
SAMPLE_JS = """async (b64) => {
    const v = window.mocapgraphViewer;
    const pose = v.scene.poses["character_pose|carol|carol"];
    const pos = pose.arrays.joint_positions.data, vp = v.viewProj;
    const rect = document.querySelector("canvas").getBoundingClientRect();
    const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    const bmp = await createImageBitmap(new Blob([bytes], {type: "image/png"}));
    const g = new OffscreenCanvas(bmp.width, bmp.height).getContext("2d");
    g.drawImage(bmp, 0, 0);
    const img = g.getImageData(0, 0, bmp.width, bmp.height).data;
    const out = [];
    for (let j = 0; j < pos.length / 3; j++) {
        const p = [pos[3 * j], pos[3 * j + 1], pos[3 * j + 2]];
        const x = vp[0] * p[0] + vp[4] * p[1] + vp[8] * p[2] + vp[12];
        const y = vp[1] * p[0] + vp[5] * p[1] + vp[9] * p[2] + vp[13];
        const w = vp[3] * p[0] + vp[7] * p[1] + vp[11] * p[2] + vp[15];
        const px = Math.round(rect.left + (x / w * 0.5 + 0.5) * rect.width);
        const py = Math.round(rect.top + (1 - (y / w * 0.5 + 0.5)) * rect.height);
        if (!(w > 0) || px < 1 || py < 1 || px >= Math.min(bmp.width - 1, rect.right) || py >= bmp.height - 1) {
            out.push(null); continue;
        }
        const s = [0, 0, 0];
        for (let dy = -1; dy <= 1; dy++) for (let dx = -1; dx <= 1; dx++) {
            const i = 4 * ((py + dy) * bmp.width + px + dx);
            for (let k = 0; k < 3; k++) s[k] += img[i + k] / 9;
        }
        out.push(s);
    }
    return {colours: out, frame: pose.fields.frame_number, joints: pos.length / 3};
}"""


def _chroma(c) -> np.ndarray:
    c = np.asarray(c, float)
    return c / max(float(c.sum()), 1e-9)


def _avatar_share(page) -> tuple[float, int]:
    """(share of the frozen frame's joints whose pixel shows the avatar's colour, joints)."""
    png = page.page.screenshot()
    got = page.page.evaluate(SAMPLE_JS, base64.b64encode(png).decode())
    seen = [c for c in got["colours"] if c is not None]
    assert len(seen) == got["joints"], "every joint is on the page"
    hits = [np.abs(_chroma(c) - _chroma(AVATAR)).sum() < 0.03 and sum(c) > 120 for c in seen]
    return sum(hits) / len(hits), got["joints"]


def _get(url: str, **headers) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def test_characters_are_skinned_avatars_driven_by_their_poses(launch_graph, open_page, tmp_path):
    pygltflib = pytest.importorskip("pygltflib")
    port = free_port()
    g = launch_graph(f"""
nodes:
  - name: carol
    type: {TESTING}:StagePerformer
    params: {{actor: carol, rate_hz: 60.0, publish: [character, physics], center: [0.0, 0.0], radius: 0.6}}
  - name: viz
    type: visualizer
    params: {{port: {port}}}
""")
    url = viewer_url(g)
    base, _, query = url.partition("?")
    key = quote("character_info|carol|carol")
    # the GLB: token-checked like the WebSocket, only for a CharacterInfo stream the viewer holds
    assert _get(f"{base}avatar.glb?key={key}")[0] == 403
    assert _get(f"{base}avatar.glb?{query}&key={key}", Origin="http://evil.example")[0] == 403
    status, body = _get(f"{base}avatar.glb?{query}&key={quote('../../etc/passwd')}")
    assert status == 404 and b"no CharacterInfo stream" in body
    page = open_page(url)
    page.wait("s.connected && s.avatarsDrawn === 1 && s.characterJointsDrawn === 16", timeout=30)
    status, glb = _get(f"{base}avatar.glb?{query}&key={key}")
    assert status == 200 and glb[:4] == b"glTF"
    doc = pygltflib.GLTF2.load_from_bytes(glb)
    names = [doc.nodes[j].name for j in doc.skins[0].joints]
    assert len(names) == 16 and names[0] == "pelvis" and len(doc.meshes) == 1
    assert {"JOINTS_0", "WEIGHTS_0"} <= set(doc.meshes[0].primitives[0].attributes.__dict__)
    s = page.stats()
    rec = s["streams"]["character_pose|carol|carol"]
    assert rec["avatar"] and rec["points"] == 16 and rec["bones"] == 15 and not s["avatarErrors"]
    assert page.page.locator("#avatar-note").is_hidden()

    # one frozen frame: the pixels under the pose's joints are the avatar's skin (the physics
    # bodies, a torso and thighs on the performer, drawn beside the avatar)
    page.page.uncheck("#show-labels")
    page.page.uncheck("#show-axes")
    page.page.check("#show-bodies-beside")
    page.page.click('[data-view="front"]')
    page.page.wait_for_function("() => Math.abs(window.mocapgraphViewer.camera.cur.az) < 0.01")

    def frozen_share() -> float:
        page.page.wait_for_timeout(300)
        page.page.check("#freeze")
        page.page.wait_for_timeout(200)
        share, joints = _avatar_share(page)
        assert joints == 16
        if not shots:
            page.page.screenshot(path=str(tmp_path / "viewer_avatar.png"))
            save_artifact(tmp_path / "viewer_avatar.png", "viewer_avatar.png")
            shots.append(1)
        page.page.uncheck("#freeze")
        return share

    shots: list[int] = []
    beside = frozen_share()
    page.page.uncheck("#show-bodies-beside")          # the bodies over the avatar cover part of it
    over = frozen_share()
    page.page.uncheck("#show-avatars")                # the same character drawn as bones: no avatar
    page.wait("s.avatarsDrawn === 0 && !s.streams['character_pose|carol|carol'].avatar", timeout=10)
    off = frozen_share()
    page.page.check("#show-avatars")
    page.wait("s.avatarsDrawn === 1", timeout=10)
    print(f"\navatar: {beside:.0%} of 16 projected joints on the avatar's skin with the bodies beside, "
          f"{over:.0%} with the bodies over it, {off:.0%} with the avatar toggled to bones")
    assert beside >= 0.85 and over <= beside - 0.15 and off <= 0.1
    assert not page.errors(), page.errors()


def test_without_threejs_the_page_says_to_run_the_setup_script(open_page, tmp_path, monkeypatch):
    from mocapgraph.viewer.server import LatestStore, ViewerServer

    monkeypatch.setenv("MOCAPGRAPH_THREE_DIR", str(tmp_path / "no_three"))
    server = ViewerServer(LatestStore(), {"node": "viz", "topics": {}}, port=free_port())
    server.start()
    try:
        assert _get(f"http://127.0.0.1:{server.port}/three/build/three.module.js")[0] == 404
        page = open_page(server.url)
        page.page.wait_for_function("() => window.mocapgraphFatal !== undefined", timeout=15000)
        text = page.page.locator("#fatal").inner_text()
        assert page.page.locator("#fatal").is_visible()
        assert "scripts/setup.sh" in text and "three.js" in text and "\n" not in text
    finally:
        server.stop()


# the page's own Avatars (avatar.js) posing a character's GLB from one CharacterPose-shaped record;
# returns the skin's bone world positions (three.js's skeleton, in our axes via the avatar's group)
DRIVE_JS = """async ([infoKey, q, root, J]) => {
    const v = window.mocapgraphViewer;
    const info = {key: infoKey, seq: 1, publish_ms: 1, fields: {character: "twisted"}};
    const s = {key: "test|twisted", arrays: {local_rotations: {data: Float32Array.from(q), shape: [J, 4]},
                                             root_position: {data: Float32Array.from(root), shape: [3]}}};
    for (let i = 0; i < 300 && !v.avatars.drive(s, info, 1); i++) await new Promise((r) => setTimeout(r, 50));
    const a = v.avatars.items.get("test|twisted");
    if (a.state !== "ready") return {error: v.avatars.errors};
    a.group.updateMatrixWorld(true);
    return {bones: a.bones.map((b) => b.getWorldPosition(b.position.clone()).toArray())};
}"""


def test_avatar_bones_follow_the_pose_with_turned_rest_orientations(open_page):
    """A character whose rest orientations are not identities (as a glTF/VRM rig's): the avatar's bones,
    posed by the page from local rotations and a root position, sit on our forward kinematics."""
    from scipy.spatial.transform import Rotation

    from mocapgraph.formats.character_file import load_character
    from mocapgraph.messages import CharacterInfo, Envelope
    from mocapgraph.retarget.character import Character
    from mocapgraph.viewer.server import LatestStore, ViewerServer

    base = load_character("standard_20")
    rng = np.random.default_rng(7)
    rest = Rotation.from_rotvec(rng.normal(scale=0.6, size=(base.n_joints, 3))).as_quat(scalar_first=True)
    ch = Character("twisted", base.joint_names, base.parents, base.rest_offsets, rest)
    store = LatestStore()
    info = CharacterInfo(character=ch.name, joint_names=list(ch.joint_names), joint_parent=ch.parents.astype(np.int32),
                         rest_offsets=ch.rest_offsets, rest_rotations=ch.rest_rotations)
    store.put("character_info", "twisted", Envelope("character_info", "CharacterInfo", 2, 1, 1, 1, "t", True), info)
    server = ViewerServer(store, {"node": "viz", "topics": {}}, port=free_port())
    server.start()
    try:
        page = open_page(server.url)
        page.page.wait_for_function("() => window.mocapgraphViewer !== undefined", timeout=15000)
        q = Rotation.from_rotvec(rng.normal(scale=0.5, size=(ch.n_joints, 3))).as_quat(scalar_first=True)
        root = np.array([0.4, -0.3, 1.0])
        got = page.page.evaluate(DRIVE_JS, ["character_info|t|twisted", q.ravel().tolist(), root.tolist(), ch.n_joints])
        assert "bones" in got, got
        truth, _ = ch.forward_kinematics(q, root)
        wrong, _ = ch.forward_kinematics(q[:, [0, 2, 3, 1]], root)   # axes not turned: far off
        assert np.abs(np.array(got["bones"]) - wrong).max() > 0.05
        worst = float(np.abs(np.array(got["bones"]) - truth).max())
        print(f"\navatar bones vs forward kinematics, rest orientations turned: worst {worst * 1e6:.3f} um")
        assert worst < 1e-4
    finally:
        server.stop()
