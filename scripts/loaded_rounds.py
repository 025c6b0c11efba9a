"""Runs the timing-sensitive tests (``pytest -m timing``) N rounds in a row with busy loops oversubscribing the cores.

Issue 16 asks that they pass 3 rounds in a row with four busy-loop processes on the two cores.
Each round is one ``pytest -m timing`` run of this checkout; the script prints per round
pass/fail, wall time, the load average and the failed tests, and keeps each round's output
under ``artifacts/loaded_rounds/``. The busy loops are stopped on every way out: normal end,
failure, Ctrl-C, SIGTERM; and each loop also ends by itself when this script's process is gone
(it watches its parent), so none outlives a SIGKILL of the script.
Exit status: 0 when every round passed, 1 otherwise, 130 on Ctrl-C.

    scripts/loaded_rounds.sh                 # 3 rounds, 4 busy loops
    scripts/loaded_rounds.sh --rounds 1 --busy 0 -- -x -k viewer
"""
from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# Spins until its parent changes (the script died, even by SIGKILL) or it is killed.
BUSY_LOOP = "import os\np = os.getppid()\nwhile os.getppid() == p:\n    for _ in range(200000):\n        pass\n"


def start_busy(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", BUSY_LOOP], stdin=subprocess.DEVNULL,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for _ in range(n)]


def stop_busy(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.kill()
    for p in procs:
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            pass


def stop_pytest(proc: subprocess.Popen) -> None:
    """SIGINT first, so pytest's fixtures stop the graphs they launched; SIGKILL if it hangs."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    except ProcessLookupError:
        pass


def _default_sigint() -> None:
    # A script started in the background inherits SIGINT ignored; pytest must still take it
    # (its fixtures then stop the graphs they launched).
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_round(i: int, extra: list[str], log_dir: Path, timeout_s: float) -> tuple[bool, float, list[str], str]:
    """One ``pytest -m timing`` run: (passed, wall s, failed test ids, summary line)."""
    log = log_dir / f"round_{i}.log"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    cmd = [sys.executable, "-m", "pytest", "-m", "timing", "-q", "-p", "no:cacheprovider", *extra]
    t0 = time.monotonic()
    with open(log, "w") as out:
        # Its own session: the terminal's Ctrl-C reaches this script only, which then stops
        # pytest cleanly (and its graphs) instead of both racing.
        proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True, preexec_fn=_default_sigint)
        try:
            rc = proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            stop_pytest(proc)
            rc = -1
        finally:
            stop_pytest(proc)
    wall = time.monotonic() - t0
    text = log.read_text(errors="replace")
    failed = re.findall(r"^(?:FAILED|ERROR) (\S+)", text, re.M)
    summary = next((ln.strip("= ") for ln in reversed(text.splitlines()) if re.search(r"\d+ (passed|failed)", ln)),
                   "timed out" if rc == -1 else f"pytest exit {rc}")
    return rc == 0, wall, failed, summary


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    extra: list[str] = []
    if "--" in argv:
        cut = argv.index("--")
        argv, extra = argv[:cut], argv[cut + 1:]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog="anything after -- goes to pytest")
    ap.add_argument("--rounds", type=int, default=3, help="rounds in a row (default 3)")
    ap.add_argument("--busy", type=int, default=4, help="busy-loop processes (default 4: two cores oversubscribed twice)")
    ap.add_argument("--round-timeout", type=float, default=900.0, help="a round still running after this is a failure, s")
    ap.add_argument("--stop-on-failure", action="store_true", help="stop after the first failed round")
    args = ap.parse_args(argv)
    log_dir = REPO / "artifacts" / "loaded_rounds"
    log_dir.mkdir(parents=True, exist_ok=True)

    def on_term(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)  # even when started with SIGINT ignored (in the background)
    busy = start_busy(args.busy)
    print(f"{args.busy} busy loops (pids {' '.join(str(p.pid) for p in busy) or '-'}) on {os.cpu_count()} cores; "
          f"{args.rounds} rounds of pytest -m timing"
          + (f" {' '.join(extra)}" if extra else "") + f"; logs in {log_dir}", flush=True)
    results = []
    try:
        for i in range(1, args.rounds + 1):
            load0 = os.getloadavg()[0]
            ok, wall, failed, summary = run_round(i, extra, log_dir, args.round_timeout)
            results.append(ok)
            print(f"round {i}: {'PASS' if ok else 'FAIL'} in {wall:.0f} s (load {load0:.1f} -> "
                  f"{os.getloadavg()[0]:.1f}): {summary}", flush=True)
            for t in failed:
                print(f"    failed: {t}", flush=True)
            if not ok and args.stop_on_failure:
                break
    except KeyboardInterrupt:
        print("interrupted: busy loops and pytest stopped", flush=True)
        return 130
    finally:
        stop_busy(busy)
    passed = sum(results)
    print(f"{passed}/{len(results)} rounds passed" + (" in a row" if passed == len(results) == args.rounds else ""))
    return 0 if passed == len(results) == args.rounds else 1


if __name__ == "__main__":
    raise SystemExit(main())
