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
A compile anywhere else is logged as a warning naming the kernel and its argument types: numba
compiles once per argument-type signature (a read-only array, as decoded messages are, is a type of
its own), so a `warm()` that missed a signature would stall a running node for seconds; the log
says which signature to add. Set NUMBA_DISABLE_JIT=1 to run the kernels as plain Python under a
debugger.
"""
from __future__ import annotations

import hashlib
import importlib
import logging
import sys
import time
import traceback
from pathlib import Path
from types import ModuleType
from typing import Callable, TypeVar

import numba
import numpy as np
from numba.core import event as numba_event

F = TypeVar("F", bound=Callable)

# Modules with kernels, in warm-up order; each compiles through its `warm()`, or through the
# function WARMED_BY names (a module above the kernels, when only their callers build real arguments).
KERNEL_MODULES: tuple[str, ...] = (
    "mocapgraph.kinematics.quat_kernels",      # (called by others: first)
    "mocapgraph.kinematics.solving.global_fit_kernels",
    "mocapgraph.kinematics.solving.joint_kernels",
    "mocapgraph.retarget.source_kernels",
    "mocapgraph.kinematics.solving.rigid_kernels",
    "mocapgraph.physics.controller_kernels",
    "mocapgraph.physics.posture_kernels",
    "mocapgraph.physics.state_kernels",
    "mocapgraph.retarget.frame_plan",
    "mocapgraph.retarget.kernels",
)
#: kernel module -> "module:function" that warms it
WARMED_BY: dict[str, str] = {
    "mocapgraph.retarget.source_kernels": "mocapgraph.retarget.warmup:warm_source_kernels",
    "mocapgraph.retarget.frame_plan": "mocapgraph.retarget.warmup:warm_frame_kernels",
    "mocapgraph.retarget.kernels": "mocapgraph.retarget.warmup:warm_frame_kernels",
}


def warm_one(name: str) -> None:
    """Run the warm-up of kernel module ``name`` (its `warm()`, or the function WARMED_BY names)."""
    module, _, func = WARMED_BY.get(name, f"{name}:warm").partition(":")
    getattr(importlib.import_module(module), func)()


_log = logging.getLogger("mocapgraph.jit")
_warming = False
runtime_compiles: list[str] = []   # "module.kernel(arg types)" compiled outside warm_all, in this process


class _RuntimeCompileReport(numba_event.Listener):
    """Logs each kernel compiled outside `warm_all` (it stalled the process for that long)."""

    def __init__(self) -> None:
        self._started: list[tuple[float, str]] = []

    def on_start(self, event: numba_event.Event) -> None:
        caller = ""
        if not _warming:   # the innermost of our frames that called into numba (not this module)
            ours = [f for f in traceback.extract_stack() if "mocapgraph" in f.filename and f.filename != __file__]
            caller = f", called from {ours[-1].filename}:{ours[-1].lineno}" if ours else ""
        self._started.append((time.perf_counter(), caller))

    def on_end(self, event: numba_event.Event) -> None:
        start, caller = self._started.pop()
        if _warming:
            return
        func = event.data["dispatcher"].py_func
        what = f"{func.__module__}.{func.__qualname__}({', '.join(map(str, event.data['args']))})"
        runtime_compiles.append(what + caller)
        _log.warning("jit: compiled %s at run time in %.1f s%s: its module's warm() does not cover these "
                     "argument types (or the cache is stale: python -m mocapgraph.jit)",
                     what, time.perf_counter() - start, caller)


if __name__ != "__main__":   # `python -m mocapgraph.jit` runs a second copy of this module
    numba_event.register("numba:compile", _RuntimeCompileReport())


def kernel(func: F) -> F:
    """Compile `func` in nopython mode, cached on disk, releasing the GIL while it runs."""
    return numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")(func)


def kernel_calling(*modules: ModuleType) -> Callable[[F], F]:
    """`kernel` for a module whose kernels call kernels of ``modules``: their sources join the cache stamp.

    numba checks a cached kernel against its own source file only, while the machine code it keeps
    has its callees compiled in: a kernel calling into another module that changed would load the
    old callee from its cache, silently. With ``kernel = kernel_calling(quat_kernels)`` at the top of
    a kernel module, its kernels' caches are stale when ``quat_kernels``' source (or what that one
    calls in turn) changes, and compile again (logged as a run-time compile unless warming)."""
    deps = tuple(modules)

    def wrap(func: F) -> F:
        disp = kernel(func)
        caller = sys.modules.get(func.__module__)
        if caller is not None:
            caller._kernel_dependencies = deps   # (for the stamp of a module calling this one)
        cache_file = getattr(getattr(disp, "_cache", None), "_cache_file", None)
        if cache_file is None or not hasattr(cache_file, "_source_stamp"):   # fail loudly, never stale
            raise RuntimeError(f"numba {numba.__version__}: jit.kernel_calling does not know this cache layout")
        cache_file._source_stamp = (cache_file._source_stamp, _sources_stamp(deps))
        return disp

    return wrap


def _sources_stamp(modules: tuple[ModuleType, ...]) -> str:
    """A hash of the source files of ``modules`` and, recursively, of the modules their kernels call."""
    h = hashlib.sha256()
    for m in modules:
        h.update(m.__name__.encode())
        h.update(Path(m.__file__).read_bytes())
        h.update(_sources_stamp(getattr(m, "_kernel_dependencies", ())).encode())
    return h.hexdigest()


def readonly(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a``, for `warm()` calls: arrays decoded from messages are read-only,
    and numba compiles a separate signature for them."""
    view = a.view()
    view.flags.writeable = False
    return view


def warm_all(modules: tuple[str, ...] = KERNEL_MODULES) -> dict[str, float]:
    """Run each kernel module's warm-up (see `warm_one`); returns seconds per module."""
    global _warming
    spent: dict[str, float] = {}
    _warming = True
    try:
        for name in modules:
            start = time.perf_counter()
            warm_one(name)
            spent[name] = time.perf_counter() - start
    finally:
        _warming = False
    return spent


def main() -> int:
    """Compile and cache every registered kernel; print the time each module took."""
    for name, seconds in warm_all().items():
        print(f"jit: {name} ready in {seconds:.2f} s")
    return 0


if __name__ == "__main__":
    from mocapgraph.jit import main as package_main   # the copy the kernel modules import
    sys.exit(package_main())
