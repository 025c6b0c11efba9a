"""The viewer draws a retargeted character (real retargeter node) as solid bones in its own colour, toggleable."""
from __future__ import annotations

from pathlib import Path

from viewer_support import free_port, image_stats, save_artifact, viewer_url


def test_character_from_the_retargeter_drawn_solid_and_toggleable(launch_graph, open_page, shared_data, tmp_path):
    port = free_port()
    csv = shared_data / "kinect2" / "Ges03_drawlines.csv"
    g = launch_graph(f"""
nodes:
  - name: reader
    type: kinect_reader
    params: {{file: "{csv}", device: kinect_front, ground: feet, loop: true}}
  - name: retargeter
    type: retargeter
    params: {{source: skeleton, character: standard_20, mapping: kinect_v2_standard_20, character_name: hero, offset: [0.0, -1.2, 0.0]}}
  - name: viz
    type: visualizer
    params: {{port: {port}}}
""")
    g.wait_ready(60)
    page = open_page(viewer_url(g))
    page.wait("s.connected && s.characterJointsDrawn >= 20", timeout=30)
    s = page.stats()
    key = next(k for k in s["streams"] if k.startswith("character_pose|"))
    rec = s["streams"][key]
    assert rec["points"] == 20 and rec["bones"] == 19 and rec["quality"]["good"] + rec["quality"]["estimated"] == 20
    assert rec["name"].startswith("hero") or "hero" in key
    shot = page.page.screenshot()
    save_artifact_bytes(shot, tmp_path / "character.png")
    with_char = image_stats(page.page, shot)
    # the global toggle hides every character, and only characters
    page.page.click("#show-characters")
    page.wait("s.characterJointsDrawn === 0", timeout=10)
    page.page.wait_for_timeout(300)
    without = image_stats(page.page, page.page.screenshot())
    assert abs(without["mean"] - with_char["mean"]) > 0.05 or without["colours"] != with_char["colours"]
    s2 = page.stats()
    assert s2["skeletonJointsDrawn"] > 0                       # the Kinect skeleton itself is still drawn
    page.page.click("#show-characters")
    page.wait("s.characterJointsDrawn === 20", timeout=10)
    assert not page.errors(), page.errors()


def save_artifact_bytes(png: bytes, path: Path) -> None:
    path.write_bytes(png)
    save_artifact(path, "viewer_character.png")
