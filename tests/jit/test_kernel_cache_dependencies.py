"""A cached kernel that calls a kernel of another module compiles again when that module changes
(jit.kernel_calling), where numba alone would load the old callee from its cache."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # compiles kernels from scratch

REPO = Path(__file__).resolve().parents[2]

CALLEE = """
from mocapgraph.jit import kernel

@kernel
def value():
    return {value}
"""
CALLER = """
from mocapgraph.jit import kernel_calling
from . import callee_kernels
kernel = kernel_calling(callee_kernels)

@kernel
def f():
    return callee_kernels.value() * 10
"""
CALLER_OF_CALLER = """
from mocapgraph.jit import kernel_calling
from . import caller_kernels
kernel = kernel_calling(caller_kernels)

@kernel
def g():
    return caller_kernels.f() + 1
"""
PLAIN = """
from mocapgraph.jit import kernel
from . import callee_kernels

@kernel
def f():
    return callee_kernels.value() * 10
"""


def _run(root: Path) -> str:
    env = dict(os.environ, PYTHONPATH=f"{root}{os.pathsep}{REPO}", PYTHONDONTWRITEBYTECODE="1")
    out = subprocess.run([sys.executable, "-c", "import kpkg.caller_kernels as c, kpkg.outer_kernels as o, "
                          "kpkg.plain_kernels as p; print(c.f(), o.g(), p.f())"],
                         cwd=root, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_a_changed_callee_module_recompiles_its_callers_and_theirs(tmp_path):
    pkg = tmp_path / "kpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "callee_kernels.py").write_text(CALLEE.format(value=1))
    (pkg / "caller_kernels.py").write_text(CALLER)
    (pkg / "outer_kernels.py").write_text(CALLER_OF_CALLER)
    (pkg / "plain_kernels.py").write_text(PLAIN)
    assert _run(tmp_path) == "10 11 10"
    assert list((pkg / "__pycache__").glob("caller_kernels.f-*.nbc"))   # cached on disk
    assert _run(tmp_path) == "10 11 10"                                  # (from the cache)
    (pkg / "callee_kernels.py").write_text(CALLEE.format(value=2))
    # kernel_calling's callers, direct and once removed, see the new callee; a plain kernel loads its
    # stale machine code from numba's cache (numba checks the caller's own file only): why it exists
    assert _run(tmp_path) == "20 21 10"
