"""Damaged copies of real C3D files and a measured ``mocapgraph bag convert`` of each: the harness
of the C3D fuzz test and ``benchmarks/c3d_fuzz.py``.

A mutation changes one byte where a reader takes its counts and layout from: the header's
counts and blocks, and per parameter record its name length, group id, offset, type, number of
dimensions, dimensions and (for numbers) its value. Random bytes elsewhere almost never matter
(mostly marker coordinates), so they would measure nothing.
"""
from __future__ import annotations

import os
import random
import signal
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

_VALUES = (0xFF, 0x7F, 0x80, 0x00)


def structural_offsets(raw: bytes) -> dict[str, list[int]]:
    """"header" / "GROUP:NAME" -> byte offsets that give counts or layout (an Intel or DEC file)."""
    out: dict[str, list[int]] = {"header": list(range(2, 20))}
    i = (raw[0] - 1) * 512 + 4
    groups: dict[int, str] = {}
    entries: list[tuple[int, str, list[int]]] = []
    while i + 2 <= len(raw):
        nlen, gid = struct.unpack_from("bb", raw, i)
        if nlen == 0:
            break
        j = i + 2 + abs(nlen)
        if j + 4 > len(raw):
            break
        name = raw[i + 2:j].decode("latin-1").strip()
        (off,) = struct.unpack_from("<h", raw, j)
        spots = [i, i + 1, j, j + 1]
        if gid < 0:
            groups[-gid] = name
        else:
            ptype, nd = struct.unpack_from("bB", raw, j + 2)
            spots += [j + 2, j + 3] + list(range(j + 4, j + 4 + nd))
            if ptype in (2, 4):
                spots += list(range(j + 4 + nd, j + 4 + nd + ptype))
        entries.append((gid, name, spots))
        if off <= 0:
            break
        i = j + off
    for gid, name, spots in entries:
        key = f"GROUP:{name}" if gid < 0 else f"{groups.get(gid, gid)}:{name}"
        out.setdefault(key, []).extend(spots)
    return out


def mutate(raw: bytes, seed: int) -> tuple[bytes, str]:
    """One structural byte of ``raw`` changed (seeded); returns the copy and what was changed."""
    rng = random.Random(seed)
    spots = structural_offsets(raw)
    key = rng.choice(sorted(spots))
    at = rng.choice(spots[key])
    new = rng.choice([v for v in _VALUES if v != raw[at]] + [rng.randrange(256)])
    b = bytearray(raw)
    b[at] = new
    return bytes(b), f"{key} byte {at}: {raw[at]} -> {new}"


@dataclass
class Run:
    """One ``bag convert`` of a damaged file."""

    code: int  # exit code (negative: killed by that signal)
    stderr: str
    peak_rss_mb: float  # the largest resident set of the command and any child it waited for (NaN: killed)
    seconds: float

    @property
    def traceback(self) -> bool:
        return "Traceback" in self.stderr


# A small launcher between the caller and the command: Linux keeps a process's peak RSS across
# fork and exec, so a command started straight from a large process (pytest at 170 MB) would
# report that process's size. The launcher (a bare interpreter, ~10 MB) forks the command and
# prints the exit code and peak RSS (KB) that wait4 gives for it and its children.
_LAUNCHER = r"""
import os, sys
pid = os.fork()
if pid == 0:
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
    os.execv(sys.executable, [sys.executable, "-m", "mocapgraph", "bag", "convert", sys.argv[1], "-o", sys.argv[2]])
_, status, usage = os.wait4(pid, 0)
print(os.waitstatus_to_exitcode(status), usage.ru_maxrss)
"""


def convert(src: Path, out: Path, timeout_s: float = 300.0, env: dict | None = None) -> Run:
    """Run ``python -m mocapgraph bag convert SRC -o OUT`` and measure it (wait4's rusage)."""
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-c", _LAUNCHER, str(src), str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        stdout, stderr = proc.communicate()
        return Run(-signal.SIGKILL, stderr, float("nan"), time.monotonic() - t0)
    code, kb = stdout.split()[-2:]
    return Run(int(code), stderr, int(kb) / 1024.0, time.monotonic() - t0)
