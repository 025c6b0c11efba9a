"""A full disk: one line, a non-zero exit, what reached the disk kept, no empty bags (issue 30, item 7).

The disk is real: a 256 KiB tmpfs mounted for the test (root only; skipped otherwise). A real
graph streams markers into it, through ``mocapgraph bag record`` and through a respawning
``bag_recorder`` node; the bags that filled it are read back with the mcap library's own stream
reader (an independent reader, not ours).
"""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from graph_helpers import wait_until

SIZE = "256k"


@pytest.fixture
def full_disk(tmp_path):
    """A folder on its own 256 KiB tmpfs (unmounted at the end)."""
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    mnt = tmp_path / "small_disk"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={SIZE}", "tmpfs", str(mnt)], capture_output=True, text=True)
    if r.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def _messages_kept(path: Path) -> int:
    """Messages the mcap library's stream reader finds in ``path`` before the cut (no footer needed)."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    n = 0
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, skip_magic=False).records:
                n += isinstance(rec, Message)
        except Exception:  # noqa: BLE001 - the file ends mid-record where the disk filled: count what came before
            pass
    return n


GRAPH = """\
nodes:
  - name: reader
    type: synthetic_actor
    params: {layout: kiip_full_body, rate_hz: 240.0, loop: true}
"""


def test_bag_record_on_a_full_disk_says_so_in_one_line_and_exits_non_zero(launch_graph, full_disk):
    g = launch_graph(GRAPH)
    g.wait_ready()
    out = full_disk / "take.mcap"
    r = g.cli("bag", "record", "markers", "-o", str(out), "--flush-s", "0.1", "--duration", "60")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode != 0, (r.stdout, r.stderr)
    assert len(lines) == 1 and "No space left on device" in lines[0] and "kept" in lines[0], r.stderr
    assert "Traceback" not in r.stdout + r.stderr
    kept = _messages_kept(out)
    assert kept > 50, kept
    assert f"{kept} messages" in lines[0] or "messages written before are kept" in lines[0]
    assert g.proc.poll() is None
    g.stop()


def test_a_respawning_recorder_on_a_full_disk_logs_one_line_per_try_and_leaves_no_empty_bags(launch_graph, full_disk):
    g = launch_graph(GRAPH + f"""\
  - name: rec
    type: bag_recorder
    params: {{path: {full_disk / "node.mcap"}, topics: [markers], flush_s: 0.1}}
    respawn: true
    respawn_delay: 0.2
""")
    g.wait_ready()
    wait_until(lambda: g.output.count("cannot record") >= 3, timeout=60, what="three failed tries", graph=g)
    g.stop()
    files = sorted(p.name for p in full_disk.iterdir())
    assert files == ["node.mcap"], files          # the one that filled the disk; no empty node_N.mcap per respawn
    assert _messages_kept(full_disk / "node.mcap") > 50
    errors = [ln for ln in g.lines if ln.startswith("[rec]") and "ERROR" in ln]
    assert all("cannot record" in ln and "No space left on device" in ln for ln in errors), errors
    assert "messages written before are kept" in errors[0] and "nothing reached the disk" in errors[1], errors
    assert "Traceback" not in g.output
