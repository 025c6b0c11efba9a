"""Run a file library's read in a forked child with a memory cap and a time limit: :func:`capped_call`.

Why: ezc3d is C++ and trusts the counts a C3D file states. One flipped byte in a parameter's
dimensions made it allocate 4-12 GB; others make it crash outright (SIGSEGV in ~100 of ~1300
one-byte changes to the shared C3D files' headers and parameters). Neither can be caught in
the calling process, and no pre-check can foresee every fault of someone else's parser. In a
child the allocation meets ``RLIMIT_AS`` (the child's address space at the fork plus
``budget_bytes``), a hang meets ``SIGALRM``, a crash is a child's exit status, and the caller
gets one line (:class:`CappedCallError`) instead of losing its process.

The child returns its result by pickle over a pipe; only the caller's own function runs there,
so the pickle carries plain data (arrays, strings) the caller asked for. Where ``os.fork`` does
not exist the function runs in-process, uncapped.
"""
from __future__ import annotations

import faulthandler
import os
import pickle
import signal
from typing import Any, Callable

try:
    import resource
except ImportError:  # not POSIX: capped_call runs in-process there
    resource = None  # type: ignore[assignment]
_MiB = 1 << 20


class CappedCallError(Exception):
    """The capped call failed: crashed, ran out of its memory budget, timed out or raised.

    ``str(err)`` is one line saying which; ``kind`` is "crash", "memory", "time" or "error".
    """

    def __init__(self, kind: str, message: str) -> None:
        self.kind = kind
        super().__init__(" ".join(message.split()))


def _address_space_bytes() -> int | None:
    """This process's current virtual size (bytes), from /proc; None where unreadable."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _child(fn: Callable[..., Any], args: tuple, budget_bytes: int, timeout_s: float, w: int) -> None:
    """Body of the forked child: cap, call, send ("ok", result) or (kind, message); never returns."""
    try:
        faulthandler.disable()  # a crash is reported by the caller in one line, not as a dump here
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.SIG_DFL)  # Ctrl-C ends the child; the caller reports it
        now = _address_space_bytes()
        if now is not None:
            cap = now + int(budget_bytes)
            resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
        signal.alarm(max(1, int(timeout_s + 0.999)))
        try:
            out: tuple = ("ok", fn(*args))
        except MemoryError:
            out = ("memory", "")
        except BaseException as exc:  # noqa: BLE001 - everything goes back to the caller as data
            msg = " ".join(str(exc).split()) or type(exc).__name__
            out = ("memory" if "bad_alloc" in msg else "error", msg)
        try:
            data = pickle.dumps(out, protocol=pickle.HIGHEST_PROTOCOL)
        except MemoryError:
            data = pickle.dumps(("memory", ""))
        with os.fdopen(w, "wb") as fh:
            fh.write(data)
    finally:
        os._exit(0)  # no atexit handlers, no flush of the parent's buffered output


def capped_call(fn: Callable[..., Any], *args: Any, budget_bytes: int, timeout_s: float,
                what: str) -> Any:
    """``fn(*args)`` run in a forked child allowed ``budget_bytes`` more address space and
    ``timeout_s`` seconds; its return value (picklable) or :class:`CappedCallError`.

    ``what`` names the work in the error ("ezc3d" -> "ezc3d crashed (SIGSEGV)").
    """
    if not hasattr(os, "fork") or resource is None:
        return fn(*args)
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child's lines run in the child
        os.close(r)
        _child(fn, args, budget_bytes, timeout_s, w)
    os.close(w)
    try:
        with os.fdopen(r, "rb") as fh:
            data = fh.read()
        _, status = os.waitpid(pid, 0)
    except BaseException:
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass
        raise
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        if sig == signal.SIGALRM:
            raise CappedCallError("time", f"{what} took longer than {timeout_s:.0f} s")
        if sig == signal.SIGINT:
            raise KeyboardInterrupt
        name = signal.Signals(sig).name if sig in signal.Signals._value2member_map_ else str(sig)
        raise CappedCallError("crash", f"{what} crashed ({name})")
    try:
        kind, value = pickle.loads(data)
    except Exception:  # noqa: BLE001 - a child cut off mid-write
        raise CappedCallError("crash", f"{what} ended without a result") from None
    if kind == "ok":
        return value
    if kind == "memory":
        raise CappedCallError("memory", f"{what} needed more than the {budget_bytes / _MiB:.0f} MB "
                                        "this file's size allows")
    raise CappedCallError("error", value)
