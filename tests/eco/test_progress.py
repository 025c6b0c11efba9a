"""Every batch command draws a tqdm bar on a terminal (a real pseudo-terminal) and none into a
pipe, as in a CI log."""
from __future__ import annotations

import fcntl
import os
import pty
import select
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run(args: list[str], tty: bool, cwd: Path) -> tuple[int, str]:
    """Run ``mocapgraph ARGS`` with stderr on a pseudo-terminal (tty) or a pipe; (code, stderr)."""
    env = dict(os.environ, COLUMNS="100")
    env.pop("MOCAPGRAPH_PROGRESS", None)
    cmd = [sys.executable, "-m", "mocapgraph", *args]
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
    trunc = tmp / "cut.mcap"
    data = c.rom_bag.read_bytes()
    trunc.write_bytes(data[: int(len(data) * 0.7)])
    return {
        "calibrating": ["calibrate", str(c.rom), "--layout", "kiip_full_body", "-o", str(tmp / "m.json")],
        "solving": ["solve", str(c.trial), "--model", str(c.model), "-o", str(tmp / "o.csv")],
        "converting": ["bag", "convert", str(c.rom), "-o", str(tmp / "b.mcap")],
        "scanning": ["bag", "info", str(c.rom_bag)],
        "recovering": ["bag", "recover", str(trunc), "-o", str(tmp / "rec.mcap")],
        "exporting": ["bag", "export-foxglove", str(c.rom_bag), "-o", str(tmp / "fox.mcap"), "-f"],
    }


@pytest.mark.parametrize("tty", [True, False], ids=["terminal", "pipe"])
def test_batch_commands_show_a_bar_only_on_a_terminal(capture, tmp_path, tty):
    for label, args in _commands(capture, tmp_path).items():
        code, err = _run(args, tty, tmp_path)
        assert code == 0, (label, err)
        if tty:
            assert f"{label}: 100%|" in err and "\r" in err, (label, err)
        else:
            assert "%|" not in err and "\r" not in err and label not in err, (label, err)
