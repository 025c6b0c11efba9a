"""formats.capped_call: a library call that crashes, over-allocates or hangs costs the caller one
line, not its process; a good call returns its value."""
from __future__ import annotations

import ctypes
import os
import time

import numpy as np
import pytest

from mocapgraph.formats.capped_call import CappedCallError, capped_call


def _segfault() -> None:
    ctypes.string_at(0)  # reads address 0: SIGSEGV, as ezc3d does on some damaged files


def _allocate(n_bytes: int) -> int:
    return int(np.ones(n_bytes, dtype=np.uint8).sum())


def _hang() -> None:
    while True:
        time.sleep(0.01)


def _raise() -> None:
    raise RuntimeError("bad\nformatting")


def test_a_value_comes_back() -> None:
    out = capped_call(np.arange, 5, budget_bytes=64 << 20, timeout_s=10, what="x")
    np.testing.assert_array_equal(out, np.arange(5))


def test_a_crash_is_one_line_and_the_caller_lives() -> None:
    with pytest.raises(CappedCallError, match=r"^ezc3d crashed \(SIGSEGV\)$") as e:
        capped_call(_segfault, budget_bytes=64 << 20, timeout_s=10, what="ezc3d")
    assert e.value.kind == "crash"


def test_an_allocation_over_the_budget_is_refused_and_one_within_passes() -> None:
    with pytest.raises(CappedCallError, match="needed more than the 64 MB") as e:
        capped_call(_allocate, 4 << 30, budget_bytes=64 << 20, timeout_s=30, what="ezc3d")
    assert e.value.kind == "memory"
    assert capped_call(_allocate, 16 << 20, budget_bytes=64 << 20, timeout_s=30, what="ezc3d") == 16 << 20


def test_a_hang_ends_at_the_time_limit() -> None:
    t0 = time.monotonic()
    with pytest.raises(CappedCallError, match="took longer than 1 s"):
        capped_call(_hang, budget_bytes=64 << 20, timeout_s=1, what="ezc3d")
    assert time.monotonic() - t0 < 5


def test_an_exception_comes_back_as_one_line_and_no_child_is_left() -> None:
    with pytest.raises(CappedCallError, match="^bad formatting$"):
        capped_call(_raise, budget_bytes=64 << 20, timeout_s=10, what="ezc3d")
    with pytest.raises(ChildProcessError):
        os.waitpid(-1, os.WNOHANG)  # every child was reaped
