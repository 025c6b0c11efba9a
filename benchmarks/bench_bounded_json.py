"""What bounding JSON before parsing costs (mocapgraph.messages.bounded_json): typical command args,
a NodeStatus text block, and hostile text (50 000 '[', 1 MiB of strings holding brackets).

Prints microseconds per call of json.loads and loads_bounded for each input, and the load
(the machine's 1-minute load average) it was measured under. No assertion: figures only.
"""
from __future__ import annotations

import json
import os
import timeit

from mocapgraph.messages.bounded_json import loads_bounded

from _context import print_context

INPUTS = {
    "command args (31 B)": json.dumps({"seconds": 16.0, "rate_hz": 60.0}),
    "status block (2 kB)": json.dumps({"node": "cal", "state": "calibrated", "detail": "x" * 80,
                                       "data_json": json.dumps({"joints": [{"joint": f"j{i}", "rom_deg": 40.0}
                                                                           for i in range(16)]})}),
    "nested 40 deep (81 B)": "[" * 40 + "]" * 40,
    "hostile 50 000 '['": "[" * 50_000,
    "1 MiB of strings with '['": json.dumps(["a[b{c" * 20] * 8000),
}


def _us(fn, n: int) -> float:
    return min(timeit.repeat(fn, number=n, repeat=5)) / n * 1e6


def main() -> None:
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print_context(None, f"{len(INPUTS)} fixed JSON texts written in this script ({', '.join(INPUTS)})",
                  "every input, best of 5 repeats")
    for name, text in INPUTS.items():
        n = 20 if len(text) > 100_000 else 2000
        try:
            base = f"{_us(lambda: json.loads(text), n):10.1f}"
        except RecursionError:
            base = "RecursionError"
        def bounded():
            try:
                loads_bounded(text, max_bytes=1 << 21, max_depth=32)
            except ValueError:
                pass
        print(f"{name:28s} json.loads {base:>14} us   loads_bounded {_us(bounded, n):10.1f} us")


if __name__ == "__main__":
    main()
