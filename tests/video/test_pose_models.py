"""The heavy pose model's install from npm (checksum, refusals) and the estimator never downloading it."""
from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

pytest.importorskip("mediapipe")

from mocapgraph.video.estimator import PoseEstimator  # noqa: E402
from mocapgraph.video.frames import VideoUnavailable  # noqa: E402
from mocapgraph.video.pose_models import (HEAVY_FILE, HEAVY_SHA256, NPM_PACKAGE, install_heavy, installed,  # noqa: E402
                                          landmark_dir, resolve)

ROOT = Path(__file__).resolve().parents[2]


def test_install_checks_the_checksum_and_refuses_in_one_line(tmp_path) -> None:
    target = tmp_path / "mediapipe_models"
    target.mkdir()
    with pytest.raises(ValueError, match=r"node_modules/@mediapipe/pose/pose_landmark_heavy.tflite is absent"):
        install_heavy(tmp_path, target)
    fake = tmp_path / NPM_PACKAGE
    fake.mkdir(parents=True)
    (fake / HEAVY_FILE).write_bytes(b"not the model")
    with pytest.raises(ValueError, match="SHA-256 differs from the pinned model's; not installed"):
        install_heavy(tmp_path, target)
    assert not (target / HEAVY_FILE).exists()
    npm_copy = ROOT / NPM_PACKAGE / HEAVY_FILE
    if not npm_copy.is_file():
        pytest.skip("node_modules/@mediapipe/pose is absent (scripts/setup.sh runs npm ci)")
    shutil.copyfile(npm_copy, fake / HEAVY_FILE)
    assert install_heavy(tmp_path, target) == f"heavy pose model installed into {target}"
    assert hashlib.sha256((target / HEAVY_FILE).read_bytes()).hexdigest() == HEAVY_SHA256
    assert install_heavy(tmp_path, target) == f"heavy pose model already in {target}"


def test_setup_put_the_heavy_model_where_mediapipe_looks() -> None:
    if not (ROOT / NPM_PACKAGE).is_dir():
        pytest.skip("node_modules/@mediapipe/pose is absent (scripts/setup.sh runs npm ci)")
    assert installed("heavy") and installed("full")
    assert hashlib.sha256((landmark_dir() / HEAVY_FILE).read_bytes()).hexdigest() == HEAVY_SHA256
    assert resolve("auto") == ("heavy", "") and resolve("full") == ("full", "")


def test_an_unknown_model_is_refused_in_one_line() -> None:
    with pytest.raises(VideoUnavailable, match=r"^unknown pose model 'huge' \(expected full or heavy\)$"):
        PoseEstimator(model="huge")
