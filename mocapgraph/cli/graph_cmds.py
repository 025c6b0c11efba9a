"""``mocapgraph launch``, ``graph check|show``, ``node list|info``."""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from typing import TYPE_CHECKING, Any

from ..nodes.registry import NODE_TYPES
from . import UserError

if TYPE_CHECKING:
    from ..launch.check import CheckedGraph

# The graph checker (networkx, the bus, every format reader) is imported by the commands that run:
# `mocapgraph --help` builds this family's parser and needs none of it.


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """``name:=value`` pairs, values typed as YAML."""
    from ..formats.yaml_source import parse_value

    out = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep or not name:
            raise UserError(f"argument {item!r} is not name:=value")
        out[name] = parse_value(value)
    return out


def load_checked(path: str, overrides: list[str], check_files: bool = True,
                 machine: str | None = None) -> CheckedGraph:
    from ..formats.yaml_source import GraphError
    from ..launch.check import check_graph
    from ..launch.graph import load_graph

    try:
        return check_graph(load_graph(path, parse_overrides(overrides)), check_files=check_files, machine=machine)
    except GraphError as exc:
        raise UserError(str(exc)) from None


def cmd_launch(args: argparse.Namespace) -> int:
    from ..launch.supervisor import run_graph

    graph = load_checked(args.file, args.args, machine=args.machine)
    if graph.spec.expects:
        raise UserError(f"{args.file}: a piece meant for inclusion: it expects "
                        f"{', '.join(e.topic for e in graph.spec.expects)} from the graph that includes it")
    return run_graph(graph, master=args.master, machine=args.machine)


def cmd_check(args: argparse.Namespace) -> int:
    graph = load_checked(args.file, args.args)
    print(f"{args.file}: OK, {len(graph.nodes)} nodes, {len(graph.topic_types())} topics")
    return 0


def to_text(graph: CheckedGraph) -> str:
    types = graph.topic_types()
    lines = [f"graph {graph.spec.file}"]
    for n in graph.nodes:
        lines.append(f"  {n.name} ({n.spec.type})" + (f" in process {n.spec.process}" if n.spec.process else "")
                     + (f", nice {n.spec.nice}" if n.spec.nice else ""))
        for port, topic in n.inputs.items():
            lines.append(f"    <- {topic} [{n.iface.inputs[port].type_name}]")
        for port, topic in n.outputs.items():
            lines.append(f"    -> {topic} [{types[topic]}]")
    lines.append("edges (publisher -> topic [type] -> subscribers)")
    pubs: dict[str, list[str]] = {}
    subs: dict[str, list[str]] = {}
    for n in graph.nodes:
        for topic in n.outputs.values():
            pubs.setdefault(topic, []).append(n.name)
        for topic in n.inputs.values():
            subs.setdefault(topic, []).append(n.name)
    for ext in graph.spec.external:
        pubs.setdefault(ext.topic, []).append(f"external {ext.endpoint}")
    for exp in graph.spec.expects:
        pubs.setdefault(exp.topic, []).append("(the includer)")
    pubs.setdefault("diagnostics", []).append("(every node)")
    for topic in sorted(set(pubs) | set(subs)):
        lines.append(f"  {', '.join(pubs.get(topic, ['(nobody)']))} -> {topic} [{types.get(topic, '*')}] -> "
                     f"{', '.join(sorted(set(subs.get(topic, [])))) or '(nobody)'}")
    return "\n".join(lines)


def to_dot(graph: CheckedGraph) -> str:
    types = graph.topic_types()
    out = ["digraph mocapgraph {", "  rankdir=LR;", '  node [fontname="Helvetica"];']
    for n in graph.nodes:
        out.append(f'  "n:{n.name}" [shape=box, style=rounded, label="{n.name}\\n({n.spec.type})"];')
    for kind, name in graph.flow.nodes:
        if kind == "topic":
            out.append(f'  "t:{name}" [shape=ellipse, label="{name}\\n{types.get(name, "*")}"];')
    for (ka, a), (kb, b) in graph.flow.edges:
        out.append(f'  "{ka[0]}:{a}" -> "{kb[0]}:{b}";')
    out.append("}")
    return "\n".join(out)


def cmd_show(args: argparse.Namespace) -> int:
    graph = load_checked(args.file, args.args, check_files=False)  # drawing needs no capture files
    if args.format == "text":
        print(to_text(graph))
        return 0
    dot = to_dot(graph)
    if args.format == "dot":
        if args.output:
            open(args.output, "w").write(dot + "\n")
        else:
            print(dot)
        return 0
    if not shutil.which("dot"):
        raise UserError("rendering an image needs Graphviz's 'dot' (apt-get install graphviz); "
                        "use --format dot to get the DOT text")
    output = args.output or "graph." + args.format
    subprocess.run(["dot", f"-T{args.format}", "-o", output], input=dot.encode(), check=True)
    print(f"wrote {output}")
    return 0


def cmd_node_list(args: argparse.Namespace) -> int:
    from ..launch.check import load_node_class

    width = max(len(n) for n in NODE_TYPES)
    for name in sorted(NODE_TYPES):
        try:
            _, cls = load_node_class(name)
            summary = cls.summary or (cls.__doc__ or "").strip().splitlines()[0]
        except KeyError as exc:
            summary = f"(cannot load: {exc})"
        print(f"{name:<{width}}  {summary}")
    return 0


def cmd_node_info(args: argparse.Namespace) -> int:
    from ..launch.check import load_node_class

    try:
        path, cls = load_node_class(args.type)
    except KeyError as exc:
        raise UserError(exc.args[0]) from None
    iface = cls.interface({})
    print(f"{args.type}  ({path})")
    print("  " + (cls.__doc__ or "").strip().replace("\n", "\n  "))
    print("inputs:")
    for name, p in iface.inputs.items():
        flags = ", ".join(f for f, on in (("latched", p.latched), ("latest-only", p.latest_only),
                                          ("optional", not p.required)) if on)
        print(f"  {name}: topic '{p.topic}' [{p.type_name}]{' (' + flags + ')' if flags else ''}  {p.doc}")
    print("outputs:")
    for name, p in iface.outputs.items():
        print(f"  {name}: topic '{p.topic}' [{p.type_name}]{' (latched)' if p.is_latched else ''}  {p.doc}")
    print("  (every node also publishes 'diagnostics' [Diagnostics] once a second)")
    print("params:")
    for name, p in iface.params.items():
        extra = []
        if p.choices:
            extra.append(f"one of {list(p.choices)}")
        if p.minimum is not None:
            extra.append(f">= {p.minimum}")
        if p.maximum is not None:
            extra.append(f"<= {p.maximum}")
        print(f"  {name}: {p.kind} = {p.default!r}  {p.doc}{' (' + ', '.join(extra) + ')' if extra else ''}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("launch", help="run a graph file: every node as its own process")
    p.add_argument("file")
    p.add_argument("args", nargs="*", help="arg overrides as name:=value")
    p.add_argument("--master", help="manifest endpoint (default $MOCAPGRAPH_MASTER or a per-user ipc socket)")
    p.add_argument("--machine", help="run only the nodes with this machine: and connect to the others' "
                   "(one graph file for a capture PC and a render PC)")
    p.set_defaults(func=cmd_launch)

    g = sub.add_parser("graph", help="check or draw a graph file without running it")
    gs = g.add_subparsers(dest="graph_command", required=True)
    c = gs.add_parser("check", help="validate a graph file (types, params, topics)")
    c.add_argument("file")
    c.add_argument("args", nargs="*")
    c.set_defaults(func=cmd_check)
    s = gs.add_parser("show", help="print the graph as text, Graphviz DOT or an image")
    s.add_argument("file")
    s.add_argument("args", nargs="*")
    s.add_argument("--format", choices=["text", "dot", "png", "svg", "pdf"], default="text")
    s.add_argument("-o", "--output")
    s.set_defaults(func=cmd_show)

    n = sub.add_parser("node", help="node types: list them or show one's ports and params")
    ns = n.add_subparsers(dest="node_command", required=True)
    ns.add_parser("list", help="every registered node type").set_defaults(func=cmd_node_list)
    i = ns.add_parser("info", help="inputs, outputs and params of a node type")
    i.add_argument("type")
    i.set_defaults(func=cmd_node_info)
