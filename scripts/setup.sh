#!/usr/bin/env bash
# Set up a machine for mocapgraph: a virtual environment in .venv with the package, its test
# tools and the video extra (the pose estimator); as root, Debian's Chromium (the viewer's browser
# tests), graphviz and npm; then the npm packages of package.json (three.js, the glTF validator,
# mediapipe's heavy pose model). What cannot be installed is skipped with a note, and the tests that
# need it skip. Safe to run again: it only does what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
  .venv/bin/python -m pip install --quiet --upgrade pip
fi
stamp=.venv/.mocapgraph-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  .venv/bin/python -m pip install --quiet -e '.[test,video]'
  # the pose estimator: the last mediapipe whose wheel ships its pose models (nothing fetched at run
  # time); --no-deps leaves out the jax/jaxlib it declares for its model maker (~0.4 GB, never imported)
  .venv/bin/python -m pip install --quiet --no-deps 'mediapipe==0.10.14'
  touch "$stamp"
fi
# Compile the per-frame kernels once (cached on disk), so no node or test pays for it.
.venv/bin/python -m mocapgraph.jit

# Debian packages: chromium (browser tests of the viewer), graphviz (graph show --format png), npm
# (the node packages below).
missing=""
command -v chromium >/dev/null 2>&1 || missing="$missing chromium"
command -v dot >/dev/null 2>&1 || missing="$missing graphviz"
command -v npm >/dev/null 2>&1 || missing="$missing npm"
if [ -n "$missing" ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing Debian packages:$missing"
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null) \
      || echo "setup: could not install$missing; the tests that need them will be skipped"
  else
    echo "setup: missing$missing (sudo apt-get install$missing); the tests that need them will be skipped"
  fi
fi

# npm packages (package.json, pinned by package-lock.json: the Khronos glTF validator, three.js,
# @mediapipe/pose) into node_modules/; without npm the tests that need them are skipped.
if command -v npm >/dev/null 2>&1; then
  if [ ! -f node_modules/.package-lock.json ] || [ package-lock.json -nt node_modules/.package-lock.json ]; then
    npm ci --no-audit --no-fund --silent || echo "setup: npm ci failed; the glTF validator and three.js tests will be skipped"
  fi
  # the estimator's heavy pose model, from @mediapipe/pose to where mediapipe looks (SHA-256 checked;
  # mediapipe's wheel lacks it and would otherwise download it from the web)
  .venv/bin/python -m mocapgraph.video.pose_models || true
else
  echo "setup: npm missing (sudo apt-get install npm); the glTF validator tests will be skipped"
fi
