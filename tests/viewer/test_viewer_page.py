"""The viewer page in headless Chromium against a real launched graph."""
from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from viewer_support import BusTap, free_port, image_stats, save_artifact, stage_graph, viewer_url, wait_until


def finite_rows(a: np.ndarray) -> int:
    return int(np.isfinite(a).all(axis=1).sum())


@pytest.fixture(scope="module")
def stage_running(launch_module_graph):
    """The stage graph, launched once for this module: its tests only command the echo nodes and
    read, and each opens a page of its own."""
    port = free_port()
    g = launch_module_graph(stage_graph(port))
    g.wait_ready()
    return g, port


@pytest.fixture
def stage(stage_running, open_page):
    g, port = stage_running
    assert g.proc.poll() is None, g.output
    page = open_page(viewer_url(g))
    page.wait("s.connected && s.framesDrawn > 5 && s.actorsDrawn >= 4", timeout=15)
    return g, page, port


def test_stage_draws_what_the_graph_sends(stage, tmp_path):
    g, page, port = stage
    tap = BusTap(g.master, ["markers", "actor_pose", "skeleton_pose", "character_pose", "physics_state"])
    try:
        wait_until(lambda: len(tap.of("markers")) > 20, what="the test's own subscriber to get markers")
        # Drawn counts equal the finite points of the very message each stream drew, for every type.
        by_key = {
            "markers|alice|": ("markers", "positions"),
            "actor_pose|alice|alice": ("actor_pose", "joint_positions"),
            "actor_pose|bob|bob": ("actor_pose", "joint_positions"),
            "skeleton_pose|alice|alice": ("skeleton_pose", "joint_positions"),
            "character_pose|carol|carol": ("character_pose", "joint_positions"),
        }
        matched = {k: 0 for k in by_key}
        saw_nan_joint = False
        t_end = time.monotonic() + 8
        while time.monotonic() < t_end and (min(matched.values()) < 4 or not saw_nan_joint):
            s = page.stats()
            time.sleep(0.05)
            for key, (topic, field) in by_key.items():
                drawn = s["streams"][key]
                sent = [m for e, m in tap.of(topic) if m.frame_number == drawn["frame"]
                        and e.sender == key.split("|")[1]]
                if not sent:
                    continue
                assert drawn["points"] == finite_rows(getattr(sent[-1], field)), (key, drawn)
                assert drawn["total"] == len(getattr(sent[-1], field))
                matched[key] += 1
                if key == "actor_pose|alice|alice" and drawn["points"] == 15:
                    saw_nan_joint = True  # joint 6 is NaN on odd seconds: nothing drawn for it
            assert s["markersDrawn"] == s["streams"]["markers|alice|"]["points"]
            assert s["jointsDrawn"] == sum(s["streams"][k]["points"] for k in s["streams"] if k.startswith("actor_pose"))
            time.sleep(0.1)
        assert min(matched.values()) >= 4, matched
        assert saw_nan_joint, "never saw alice's NaN joint drawn as nothing"
        last_marker = tap.of("markers")[-1][1]
        assert 0 < s["markersDrawn"] < 60 and s["markersTotal"] == len(last_marker.positions)
        bodies = tap.of("physics_state")[-1][1]
        assert s["bodiesDrawn"] == finite_rows(bodies.positions) == 5
    finally:
        tap.close()

    # Bones come from the latched companions: a joint per bone bar the root.
    assert s["streams"]["actor_pose|bob|bob"]["bones"] == 15
    assert s["streams"]["character_pose|carol|carol"]["bones"] == 15

    # A reference topic (ground truth) is drawn apart from the actors, as a neutral ghost.
    truth = s["streams"]["ground_truth|truth|truth"]
    assert truth["reference"] and truth["points"] == 16 and "quality" not in truth
    assert s["referenceJointsDrawn"] == 16

    # A type the page does not know is listed, not drawn.
    assert s["topics"]["force_plates"]["type"] == "ForcePlateSample"
    assert not any(v["topic"] == "force_plates" for v in s["streams"].values())
    row = page.page.locator('#topic-table tr[data-topic="force_plates"]')
    assert row.get_attribute("data-drawn") == "not drawn"
    assert "unknown type" in row.inner_text()

    # The side panel's rate is the visualizer's own edge figure from the diagnostics topic (what
    # the performers reach at 120 Hz on a busy machine, so compared with the message, not 120).
    diag = BusTap(g.master, ["diagnostics"])
    try:
        def shown_and_sent():
            text = page.page.locator('#topic-table tr[data-topic="markers"] td').nth(2).inner_text()
            sent = [m.edge_rate_hz[list(m.edge_topics).index("markers")] for _, m in diag.of("diagnostics")
                    if m.node == "viz" and "markers" in m.edge_topics][-3:]  # the page may be a second behind
            return text not in ("–", "") and sent and any(abs(float(text) - r) <= 0.5 for r in sent)
        wait_until(shown_and_sent, what="the page's markers rate to be the visualizer's diagnostics figure")
    finally:
        diag.close()

    # Each actor can be switched off and on.
    page.page.locator('label.actor[data-key="actor_pose|bob|bob"] input').uncheck()
    page.wait('!s.streams["actor_pose|bob|bob"].visible && s.jointsDrawn === s.streams["actor_pose|alice|alice"].points')
    page.page.locator('label.actor[data-key="actor_pose|bob|bob"] input').check()
    page.wait('s.streams["actor_pose|bob|bob"].visible && s.streams["actor_pose|bob|bob"].points === 16')

    # Preset views, orbit and zoom move the camera.
    cam = "window.mocapgraphViewer.camera.cur"
    page.page.click('[data-view="top"]')
    page.page.wait_for_function(f"() => Math.abs({cam}.el - Math.PI / 2) < 0.01")
    page.page.click('[data-view="front"]')
    page.page.wait_for_function(f"() => Math.abs({cam}.az) < 0.01 && Math.abs({cam}.el - 0.12) < 0.01")
    box = page.page.locator("#canvas").bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.page.mouse.move(cx, cy)
    page.page.mouse.down()
    page.page.mouse.move(cx - 120, cy, steps=4)
    page.page.mouse.up()
    az = page.page.evaluate(f"{cam}.az")
    assert az == pytest.approx(0.72, abs=0.05)  # 120 px at 0.006 rad per px
    dist = page.page.evaluate(f"{cam}.dist")
    page.page.mouse.wheel(0, -400)
    page.page.wait_for_function(f"() => {cam}.dist < {dist} * 0.8")

    # The stage as a producer sees it: saved as an artefact and not blank.
    page.page.click('[data-view="perspective"]')
    page.page.wait_for_function(f"() => Math.abs({cam}.az - 0.62) < 0.01")
    shot = tmp_path / "viewer_stage.png"
    png = page.page.screenshot(path=str(shot))
    save_artifact(shot, "viewer_stage.png")
    img = image_stats(page.page, png)
    assert img["width"] == 1280 and img["std"] > 10 and img["colours"] > 80, img
    assert img["green"] > 150, img  # seen markers and good joints
    assert img["red"] > 5, img  # unseen markers
    assert page.errors() == []
    assert page.stats()["errors"] == []


def _status(tap: BusTap, topic: str) -> str:
    msgs = tap.of(topic)
    return msgs[-1][1].state if msgs else ""


def test_buttons_command_calibration_and_player(stage):
    g, page, port = stage
    tap = BusTap(g.master, ["calibration_command", "calibration_status", "player_command", "player_status"])
    try:
        page.wait('s.calibration === "idle" && s.player === "paused"')
        p = page.page
        for button, state in (("find_base_pose", "base_pose_found"), ("capture_gym", "gym_captured"),
                              ("process", "calibrated")):
            p.click(f'[data-calib="{button}"]')
            page.wait(f's.calibration === "{state}"', timeout=10)
            assert _status(tap, "calibration_status") == state  # the node itself is in that state
        sent = [m for _, m in tap.of("calibration_command")]
        assert [(m.target, m.command) for m in sent] == [
            ("calib", "find_base_pose"), ("calib", "capture_gym"), ("calib", "process")]
        # Per-joint reliability from the calibration status (the echo calls joint i % 5 == 0 unreliable).
        wait_until(lambda: p.locator('#joint-table .qdot[title="unreliable"]').count() == 4, what="4 unreliable joints")
        assert p.locator('#joint-table .qdot[title="good"]').count() == 12
        assert p.locator("#joint-table tr").count() == 17
        # A refused transition is reported, the state stays.
        p.click('[data-calib="process"]')
        wait_until(lambda: "cannot process" in p.locator("#calib-detail").inner_text(), what="refusal shown")
        assert _status(tap, "calibration_status") == "calibrated"

        p.click('[data-player="play"]')
        page.wait('s.player === "playing"')
        wait_until(lambda: json.loads(tap.of("player_status")[-1][1].data_json)["position_s"] > 0.3, what="playback to advance")
        p.click('[data-player="pause"]')
        page.wait('s.player === "paused"')
        t0 = json.loads(tap.of("player_status")[-1][1].data_json)["position_s"]
        p.click('[data-player="step"]')
        wait_until(lambda: json.loads(tap.of("player_status")[-1][1].data_json)["position_s"] > t0, what="a step")
        t1 = json.loads(tap.of("player_status")[-1][1].data_json)["position_s"]
        assert t1 - t0 == pytest.approx(1 / 120, abs=1e-6)
        p.evaluate("""() => { const s = document.getElementById('player-seek');
                              s.value = '12.5'; s.dispatchEvent(new Event('input'));
                              s.dispatchEvent(new Event('change')); }""")
        wait_until(lambda: math.isclose(json.loads(tap.of("player_status")[-1][1].data_json)["position_s"], 12.5),
                   what="seek to 12.5 s")
        seek = [m for _, m in tap.of("player_command") if m.command == "seek"]
        assert json.loads(seek[-1].args_json) == {"position_s": 12.5} and seek[-1].target == "player"
        wait_until(lambda: p.locator("#player-time").inner_text().startswith("12.50 s"), what="time shown")
    finally:
        tap.close()
    assert page.errors() == []
