"""Physics tests: node processes must import the test helper node (tests/physics/physics_support.py)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

PHYSICS_TESTS = Path(__file__).resolve().parent


@pytest.fixture(autouse=True)
def _support_on_path(monkeypatch) -> None:
    """Launched node processes inherit this environment and can load ``physics_support:CommandScript``."""
    old = os.environ.get("PYTHONPATH", "")
    monkeypatch.setenv("PYTHONPATH", str(PHYSICS_TESTS) + (os.pathsep + old if old else ""))
