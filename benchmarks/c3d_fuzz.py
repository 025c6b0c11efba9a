"""Damaged C3D files through ``mocapgraph bag convert``: peak memory, time and outcome of N seeded
one-byte structural changes (mocapgraph.testing.c3d_fuzz) to each shared C3D file.

Run: .venv/bin/python benchmarks/c3d_fuzz.py [--seeds 50] [--file NAME]
Prints per file: size, converted / refused in one line / other (traceback, crash, timeout), the
largest peak RSS against the bound 10 x size + 150 MB, the slowest run, and the load average.
Exit 1 when any run has a traceback, a crash, or breaks the bound. Files absent from
../shared/data are skipped.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from mocapgraph.testing.c3d_fuzz import convert, mutate

from _context import print_context

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "c3d"
MARGIN_MB = 150.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--file", default="", help="only files whose path contains this")
    args = ap.parse_args()
    files = sorted(p for p in DATA.glob("**/*.c3d") if args.file in str(p))
    if not files:
        print(f"no C3D files under {DATA}")
        return 0
    print_context(f"0..{args.seeds - 1} (random.Random(seed) in mocapgraph.testing.c3d_fuzz.mutate, one mutation each)",
                  f"{len(files)} real C3D files under {DATA}", f"every file, {args.seeds} mutated copies each"
                  + (f" (files matching {args.file!r})" if args.file else ""))
    print(f"seeds 0..{args.seeds - 1}, one structural byte each; bound = 10 x size + {MARGIN_MB:.0f} MB; "
          f"load {os.getloadavg()[0]:.1f}")
    bad_total = 0
    with tempfile.TemporaryDirectory() as tmp:
        for f in files:
            raw = f.read_bytes()
            bound = 10 * len(raw) / 2**20 + MARGIN_MB
            ok = refused = 0
            bad: list[str] = []
            peak = slow = 0.0
            for seed in range(args.seeds):
                data, what = mutate(raw, seed)
                src = Path(tmp) / f.name
                src.write_bytes(data)
                run = convert(src, Path(tmp) / "out.mcap", timeout_s=300)
                (Path(tmp) / "out.mcap").unlink(missing_ok=True)
                peak, slow = max(peak, run.peak_rss_mb), max(slow, run.seconds)
                one_line = len(run.stderr.strip().splitlines()) == 1
                if run.code == 0 and not run.traceback:
                    ok += 1
                elif run.code == 2 and one_line and not run.traceback:
                    refused += 1
                else:
                    bad.append(f"seed {seed} ({what}): exit {run.code}, {run.stderr.strip()[-200:]!r}")
                if run.peak_rss_mb >= bound:
                    bad.append(f"seed {seed} ({what}): peak {run.peak_rss_mb:.0f} MB")
            print(f"{f.relative_to(DATA)!s:<32} {len(raw) / 2**20:5.2f} MB  converted {ok:3d}  refused {refused:3d}  "
                  f"other {len(bad):2d}  peak {peak:6.0f} MB (bound {bound:4.0f})  slowest {slow:5.1f} s  "
                  f"load {os.getloadavg()[0]:.1f}", flush=True)
            for b in bad:
                print("    " + b)
            bad_total += len(bad)
    return 1 if bad_total else 0


if __name__ == "__main__":
    sys.exit(main())
