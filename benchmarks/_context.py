"""Print one context line beside a benchmark's figures: its seed, data, split, load and commit.

Issue 28: a figure without the seed it was drawn with, the data and split it ran on and the load it
ran under is hard to trust or to compare. Every benchmark calls :func:`print_context` at the start
of its run, and once per section where a section runs on different data:

    context: seed 0; data synthetic actor kiip_full_body seed 0; split none; load 1.23 on 2 cores; commit 63b2188

``seed`` is the seed (or seeds) of every random source the figures depend on, or ``None`` for "no
random input"; ``data`` says what ran (a synthetic actor and its seed, the path of a real capture,
generated frames); ``split`` which frames or which train/test split (``None``: "none").
Standard library only.
"""
from __future__ import annotations

import functools
import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@functools.lru_cache(maxsize=1)
def commit() -> str:
    """``git rev-parse --short HEAD`` of the repository, "+dirty" when tracked files other than
    benchmarks/RESULTS.md have changes; "unknown" without git."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                              text=True, timeout=10)
        if head.returncode != 0 or not head.stdout.strip():
            return "unknown"
        status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                                capture_output=True, text=True, timeout=10)
        dirty = any(line[3:].strip() != "benchmarks/RESULTS.md" for line in status.stdout.splitlines())
        return head.stdout.strip() + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _seed(seed) -> str:
    if seed is None:
        return "none (no random input)"
    if isinstance(seed, (list, tuple)):
        return ", ".join(str(s) for s in seed)
    return str(seed)


def context_line(seed, data: str, split: str | None = None, section: str = "") -> str:
    """The one line: ``context[ (section)]: seed ...; data ...; split ...; load X on N cores; commit H``."""
    head = f"context ({section})" if section else "context"
    return (f"{head}: seed {_seed(seed)}; data {data}; split {split or 'none'}; "
            f"load {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; commit {commit()}")


def print_context(seed, data: str, split: str | None = None, section: str = "") -> None:
    """Print :func:`context_line` (flushed, so it lands before the figures it belongs to)."""
    print(context_line(seed, data, split, section), flush=True)
