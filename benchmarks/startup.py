"""Start-up benchmark: what a node process imports before it can build its node, per node type.

Every launched node is ``python -m mocapgraph.bus.runtime SPEC.json``: the interpreter starts,
imports the runtime, then the node's module (`runtime.load_class`), then builds the node. This
script runs, per node type, a fresh interpreter that does just the imports (no node is built, no
socket opened) under ``python -X importtime`` and prints:

- the import wall time and CPU time (process_time) measured inside that interpreter, from before
  ``import mocapgraph.bus.runtime`` to after ``load_class``; the modules loaded (a node that loads its
  math when it is built, the frame solver and the calibration, pays that after these figures);
- which heavy packages got loaded (scipy, numba, ezc3d, mujoco, networkx, websockets, mcap);
- the top packages by their own import time (-X importtime "self", summed per top-level package);
- a baseline measured in the same run: ``import numpy, zmq`` alone (the floor every node pays);
- per shipped graph (graph_configs/*.yaml), the launcher's check before it starts anything
  (`load_checked`, as ``mocapgraph launch`` runs it; input files not checked): it imports the
  class of every node type of the graph, so it pays the union of their imports, serially.

One interpreter per type, run once (no repetitions: this is a shared 2-core machine); the load
average is printed beside each figure, as one run's wall time moves with it.

With ``--against DIR`` (a copy of an older tree, e.g. ``git archive COMMIT mocapgraph | tar -x -C DIR``)
each figure is measured for that tree too, in the same run, and printed beside this one with the
CPU ratio (this tree / DIR).

Usage: python benchmarks/startup.py [--types synthetic_actor,bag_recorder] [--top 5] [--against DIR]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

from mocapgraph.nodes.registry import NODE_TYPES

from _context import print_context

ROOT = Path(__file__).resolve().parents[1]
GRAPHS = ROOT / "graph_configs"
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


def measure(imports: str, tree: str = "") -> dict:
    """One fresh interpreter running ``imports`` under -X importtime (``tree`` first on its path):
    times, modules, self-time per package."""
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    if tree:
        env["PYTHONPATH"] = os.pathsep.join([tree, *filter(None, [env.get("PYTHONPATH", "")])])
    run = subprocess.run([sys.executable, "-X", "importtime", "-c", _CHILD.format(imports=imports)],
                         capture_output=True, text=True, timeout=120, env=env, cwd=tree or ROOT)  # (-c puts the cwd first)
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


def _row(r: dict) -> str:
    heavy = ",".join(h for h in HEAVY if h in set(r["modules"])) or "-"
    return f"{r['wall']:7.3f} {r['cpu']:6.3f} {len(r['modules']):5d}  {heavy:22s}"


def _against(r: dict, old: dict | None) -> str:
    return "" if old is None else f" | before {_row(old)} cpu x{r['cpu'] / old['cpu']:.2f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--types", default="", help="comma-separated node types (default: the shipped graphs' "
                                                    "types, then the rest of the registry)")
    parser.add_argument("--top", type=int, default=4, help="packages listed per type, by own import time")
    parser.add_argument("--graphs", default="", help="comma-separated graph files for the launcher's check "
                                                     "(default: graph_configs/*.yaml; 'none' to skip)")
    parser.add_argument("--against", default="", help="an older tree (folder holding mocapgraph/) measured "
                                                      "beside this one")
    args = parser.parse_args()
    types = args.types.split(",") if args.types else [*SHIPPED, *(t for t in NODE_TYPES if t not in SHIPPED)]
    old_tree = str(Path(args.against).resolve()) if args.against else ""

    def both(imports: str) -> tuple[dict, dict | None]:
        return measure(imports), (measure(imports, old_tree) if old_tree else None)

    print_context(None, f"imports of {len(types)} node types (fresh interpreters, -X importtime)"
                  + (f", beside the tree {old_tree}" if old_tree else ""), "each type once, no repetition",
                  section="node types")
    base = measure("import numpy, zmq")
    print(f"baseline import numpy, zmq: wall {base['wall']:.3f} s, cpu {base['cpu']:.3f} s, "
          f"{len(base['modules'])} modules (load average {load()})")
    head = f"{'wall s':>7s} {'cpu s':>6s} {'mods':>5s}  {'heavy loaded':22s}"
    print(f"{'node type':20s} {head}" + (f" | before {head} ratio" if old_tree else "")
          + " | top own import time (s)")
    totals = {"wall": 0.0, "cpu": 0.0, "old_wall": 0.0, "old_cpu": 0.0}
    for t in types:
        r, old = both(f"from mocapgraph.bus.runtime import load_class\nload_class({NODE_TYPES[t]!r})")
        totals["wall"] += r["wall"]
        totals["cpu"] += r["cpu"]
        if old is not None:
            totals["old_wall"] += old["wall"]
            totals["old_cpu"] += old["cpu"]
        top = sorted(r["per_package"].items(), key=lambda kv: -kv[1])[:args.top]
        print(f"{t:20s} {_row(r)}{_against(r, old)} | " + ", ".join(f"{k} {v:.3f}" for k, v in top)
              + f"  (load {load()})")
    print(f"sum over {len(types)} types: wall {totals['wall']:.2f} s, cpu {totals['cpu']:.2f} s"
          + (f" (before: wall {totals['old_wall']:.2f} s, cpu {totals['old_cpu']:.2f} s, cpu "
             f"x{totals['cpu'] / totals['old_cpu']:.2f})" if old_tree else "") + f" (load average {load()})")
    if args.graphs != "none":
        graphs = args.graphs.split(",") if args.graphs else sorted(str(p) for p in GRAPHS.glob("*.yaml"))
        print_context(None, f"the launcher's check of {len(graphs)} graphs ({', '.join(Path(g).name for g in graphs)}), "
                      "input files not checked", "each graph once", section="graphs")
        print(f"{'launcher check of':24s} {head}" + (f" | before {head} ratio" if old_tree else ""))
        cpu = old_cpu = 0.0
        for g in graphs:
            r, old = both(f"from mocapgraph.cli.graph_cmds import load_checked\nload_checked({g!r}, [], check_files=False)")
            cpu += r["cpu"]
            old_cpu += old["cpu"] if old else 0.0
            print(f"{Path(g).name:24s} {_row(r)}{_against(r, old)}  (load {load()})")
        print(f"sum over {len(graphs)} graphs: cpu {cpu:.2f} s" + (f" (before {old_cpu:.2f} s, x{cpu / old_cpu:.2f})"
                                                                   if old_tree else "") + f" (load average {load()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
