"""scripts/loaded_rounds.sh: a failed round is reported as failed, the exit status says so, and
no busy loop outlives the script (on a normal end and on SIGTERM mid-round)."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from graph_helpers import pid_alive, wait_until

pytestmark = pytest.mark.slow  # runs the loaded-rounds script and its busy loops

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "loaded_rounds.sh"
# The rounds collect this one file, not the whole suite (seconds of collection under the busy
# loops); what is selected from it, and what the script makes of the result, is the same.
ONE_FILE = "tests/launch/test_respawn_backoff.py"


def _busy_pids(text: str) -> list[int]:
    return [int(p) for p in re.search(r"busy loops \(pids ([\d ]+)\)", text).group(1).split()]


def test_a_failed_round_fails_the_run_and_the_busy_loops_stop() -> None:
    env = dict(os.environ, PYTHON=sys.executable)
    # -k matching nothing: pytest exits 5, which is a failed round
    r = subprocess.run([str(SCRIPT), "--rounds", "1", "--busy", "2", "--", ONE_FILE, "-k", "no_test_is_named_this"],
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "round 1: FAIL" in r.stdout and "0/1 rounds passed" in r.stdout
    pids = _busy_pids(r.stdout)
    assert len(pids) == 2
    wait_until(lambda: not any(pid_alive(p) for p in pids), timeout=10, what="busy loops gone")


def test_sigterm_mid_round_stops_pytest_and_the_busy_loops(tmp_path) -> None:
    env = dict(os.environ, PYTHON=sys.executable)
    out = tmp_path / "out.txt"
    with open(out, "w") as f:
        proc = subprocess.Popen([str(SCRIPT), "--rounds", "2", "--busy", "1", "--", ONE_FILE, "-k", "respawn_delay"],
                                env=env, stdout=f, stderr=subprocess.STDOUT)
    try:
        wait_until(lambda: "busy loops (pids" in out.read_text(), timeout=60, what="script started")
        pids = _busy_pids(out.read_text())
        time.sleep(1.0)  # inside the first round
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(90) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "interrupted" in out.read_text()
    wait_until(lambda: not any(pid_alive(p) for p in pids), timeout=10, what="busy loops gone")
