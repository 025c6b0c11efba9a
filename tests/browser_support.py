"""One headless Chromium per test process: where Debian's browser is and the flags every browser test uses.

Playwright's sync API allows one session per process, so every test that needs a browser takes the
``browser`` fixture (tests/conftest.py: one Chromium for consecutive modules using it) instead of starting its own.
"""
from __future__ import annotations

import shutil

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--no-first-run", "--autoplay-policy=no-user-gesture-required"]
