"""The estimator's two pose landmark models: where each lives, and installing the heavy one from npm.

mediapipe 0.10.14's wheel ships the ``full`` landmark model. Its ``heavy`` model (BlazePose GHUM
Heavy: more accurate landmarks, about 3 times the cost) is not in the wheel, and mediapipe would
download it from Google's storage the first time it is asked for. We never let it: the npm package
``@mediapipe/pose`` (pinned in package.json, installed by ``npm ci`` from the npm registry) ships the
same file, and ``python -m mocapgraph.video.pose_models`` (run by scripts/setup.sh) copies it, its
SHA-256 checked, to where mediapipe looks (``mediapipe/modules/pose_landmark/``). The estimator asks
for the heavy model only when that file is there. Triangulating recorded video runs ``auto`` (heavy
when installed: its image landmarks keep every bone within 5 % on the demo, the full model's forearm
5.3-5.5 %); one camera runs ``full`` (its metric 3D estimate is the better one: thighs and shanks
within 10 % of the triangulated ones, the heavy model's within 19 %), and so do live cameras, for speed.
"""
from __future__ import annotations

import hashlib
import shutil
import sys
from pathlib import Path

POSE_MODELS = ("full", "heavy")
CHOICES = ("auto",) + POSE_MODELS          # auto: heavy when installed, else full (with a note)
COMPLEXITY = {"full": 1, "heavy": 2}      # mediapipe's model_complexity of each
HEAVY_FILE = "pose_landmark_heavy.tflite"
HEAVY_SHA256 = "59e42d71bcd44cbdbabc419f0ff76686595fd265419566bd4009ef703ea8e1fe"   # @mediapipe/pose 0.5.1675469404
NPM_PACKAGE = Path("node_modules") / "@mediapipe" / "pose"
INSTALL_HINT = "scripts/setup.sh installs it (make setup) from npm's @mediapipe/pose; or use pose_model full"


def landmark_dir() -> Path | None:
    """mediapipe's folder of pose landmark models, None when mediapipe is not installed."""
    try:
        import mediapipe
    except ImportError:
        return None
    return Path(mediapipe.__file__).parent / "modules" / "pose_landmark"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def installed(model: str) -> bool:
    """Whether the estimator can run ``model`` (full or heavy) without fetching anything."""
    folder = landmark_dir()
    if folder is None:
        return False
    name = "pose_landmark_full.tflite" if model == "full" else HEAVY_FILE
    return (folder / name).is_file()


def resolve(model: str) -> tuple[str, str]:
    """The model to run for a ``pose_model`` setting and a note ('' when none): ``auto`` is heavy
    when it is installed, else full, saying so."""
    if model != "auto":
        return model, ""
    if installed("heavy"):
        return "heavy", ""
    return "full", f"the heavy pose model is not installed ({INSTALL_HINT.split(';')[0]}): using full"


def install_heavy(root: Path, folder: Path | None = None) -> str:
    """Copy the heavy model from ``root``/node_modules/@mediapipe/pose into ``folder`` (mediapipe's),
    its checksum verified; a line saying what was done. ValueError when it cannot be."""
    folder = folder or landmark_dir()
    if folder is None:
        raise ValueError("mediapipe is not installed (pip install 'mocapgraph[video]')")
    target = folder / HEAVY_FILE
    if target.is_file() and _sha256(target) == HEAVY_SHA256:
        return f"heavy pose model already in {folder}"
    source = root / NPM_PACKAGE / HEAVY_FILE
    if not source.is_file():
        raise ValueError(f"{source} is absent (npm ci installs @mediapipe/pose)")
    if _sha256(source) != HEAVY_SHA256:
        raise ValueError(f"{source}: SHA-256 differs from the pinned model's; not installed")
    partial = target.with_name(target.name + ".partial")
    shutil.copyfile(source, partial)
    partial.replace(target)
    return f"heavy pose model installed into {folder}"


def main() -> int:
    try:
        print(f"setup: {install_heavy(Path.cwd())}")
    except (ValueError, OSError) as exc:
        print(f"setup: heavy pose model not installed: {exc}; pose_model heavy will be refused")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
