"""Start-up benchmark: what a node process imports before it can build its node, per node type.

Every launched node is ``python -m mocapgraph.bus.runtime SPEC.json``: the interpreter starts,
imports the runtime, then the node's module (`runtime.load_class`), then builds the node. This
script runs, per node type, a fresh interpreter that does just the imports (no node is built, no
socket opened) under ``python -X importtime`` and prints:

- the import wall time and CPU time (process_time) measured inside that interpreter, from before
  ``import mocapgraph.bus.runtime`` to after ``load_class``; the modules loaded;
- which heavy packages got loaded (scipy, numba, ezc3d, mujoco, networkx, websockets, mcap);
- the top packages by their own import time (-X importtime "self", summed per top-level package);
- a baseline measured in the same run: ``import numpy, zmq`` alone (the floor every node pays).

One interpreter per type, run once (no repetitions: this is a shared 2-core machine); the load
average is printed beside each figure, as one run's wall time moves with it.

Usage: python benchmarks/startup.py [--types synthetic_actor,bag_recorder] [--top 5]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections import defaultdict

from mocapgraph.nodes.registry import NODE_TYPES

HEAVY = ("scipy", "numba", "ezc3d", "mujoco", "networkx", "websockets", "mcap", "matplotlib")

# The node types the shipped graphs (graph_configs/*.yaml) use, first; the rest of the registry after.
SHIPPED = ("synthetic_actor", "c3d_reader", "trc_reader", "calibration", "frame_solver", "retargeter",
           "physics_tracker", "bag_recorder", "visualizer", "topic_logger", "bvh_player", "kinect_reader")

_CHILD = """
import sys, time, json
w0, c0 = time.perf_counter(), time.process_time()
{imports}
w1, c1 = time.perf_counter(), time.process_time()
print(json.dumps({{"wall": w1 - w0, "cpu": c1 - c0, "modules": sorted(sys.modules)}}))
"""


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def measure(imports: str) -> dict:
    """One fresh interpreter running ``imports`` under -X importtime: times, modules, self-time per package."""
    run = subprocess.run([sys.executable, "-X", "importtime", "-c", _CHILD.format(imports=imports)],
                         capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    if run.returncode != 0:
        raise RuntimeError(run.stderr.strip().splitlines()[-1])
    result = json.loads(run.stdout.strip().splitlines()[-1])
    per_package: dict[str, float] = defaultdict(float)
    for line in run.stderr.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        self_us, _cumulative, name = line[len("import time:"):].split("|")
        name = name.strip()
        top = name.split(".")[0]
        # our own modules by subpackage (mocapgraph.formats), the rest by top-level package
        key = ".".join(name.split(".")[:2]) if top == "mocapgraph" else top
        per_package[key] += int(self_us) / 1e6
    result["per_package"] = dict(per_package)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--types", default="", help="comma-separated node types (default: the shipped graphs' "
                                                    "types, then the rest of the registry)")
    parser.add_argument("--top", type=int, default=5, help="packages listed per type, by own import time")
    args = parser.parse_args()
    types = args.types.split(",") if args.types else [*SHIPPED, *(t for t in NODE_TYPES if t not in SHIPPED)]

    base = measure("import numpy, zmq")
    print(f"baseline import numpy, zmq: wall {base['wall']:.3f} s, cpu {base['cpu']:.3f} s, "
          f"{len(base['modules'])} modules (load average {load()})")
    print(f"{'node type':20s} {'wall s':>7s} {'cpu s':>6s} {'mods':>5s}  heavy loaded | top own import time (s)")
    total_wall = total_cpu = 0.0
    for t in types:
        module, _, cls = NODE_TYPES[t].partition(":")
        r = measure(f"from mocapgraph.bus.runtime import load_class\nload_class({NODE_TYPES[t]!r})")
        total_wall += r["wall"]
        total_cpu += r["cpu"]
        loaded = set(r["modules"])
        heavy = ",".join(h for h in HEAVY if h in loaded) or "-"
        top = sorted(r["per_package"].items(), key=lambda kv: -kv[1])[:args.top]
        print(f"{t:20s} {r['wall']:7.3f} {r['cpu']:6.3f} {len(loaded):5d}  {heavy} | "
              + ", ".join(f"{k} {v:.3f}" for k, v in top) + f"  (load {load()})")
    print(f"sum over {len(types)} types: wall {total_wall:.2f} s, cpu {total_cpu:.2f} s; "
          f"above the numpy+zmq floor: wall {total_wall - len(types) * base['wall']:.2f} s (load average {load()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
