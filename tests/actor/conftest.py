"""Actor tests: node processes must import the test source (tests/actor/actor_source.py)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

ACTOR_TESTS = Path(__file__).resolve().parent


@pytest.fixture(autouse=True)
def _source_on_path(monkeypatch) -> None:
    """Launched node processes inherit this environment and can load ``actor_source:ActorSource``."""
    old = os.environ.get("PYTHONPATH", "")
    monkeypatch.setenv("PYTHONPATH", str(ACTOR_TESTS) + (os.pathsep + old if old else ""))
