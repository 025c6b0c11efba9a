"""Every batch command draws a tqdm bar on a terminal (a real pseudo-terminal) and none into a
pipe, as in a CI log."""
from __future__ import annotations

import fcntl
import json
import os
import pty
import select
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest

from mocapgraph.bag.reader import BagReader
from mocapgraph.bag.writer import BagWriter
from mocapgraph.cli import main

pytestmark = pytest.mark.slow  # batch commands under a pseudo-terminal

ROOT = Path(__file__).resolve().parents[2]


def _run(args: list[str], tty: bool, cwd: Path, module: bool = True) -> tuple[int, str]:
    """Run ``mocapgraph ARGS`` (or ``python ARGS``) with stderr on a pseudo-terminal (tty) or a
    pipe; (code, stderr)."""
    env = dict(os.environ, COLUMNS="100")
    env.pop("MOCAPGRAPH_PROGRESS", None)
    cmd = [sys.executable, *(["-m", "mocapgraph"] if module else []), *args]
    if not tty:
        p = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd, timeout=120)
        return p.returncode, p.stderr
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 100, 0, 0))  # a terminal has a size
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=slave, stdin=subprocess.DEVNULL, env=env, cwd=cwd)
    os.close(slave)
    chunks = []
    while True:
        r, _, _ = select.select([master], [], [], 0.2)
        if r:
            try:
                data = os.read(master, 65536)
            except OSError:  # EIO: the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        elif p.poll() is not None:
            break
    os.close(master)
    return p.wait(timeout=60), b"".join(chunks).decode(errors="replace")


def _commands(c, tmp: Path) -> dict[str, list[str]]:
    # a recorder's bag closes a chunk every flush; cut one mid-way, so whole chunks remain to recover
    chunked = tmp / "chunked.mcap"
    with BagReader(c.rom_bag) as src, BagWriter(chunked, chunk_kb=16) as dst:
        for m in src.messages():
            dst.write_frames(m.frames(), log_ns=m.log_ns)
    trunc = tmp / "cut.mcap"
    data = chunked.read_bytes()
    trunc.write_bytes(data[: int(len(data) * 0.7)])
    cmds = {
        "calibrating": ["calibrate", str(c.rom), "--layout", "kiip_full_body", "-o", str(tmp / "m.json")],
        "solving": ["solve", str(c.trial), "--model", str(c.model), "-o", str(tmp / "o.csv")],
        "converting": ["bag", "convert", str(c.rom), "-o", str(tmp / "b.mcap")],
        "scanning": ["bag", "info", str(c.rom_bag)],
        "recovering": ["bag", "recover", str(trunc), "-o", str(tmp / "rec.mcap")],
        "exporting": ["bag", "export-foxglove", str(c.rom_bag), "-o", str(tmp / "fox.mcap"), "-f"],
        "building": ["posture-db", "build", "synthetic:walk", "-o", str(tmp / "db.npz")],
    }
    bvh = (ROOT / ".." / "shared" / "data" / "bvh" / "cmu" / "131_01.bvh").resolve()
    if bvh.exists():  # a real capture, read in place (left out where ../shared/data is absent)
        cmds["retargeting"] = ["retarget", str(bvh), "--character", "standard_20", "-o", str(tmp / "r.bvh")]
    return cmds


# Every command in one process (the command's own main()), its stderr a pseudo-terminal.
DRIVER = """import json, sys
from mocapgraph.cli import main
for args in json.loads(sys.argv[1]):
    print("---", args[0], args[1], file=sys.stderr, flush=True)
    if main(args):
        sys.exit(f"failed: {args}")
"""


def test_batch_commands_show_a_bar_on_a_terminal(capture, tmp_path):
    cmds = _commands(capture, tmp_path)
    code, err = _run(["-c", DRIVER, json.dumps(list(cmds.values()))], True, tmp_path, module=False)
    assert code == 0, err
    parts = err.split("--- ")[1:]
    assert len(parts) == len(cmds), err
    for (label, _), part in zip(cmds.items(), parts):
        assert f"{label}: 100%|" in part and "\r" in part, (label, part)


def test_and_none_into_a_log(capture, tmp_path, capsys, monkeypatch):
    """The same commands with stderr captured (not a terminal), as in a CI log."""
    monkeypatch.delenv("MOCAPGRAPH_PROGRESS", raising=False)
    for label, args in _commands(capture, tmp_path).items():
        code = main(args)
        err = capsys.readouterr().err
        assert code == 0, (label, err)
        assert "%|" not in err and "\r" not in err and label not in err, (label, err)
