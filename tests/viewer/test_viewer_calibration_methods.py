"""The viewer's calibration panel against the model file the real calibration node wrote: each
joint's centre method (functional / anatomical / regression / prior), residual and reliability
as shown in headless Chromium."""
from __future__ import annotations

import json

from graph_helpers import wait_until
from viewer_support import BusTap, free_port, real_calibration_graph, viewer_url


def test_method_column_shows_the_method_the_model_file_records(launch_graph, open_page, tmp_path):
    port = free_port()
    model_file = tmp_path / "model.json"
    # One second of gym: some joints move enough for a functional centre, others fall back to
    # the prior, so the column holds more than one method.
    g = launch_graph(real_calibration_graph(
        port, f'auto: false, gym_seconds: 1.0, model_file: "{model_file}"'))
    g.wait_ready()
    tap = BusTap(g.master, ["calibration_status"])
    try:
        page = open_page(viewer_url(g))
        page.wait('s.connected && s.calibration === "idle"', timeout=15)
        for button, state, timeout in (("find_base_pose", "base_pose_found", 20), ("capture_gym", "gym_captured", 30),
                                       ("process", "calibrated", 60)):
            page.wait(f'!document.querySelector(\'[data-calib="{button}"]\').disabled', timeout=10)
            page.page.click(f'[data-calib="{button}"]')
            wait_until(lambda: any(m.state == state for _, m in tap.of("calibration_status")),
                       what=f"the calibration node to reach {state}", timeout=timeout)
        wait_until(lambda: model_file.exists(), what="the model file")
        page.wait('s.calibration === "calibrated"', timeout=15)
        joints = json.loads(model_file.read_text())["joints"]
        expected = {j["name"]: j["quality"] for j in joints}
        methods = {n: q["method"] for n, q in expected.items()}
        print(methods)
        assert len(set(methods.values())) >= 2, methods
        rows = wait_until(lambda: (r := page.page.evaluate("""() => [...document.querySelectorAll('#joint-table tr')]
                                   .slice(1).map((tr) => [tr.cells[0].textContent, tr.cells[1].textContent,
                                   tr.cells[2].textContent, tr.querySelector('.qdot').dataset.reliable])"""))
                          and len(r) == len(expected) and r, what="the joint table")
        assert [r[0] for r in rows] == [j["name"] for j in joints]  # every joint, in the model's order
        for name, method, residual, reliable in rows:
            q = expected[name]
            assert method == q["method"], (name, method, q)
            assert reliable == str(q["reliable"]).lower(), (name, reliable, q)
            assert abs(float(residual) - 1000 * q["residual_rms"]) <= 0.051, (name, residual, q)
        # A centre from the prior is never shown reliable.
        assert all(rel == "false" for _, m, _, rel in rows if m == "prior")
        assert page.errors() == []
    finally:
        tap.close()
