"""Compiled per-frame kernels: the one numba decorator the hot paths use, and the cache warm-up.

Why compiled code: one 20-joint frame of retargeting, one physics control step or one global-fit
iteration is a few hundred scalar operations; as numpy calls each costs 1-6 us of dispatch on
these machines, so a frame costs 200-1300 us however it is vectorised. The same arithmetic as a
numba kernel (plain loops, compiled with LLVM) runs in a few microseconds. Kernels are written
beside their math (`<part>/*_kernels.py`), keep a numpy reference that the tests compare them
to, and take and return plain float64 arrays (SI units, wxyz quaternions, as everywhere else).

`kernel` compiles lazily on first call and caches the machine code next to the source
(`__pycache__`, or numba's per-user cache when the package is read-only), so a node process
loads it in milliseconds after the first run. `python -m mocapgraph.jit` compiles every
registered kernel module once (scripts/setup.sh runs it, so tests and the demo never compile).
Set NUMBA_DISABLE_JIT=1 to run the kernels as plain Python under a debugger.
"""
from __future__ import annotations

import importlib
import sys
import time
from typing import Callable, TypeVar

import numba

F = TypeVar("F", bound=Callable)

# Modules whose `warm()` calls each of their kernels once with small inputs (compiles and caches).
KERNEL_MODULES: tuple[str, ...] = (
    "mocapgraph.kinematics.bone_follow_kernels",
    "mocapgraph.kinematics.global_fit_kernels",
    "mocapgraph.kinematics.joint_kernels",
    "mocapgraph.kinematics.retarget_source_kernels",
    "mocapgraph.kinematics.rigid_kernels",
    "mocapgraph.physics.controller_kernels",
    "mocapgraph.physics.posture_kernels",
    "mocapgraph.physics.state_kernels",
)


def kernel(func: F) -> F:
    """Compile `func` in nopython mode, cached on disk, releasing the GIL while it runs."""
    return numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")(func)


def warm_all(modules: tuple[str, ...] = KERNEL_MODULES) -> dict[str, float]:
    """Import each kernel module and run its `warm()`; returns seconds per module."""
    spent: dict[str, float] = {}
    for name in modules:
        start = time.perf_counter()
        importlib.import_module(name).warm()
        spent[name] = time.perf_counter() - start
    return spent


def main() -> int:
    """Compile and cache every registered kernel; print the time each module took."""
    for name, seconds in warm_all().items():
        print(f"jit: {name} ready in {seconds:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
