"""`graph check` refuses what `launch` could not run, in one line, fast, exit 2; `bag recover` keeps files."""
from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from mocapgraph.bag.writer import BagWriter
from mocapgraph.cli import main
from mocapgraph.messages import MarkerFrame

GOOD_NODE = "  - name: pattern\n    type: marker_test_pattern\n"


def check(path: Path, *args: str, timeout: float = 10.0) -> tuple[int, str, float]:
    """Exit code, stderr+stdout and seconds of ``mocapgraph graph check`` run in this process
    (in a thread, so a hang is a failure, not a stuck test run)."""
    box: dict = {}
    err, out = io.StringIO(), io.StringIO()

    def run() -> None:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            box["rc"] = main(["graph", "check", str(path), *args])

    t0 = time.monotonic()
    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(timeout)
    elapsed = time.monotonic() - t0
    assert not t.is_alive(), f"graph check of {path.name} still running after {timeout} s"
    return box.get("rc"), err.getvalue() + out.getvalue(), elapsed


def alias_bomb() -> str:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for i in range(1, 10):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    return "\n".join(lines) + "\nnodes:\n" + GOOD_NODE


CASES = {
    "binary": (lambda p: p.write_bytes(bytes(range(256)) * 8), "binary data"),
    "latin1": (lambda p: p.write_bytes(b"nodes:\n  - name: caf\xe9\n"), "not UTF-8"),
    "empty": (lambda p: p.write_text("# nothing here\n"), "empty file"),
    "no_nodes": (lambda p: p.write_text("args: {}\nnodes: []\n"), "no node to run"),
    "fifo": (lambda p: os.mkfifo(p), "is a FIFO"),
    "directory": (lambda p: p.mkdir(), "is a directory"),
    "oversized": (lambda p: p.write_text("nodes:\n" + GOOD_NODE + "#" * (1 << 21) + "\n"), "at most 1048576"),
    "deep": (lambda p: p.write_text("nodes: " + "[" * 20000 + "]" * 20000 + "\n"), "nested deeper"),
    "alias_bomb": (lambda p: p.write_text(alias_bomb()), "expands to more than"),
    "slash_name": (lambda p: p.write_text("nodes:\n  - name: ../../etc/x\n    type: marker_test_pattern\n"),
                   "is not a node name"),
    "nul_name": (lambda p: p.write_text('nodes:\n  - name: "a\\0b"\n    type: marker_test_pattern\n'),
                 "is not a node name"),
    "nan_param": (lambda p: p.write_text(GOOD_NODE.join(["nodes:\n", "    params: {rate_hz: .nan}\n"])),
                  "finite number"),
    "inf_param": (lambda p: p.write_text(GOOD_NODE.join(["nodes:\n", "    params: {rate_hz: .inf}\n"])),
                  "finite number"),
    "bad_host": (lambda p: p.write_text(GOOD_NODE.join(["nodes:\n", "    host: 'not a host!'\n"])),
                 "not an IP address or host name"),
    "foreign_host": (lambda p: p.write_text(GOOD_NODE.join(["nodes:\n", "    host: 192.0.2.77\n"])),
                     "not an address of this machine"),
    "inf_respawn": (lambda p: p.write_text(GOOD_NODE.join(["nodes:\n", "    respawn_delay: .inf\n"])),
                    "finite number of seconds"),
}


@pytest.fixture(scope="module", autouse=True)
def _warm(tmp_path_factory) -> None:
    """Import time is not check time: run one good check first."""
    p = tmp_path_factory.mktemp("warm") / "ok.yaml"
    p.write_text("nodes:\n" + GOOD_NODE)
    assert check(p, timeout=60)[0] == 0


@pytest.mark.timing  # a wall-clock bound (a hang or a quadratic path fails it)
@pytest.mark.parametrize("case", sorted(CASES))
def test_graph_check_refuses_in_one_line(case: str, tmp_path: Path) -> None:
    make, words = CASES[case]
    path = tmp_path / f"{case}.yaml"
    make(path)
    rc, text, elapsed = check(path)
    print(f"{case}: {elapsed:.3f} s: {text.strip()[:150]}")
    assert rc == 2, text
    lines = text.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"mocapgraph: {path}"), text
    assert words in text, text
    assert "Traceback" not in text
    assert elapsed < 2.0


def test_long_tmpdir_is_refused_up_front(tmp_path: Path, monkeypatch) -> None:
    import tempfile

    deep = tmp_path / ("d" * 90)
    deep.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(deep))
    path = tmp_path / "g.yaml"
    path.write_text("nodes:\n" + GOOD_NODE)
    rc, text, _ = check(path)
    assert rc == 2 and "set TMPDIR to a shorter directory" in text and len(text.strip().splitlines()) == 1, text
    monkeypatch.setattr(tempfile, "tempdir", None)
    assert check(path)[0] == 0


@pytest.mark.timing  # a wall-clock bound (a hang or a quadratic path fails it)
def test_the_check_is_linear_in_nodes(tmp_path: Path) -> None:
    def graph(n: int) -> Path:
        p = tmp_path / f"n{n}.yaml"
        p.write_text("nodes:\n" + "".join(f"  - name: p{i}\n    type: marker_test_pattern\n"
                                          f"    remap: {{markers: m{i}, marker_layout: l{i}}}\n" for i in range(n)))
        return p

    small, big = graph(300), graph(1200)
    check(small)  # warm imports
    rc_s, _, t_s = check(small, timeout=60)
    rc_b, text, t_b = check(big, timeout=60)
    print(f"graph check: 300 nodes {t_s:.2f} s, 1200 nodes {t_b:.2f} s (ratio {t_b / t_s:.1f}, linear 4)")
    assert rc_s == 0 and rc_b == 0, text
    assert t_b / t_s < 8  # quadratic would be 16


def test_check_runs_as_a_command_with_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "bin.yaml"
    path.write_bytes(b"\x00\x01\x02" * 100)
    r = subprocess.run([sys.executable, "-m", "mocapgraph", "graph", "check", str(path)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "binary data" in r.stderr, r.stderr


def _bag(path: Path) -> None:
    import numpy as np

    with BagWriter(str(path)) as w:
        for i in range(50):
            w.write("markers", MarkerFrame(frame_number=i, rate_hz=100.0, positions=np.zeros((2, 3)),
                                           valid=np.ones(2, bool), residual=np.zeros(2, np.float32)),
                    seq=i + 1, capture_ns=i * 10_000_000)


def test_bag_recover_keeps_an_existing_output_and_fails_on_a_non_bag(tmp_path: Path, capsys) -> None:
    src = tmp_path / "a.mcap"
    _bag(src)
    out = tmp_path / "precious.mcap"
    out.write_bytes(b"keep me")
    assert main(["bag", "recover", str(src), "-o", str(out)]) == 2
    assert "--force" in capsys.readouterr().err and out.read_bytes() == b"keep me"
    assert main(["bag", "recover", str(src), "-o", str(out), "--force"]) == 0
    assert out.read_bytes()[:5] == b"\x89MCAP"
    tiny = tmp_path / "tiny.mcap"
    tiny.write_bytes(b"\x89MCAP0\r\n\x00\x01")  # 10 bytes: the magic and nothing else
    assert main(["bag", "recover", str(tiny), "-o", str(tmp_path / "t.mcap")]) == 2
    assert "nothing to recover" in capsys.readouterr().err and not (tmp_path / "t.mcap").exists()
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(os.urandom(10))
    assert main(["bag", "recover", str(junk)]) == 2
    assert "not an MCAP file" in capsys.readouterr().err
