"""Run the benchmark scripts one at a time and rewrite benchmarks/RESULTS.md with every figure they print.

What `make bench` calls. Each script of benchmarks/ (not the helpers: ``_*.py``, ``*_nodes.py``)
runs as its own process with this interpreter (and its SCRIPT_ARGS, if any), the repository first on PYTHONPATH, from the
repository's root, with a timeout; its stdout goes into RESULTS.md verbatim, with its wall time,
exit status and the load average before and after. A script that fails or times out is recorded as
such, with the end of its stderr, and this runner then exits 1.

The header holds the date (UTC), the commit (`git rev-parse --short HEAD`, "dirty" when the tree
has changes other than RESULTS.md), the machine (cores, OS, Python) and its load average before
and after the run. The block between ``<!-- notes -->`` and ``<!-- /notes -->`` is kept as it is
from one run to the next (hand-written notes: the full suite's time, what else ran on the machine).

Usage: python benchmarks/_run_all.py [--timeout S] [--list] [SCRIPT ...]
  SCRIPT: names such as ``bus`` or ``benchmarks/bus.py``; only those run and only their sections
  are replaced, the others are kept from the previous RESULTS.md (each section carries its own
  date, commit and load). Without names every script runs and the file is written afresh.
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
RESULTS = BENCH / "RESULTS.md"
SHARED = (ROOT / ".." / "shared" / "data").resolve()   # where the scripts look for real captures
STDERR_TAIL = 40          # lines of a failed script's stderr kept in RESULTS.md
SECTION = re.compile(r"<!-- bench:(?P<name>[\w.-]+) -->\n(?P<body>.*?)<!-- /bench:(?P=name) -->\n", re.S)
NOTES = re.compile(r"<!-- notes -->\n(?P<body>.*?)<!-- /notes -->\n", re.S)
# a script's args under make bench, where its own defaults would run too long for the whole set
SCRIPT_ARGS = {"lab_pipelines.py": ["--seconds", "20"]}
DEFAULT_NOTES = ("The machine is shared with other work (the load averages beside each figure show how "
                 "much): compare the ratios each script prints against its same-run baseline, not "
                 "absolute times across runs.\n")


def scripts() -> list[Path]:
    """The benchmark scripts, as `make bench` has always selected them."""
    return [p for p in sorted(BENCH.glob("*.py")) if not p.name.startswith("_") and not p.name.endswith("_nodes.py")]


def pick(names: list[str]) -> list[Path]:
    known = {p.stem: p for p in scripts()}
    chosen = []
    for name in names:
        stem = Path(name).stem
        if stem not in known:
            sys.exit(f"_run_all: no benchmark {name!r} (known: {', '.join(known)})")
        chosen.append(known[stem])
    return chosen


def git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def commit() -> str:
    head = git("rev-parse", "--short", "HEAD") or "unknown"
    # (a pathspec, not a parse of the status lines: git() strips the output, and with it the
    # leading blank of the first " M path" line)
    changed = git("status", "--porcelain", "--", ".", ":(exclude)benchmarks/RESULTS.md").splitlines()
    return f"{head} dirty" if changed else head


def load() -> str:
    return "{:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def now() -> str:
    return dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def run_one(script: Path, timeout_s: float) -> tuple[str, bool]:
    """Run one script; return its RESULTS.md section (without the markers) and whether it failed."""
    rel = script.relative_to(ROOT).as_posix()
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    env.setdefault("PYTHONUNBUFFERED", "1")
    print(f"== {rel} (timeout {timeout_s:.0f} s, load {load()})", flush=True)
    started, load_before, date = time.monotonic(), load(), now()
    proc = subprocess.Popen([sys.executable, str(script), *SCRIPT_ARGS.get(script.name, [])], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, errors="replace", start_new_session=True)
    timed_out = False
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        timed_out = True
        # the script's own process group (its launched graphs too): SIGINT first so a launch stops
        # its nodes; a script that takes SIGINT as "skip this part" gets SIGTERM, then SIGKILL
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                pass
            try:
                out, err = proc.communicate(timeout=10)
                break
            except subprocess.TimeoutExpired:
                continue
        else:
            out, err = "", ""
    wall = time.monotonic() - started
    if timed_out:
        status = f"TIMED OUT after {timeout_s:.0f} s (killed; output so far below)"
    elif proc.returncode == 0:
        status = "ok (exit 0)"
    else:
        status = f"FAILED (exit {proc.returncode})"
    print(out, end="" if out.endswith("\n") or not out else "\n", flush=True)
    print(f"-- {rel}: {status}, {wall:.1f} s", flush=True)
    lines = [" ".join([f"## {rel}", *SCRIPT_ARGS.get(script.name, [])]), "",
             f"- status: {status}",
             f"- wall time: {wall:.1f} s",
             f"- run: {date}, commit {commit()}",
             f"- load average (1, 5, 15 min): {load_before} before, {load()} after",
             "", "```", (out or "(no output)").rstrip("\n"), "```", ""]
    if timed_out or proc.returncode != 0:
        tail = "\n".join((err or "(no stderr)").rstrip("\n").splitlines()[-STDERR_TAIL:])
        lines += [f"stderr (last {STDERR_TAIL} lines):", "", "```", tail, "```", ""]
    return "\n".join(lines) + "\n", (timed_out or proc.returncode != 0)


def not_run(script: Path) -> str:
    rel = script.relative_to(ROOT).as_posix()
    return f"## {rel}\n\n- status: not run in this session\n\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scripts", nargs="*", help="only these (e.g. bus solver); their sections are replaced, the rest kept")
    ap.add_argument("--timeout", type=float, default=1200.0, help="per script, s (default 1200)")
    ap.add_argument("--list", action="store_true", help="print the scripts make bench runs and exit")
    args = ap.parse_args()
    if args.list:
        print("\n".join(p.relative_to(ROOT).as_posix() for p in scripts()))
        return 0
    chosen = pick(args.scripts) if args.scripts else scripts()
    old = RESULTS.read_text(encoding="utf-8") if RESULTS.exists() else ""
    sections = {m["name"]: m["body"] for m in SECTION.finditer(old)} if args.scripts else {}
    notes = m["body"] if (m := NOTES.search(old)) else DEFAULT_NOTES

    date, load_before, started = now(), load(), time.monotonic()
    failed = []
    for script in chosen:
        body, bad = run_one(script, args.timeout)
        sections[script.name] = body
        if bad:
            failed.append(script.name)
        write(sections, notes, date, load_before, time.monotonic() - started, chosen, failed, partial=True)
    write(sections, notes, date, load_before, time.monotonic() - started, chosen, failed, partial=False)
    print(f"_run_all: {len(chosen)} script(s) in {time.monotonic() - started:.0f} s, "
          f"{len(failed)} failed or timed out{': ' + ', '.join(failed) if failed else ''}; wrote {RESULTS.relative_to(ROOT)}")
    return 1 if failed else 0


def write(sections: dict[str, str], notes: str, date: str, load_before: str, wall: float,
          chosen: list[Path], failed: list[str], partial: bool) -> None:
    """Write RESULTS.md (also after every script, so an interrupted run keeps what it measured)."""
    everything = scripts()
    ran = "all" if len(chosen) == len(everything) else (", ".join(p.stem for p in chosen)
                                                         + " (the other sections are kept from earlier runs, each with its own date and commit)")
    head = [
        "# Benchmark results",
        "",
        "Written by `make bench` (benchmarks/_run_all.py): every figure below is the script's own output, verbatim.",
        "Refresh one section with `.venv/bin/python benchmarks/_run_all.py NAME`.",
        "",
        f"- date: {date}",
        f"- commit: {commit()}",
        f"- machine: {os.cpu_count()} cores, {platform.platform()}, Python {platform.python_version()}",
        f"- real captures: {SHARED} " + ("present" if SHARED.is_dir() else "ABSENT (the scripts that read them skip those parts)"),
        f"- load average (1, 5, 15 min): {load_before} before, {load()} {'now (run in progress)' if partial else 'after'}",
        f"- scripts run: {ran}; wall time {wall / 60:.1f} min; "
        + (f"failed or timed out: {', '.join(failed)}" if failed else "none failed"),
        "",
        "<!-- notes -->", notes.rstrip("\n"), "<!-- /notes -->",
        "",
    ]
    body = []
    for script in everything:
        text = sections.get(script.name, not_run(script))
        body.append(f"<!-- bench:{script.name} -->\n{text}<!-- /bench:{script.name} -->\n")
    tmp = RESULTS.with_suffix(".md.tmp")
    tmp.write_text("\n".join(head) + "\n" + "\n".join(body), encoding="utf-8")
    tmp.replace(RESULTS)


if __name__ == "__main__":
    sys.exit(main())
