"""``calibrate --report``: the HTML report opened in headless Chromium shows the model file's
numbers (per-joint residual, range of motion, reliability) and its figures; the PNG variant."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from mocapgraph.cli import main
from mocapgraph.kinematics.calibration.marker_residuals import marker_residuals
from mocapgraph.kinematics.model import load_model

pytestmark = pytest.mark.slow  # a browser and the report command

ROOT = Path(__file__).resolve().parents[2]


def test_report_numbers_match_the_model_file_in_chromium(capture, tmp_path, capsys, browser):
    out = tmp_path / "session"
    out.mkdir()
    code = main(["calibrate", str(capture.rom), "--layout", "kiip_full_body", "-o", str(out / "model.json"),
                 "--report", "report.html"])
    assert code == 0
    report = out / "report.html"  # a bare name lands next to the model file
    assert f"wrote {report}" in capsys.readouterr().out
    doc = json.loads((out / "model.json").read_text())

    page = browser.new_page(viewport={"width": 1200, "height": 900})
    try:
        page.goto(report.as_uri())
        rows = page.eval_on_selector_all("#joints tbody tr", """rows => rows.map(r => ({
            joint: r.querySelector('.joint').textContent, residual: r.querySelector('.residual_mm').textContent,
            rom: r.querySelector('.rom_deg').textContent, reliable: r.querySelector('.reliable').textContent,
            se: r.querySelector('.se_mm').textContent,
            frames: r.querySelector('.frames').textContent}))""")
        images = page.eval_on_selector_all(
            "figure img", "imgs => imgs.map(i => [i.alt, i.naturalWidth, i.naturalHeight])")
        layout = page.text_content("#layout")
        gym = page.text_content("#gym-frames")
        ARTIFACTS = ROOT / "artifacts"
        ARTIFACTS.mkdir(exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / "calibration_report.png"), full_page=True)
    finally:
        page.close()
    assert layout == doc["layout"] and int(gym) == doc["n_gym_frames"]
    assert [r["joint"] for r in rows] == [j["name"] for j in doc["joints"]]
    for r, j in zip(rows, doc["joints"]):
        q = j["quality"]
        assert r["residual"] == f"{q['residual_rms'] * 1000:.2f}"
        assert r["rom"] == f"{math.degrees(q['range_of_motion_rad']):.1f}"
        assert r["se"] == f"{q['centre_se'] * 1000:.2f}"   # each centre's standard error (issue 27)
        assert r["reliable"] == ("yes" if q["reliable"] else "NO") and int(r["frames"]) == q["n_frames"]
    assert sorted(a for a, _, _ in images) == ["joints", "markers", "pose"]
    assert all(w > 500 and h > 200 for _, w, h in images)  # the figures decoded in the browser


def test_png_report_and_marker_residuals(capture, tmp_path):
    assert main(["calibrate", str(capture.rom), "--layout", "kiip_full_body", "-o", str(tmp_path / "m.json"),
                 "--report", str(tmp_path / "r.png")]) == 0
    png = (tmp_path / "r.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    assert w == 1100 and h > 1200  # 10 in wide at 110 dpi, three panel rows
    # Residuals: the synthetic capture has 1 mm noise per axis, so a rigid-fit residual is about
    # sqrt(3) * 1 mm * (a little less for the fit's own freedom): check the scale, not our code.
    model = load_model(tmp_path / "m.json")
    r = marker_residuals(model, capture.markers)
    med = np.nanmedian(r) * 1000
    print(f"\nmarker residual median {med:.2f} mm (1 mm noise per axis)")
    assert 0.8 < med < 2.0 and np.isfinite(r).mean() > 0.9


def test_report_needs_html_or_png(capture, tmp_path, capsys):
    assert main(["calibrate", str(capture.rom), "--layout", "kiip_full_body", "-o", str(tmp_path / "m.json"),
                 "--report", "r.pdf"]) == 2
    assert "give a .html or .png file" in capsys.readouterr().err
