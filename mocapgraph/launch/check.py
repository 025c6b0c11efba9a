"""Checking a whole graph before any process starts (node types, params, topics, types).

The data-flow graph is a networkx DiGraph whose vertices are nodes and topics
(``("node", name)``, ``("topic", name)``); the same graph orders shutdown and draws
``mocapgraph graph show``.
"""
from __future__ import annotations

import functools
import ipaddress
import os
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import networkx as nx

from ..bus.node import DIAGNOSTICS_TOPIC, Node, NodeConfigError
from ..bus.input_files import InputFileError, check_input_file
from ..bus.ports import Interface
from ..messages.registry import all_types
from ..nodes.registry import NODE_TYPES, resolve
from .graph import GraphSpec, NodeSpec, did_you_mean
from ..formats.yaml_source import GraphError


@dataclass
class ResolvedNode:
    """A node with its class, checked params and concrete topics."""

    spec: NodeSpec
    class_path: str
    cls: type[Node]
    params: dict[str, Any]
    iface: Interface
    inputs: dict[str, str] = field(default_factory=dict)  # port -> topic
    outputs: dict[str, str] = field(default_factory=dict)  # port -> topic

    @property
    def name(self) -> str:
        return self.spec.name


@dataclass
class CheckedGraph:
    """A graph that passed every check, ready to launch."""

    spec: GraphSpec
    nodes: list[ResolvedNode]
    flow: nx.DiGraph

    def topic_types(self) -> dict[str, str]:
        out: dict[str, str] = {}
        for n in self.nodes:
            for port, topic in n.outputs.items():
                out[topic] = n.iface.outputs[port].type_name
        for ext in self.spec.external:
            out[ext.topic] = ext.type
        for exp in self.spec.expects:
            out.setdefault(exp.topic, exp.type)
        out[DIAGNOSTICS_TOPIC] = "Diagnostics"
        return out

    def node(self, name: str) -> ResolvedNode:
        return next(n for n in self.nodes if n.name == name)


def node_class_path(type_name: str, base: Path) -> str:
    """Where a node type may be loaded from: a registry name, ``mocapgraph.<module>:Class``, or a
    ``.py`` file the graph names (``nodes/my_node.py:MyNode``, relative to ``base``, the graph's
    folder) -> its import path (a file: absolute). KeyError (one line) for anything else: a
    ``module:Class`` of any other module would run that module's import-time code on a mere check."""
    if ":" not in type_name:
        return resolve(type_name)
    module, _, cls = type_name.rpartition(":")
    if module.endswith(".py"):
        file = (base / module).resolve()
        if not file.is_file():
            raise KeyError(f"node type {type_name!r}: no file {file}")
        return f"{file}:{cls}"
    if module == "mocapgraph" or module.startswith("mocapgraph."):
        return type_name
    raise KeyError(f"node type {type_name!r}: only registered types, mocapgraph modules and .py files the graph "
                   f"names load (write it as path/to/{module.rpartition('.')[2]}.py:{cls}, relative to the graph file)")


def load_node_class(type_name: str, spec: NodeSpec | None = None) -> tuple[str, type[Node]]:
    """Import a node class by registry name, mocapgraph module:Class or file.py:Class (node_class_path)."""
    from ..bus.runtime import load_class

    try:
        path = node_class_path(type_name, Path(spec.file).parent if spec is not None and spec.file else Path.cwd())
    except KeyError as exc:
        unknown = ":" not in type_name
        msg = (f"unknown node type {type_name!r}{did_you_mean(type_name, list(NODE_TYPES))}" if unknown
               else exc.args[0])
        if spec is None:
            raise KeyError(msg) from None
        raise spec.error("type", msg) from None
    try:
        return path, load_class(path)
    except (ImportError, AttributeError, TypeError, ValueError) as exc:
        msg = f"cannot load node type {type_name!r}: {exc}"
        if spec is None:
            raise KeyError(msg) from None
        raise spec.error("type", msg) from None


def _remapped(spec: NodeSpec, port: str, default_topic: str) -> str:
    return spec.remap.get(port, spec.remap.get(default_topic, default_topic))


def _blame_key(spec: NodeSpec, port: str, default_topic: str) -> str:
    """The key to name in an error about a port: its remap when it has one, else the node type."""
    return "remap" if port in spec.remap or default_topic in spec.remap else "type"


#: longest ipc path the kernel takes (sun_path is 108 bytes with its NUL)
IPC_PATH_MAX = 107
_RUN_DIR_ROOM = len("/mocapgraph-4194304-abcdefgh/")  # tempfile.mkdtemp(prefix=f"mocapgraph-{pid}-")


def ipc_path_problem(name: str) -> str:
    """Why the launcher could not bind the ipc socket of node ``name`` here ('' when it can)."""
    n = len(os.fsencode(tempfile.gettempdir())) + _RUN_DIR_ROOM + len(name.encode()) + len(".pub")
    if n > IPC_PATH_MAX:
        return (f"its socket path would be {n} bytes, more than the {IPC_PATH_MAX} the OS allows: "
                f"set TMPDIR to a shorter directory (now {tempfile.gettempdir()[:60]!r}) or shorten the name")
    return ""


@functools.lru_cache(maxsize=256)
def host_problem(host: str) -> str:
    """Why a publisher cannot bind ``host`` ('' when it can): not an address or resolvable name,
    or not an address of this machine."""
    if not host or len(host) > 253 or any(c in host for c in "/ \0:") and not _is_ip(host):
        return f"{host[:80]!r} is not an IP address or host name"
    try:
        infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError):
        return f"{host[:80]!r} is neither an IP address nor a name that resolves"
    for family, _, _, _, addr in infos:
        try:
            with socket.socket(family, socket.SOCK_STREAM) as s:
                s.bind((addr[0], 0))
            return ""
        except OSError:
            continue
    return f"{host[:80]!r} is not an address of this machine (nothing could bind it)"


def _loopback(host: str) -> bool:
    """True when every address ``host`` stands for is a loopback one."""
    if host == "localhost":
        return True
    try:
        addrs = {a[4][0] for a in socket.getaddrinfo(host, None)}
        return all(ipaddress.ip_address(a.split("%")[0]).is_loopback for a in addrs)
    except (OSError, ValueError):
        return False


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return False


def _check_files(ns: NodeSpec, iface: Interface, params: dict[str, Any]) -> None:
    """Every ``kind="file"`` param names a file this machine can read (GraphError otherwise)."""
    for key, p in iface.params.items():
        if p.kind != "file" or (not params.get(key) and not p.required):
            continue
        try:
            check_input_file(params[key])
        except InputFileError as exc:
            raise ns.error(f"params.{key}", str(exc)) from None


def _check_name(ns: NodeSpec, seen: dict[str, NodeSpec], machine: str | None) -> None:
    """The node's name is new in the graph, fits an ipc socket path, and (with --machine) it
    names its machine. Records it in ``seen``."""
    if ns.name in seen:
        first = seen[ns.name]
        raise ns.error("name", f"duplicate node name (first at {first.file}:{first.line})")
    seen[ns.name] = ns
    problem = ipc_path_problem(ns.name)
    if problem:
        raise ns.error("name", problem)
    if machine is not None and not ns.machine:
        raise ns.error("name", "launched with --machine, every node names its machine: (this one does not)")


def _check_host(ns: NodeSpec, spec: GraphSpec, machine: str | None) -> None:
    """The node's ``host:`` can be published on: a node of another machine only needs a name
    that resolves, one of this machine an address it can bind; either, when reachable from
    other machines, needs the graph's security: section."""
    if not ns.host:
        return
    secured = spec.security.curve or spec.security.insecure
    if machine is not None and ns.machine != machine:
        try:
            socket.getaddrinfo(ns.host, None)
        except (socket.gaierror, UnicodeError):
            raise ns.error("host", f"{ns.host[:80]!r} is neither an IP address nor a name that resolves") from None
        if not _loopback(ns.host) and not secured:
            raise ns.error("host", f"{ns.host} is reachable from other machines: give the graph a security: "
                           "section (key:, authorized:) or security: {insecure: true}")
        return
    problem = host_problem(ns.host)
    if problem:
        raise ns.error("host", problem)
    if not _loopback(ns.host) and not secured:
        raise ns.error("host", f"{ns.host} is reachable from other machines: give the graph a security: "
                       "section (key:, authorized:; see 'mocapgraph keys generate') for CurveZMQ, "
                       "or security: {insecure: true} to publish plaintext knowingly")


def _node_interface(ns: NodeSpec, cls: type[Node]) -> Interface:
    """The ports and params ``cls`` declares for the node's params; every param given is one."""
    try:
        iface = cls.interface(ns.params)
    except (NodeConfigError, ValueError, TypeError, OSError) as exc:
        # A node shaping its ports from params (a bag player reading its file) may refuse them.
        raise ns.error("params", str(exc)) from None
    for key in ns.params:
        if key not in iface.params:
            raise ns.error(f"params.{key}", f"unknown parameter of {ns.type}{did_you_mean(key, list(iface.params))}")
    return iface


def _node_params(ns: NodeSpec, cls: type[Node], iface: Interface) -> dict[str, Any]:
    """The node's params checked and filled with defaults by its class, blamed on the key the
    class's message names."""
    try:
        params = cls.check_params(ns.params, iface)
        if hasattr(cls, "graph_check"):   # what a node reports when running, the check refuses at once
            cls.graph_check(params)
    except NodeConfigError as exc:
        key = str(exc).split("'")[1] if "'" in str(exc) else ""
        raise ns.error(f"params.{key}" if key else "params", str(exc)) from None
    return params


def _check_remap(ns: NodeSpec, iface: Interface) -> None:
    """Every ``remap:`` key is one of the node's ports or default topics."""
    known = set(iface.inputs) | set(iface.outputs) | {p.topic for p in iface.inputs.values()} | {
        p.topic for p in iface.outputs.values()}
    for key in ns.remap:
        if key not in known:
            raise ns.error("remap", f"{ns.type} has no port or topic {key!r}{did_you_mean(key, sorted(known))}")


def _resolve_node(ns: NodeSpec, check_files: bool) -> ResolvedNode:
    """The node's class, checked params and concrete (remapped) topics."""
    path, cls = load_node_class(ns.type, ns)
    iface = _node_interface(ns, cls)
    params = _node_params(ns, cls, iface)
    if check_files:
        _check_files(ns, iface, params)
    _check_remap(ns, iface)
    rn = ResolvedNode(ns, path, cls, params, iface)
    rn.inputs = {p: _remapped(ns, p, d.topic) for p, d in iface.inputs.items()}
    rn.outputs = {p: _remapped(ns, p, d.topic) for p, d in iface.outputs.items()}
    return rn


#: topic -> [(who publishes it, message type name)]
_Publishers = dict[str, list[tuple[str, str]]]


def _outside_publishers(spec: GraphSpec) -> _Publishers:
    """The topics published from outside the graph's nodes: ``external:`` endpoints and what an
    including graph ``expects:`` to provide; each of a known message type."""
    types = all_types()
    publishers: _Publishers = {}
    for ext in spec.external:
        if ext.type not in types:
            raise GraphError(ext.file, ext.line, f"external[{ext.topic}].type",
                             f"unknown message type{did_you_mean(ext.type, list(types))}")
        publishers.setdefault(ext.topic, []).append((f"external:{ext.endpoint}", ext.type))
    for exp in spec.expects:
        if exp.type not in types:
            raise GraphError(exp.file, exp.line, f"expects[{exp.topic}].type",
                             f"unknown message type{did_you_mean(exp.type, list(types))}")
        publishers.setdefault(exp.topic, []).append(("the includer", exp.type))
    return publishers


def _add_outputs(resolved: list[ResolvedNode], publishers: _Publishers, flow: nx.DiGraph) -> None:
    """Node -> topic edges of ``flow``; adds each output to ``publishers``, refusing a topic
    published under two types."""
    for rn in resolved:
        flow.add_node(("node", rn.name))
        for port, topic in rn.outputs.items():
            t = rn.iface.outputs[port].type_name
            for other, other_t in publishers.get(topic, []):
                if other_t != t:
                    raise rn.spec.error(_blame_key(rn.spec, port, rn.iface.outputs[port].topic),
                                        f"publishes {topic!r} as {t} but {other} publishes it as {other_t}")
            publishers.setdefault(topic, []).append((rn.name, t))
            flow.add_edge(("node", rn.name), ("topic", topic), type=t)


def _add_inputs(resolved: list[ResolvedNode], publishers: _Publishers, flow: nx.DiGraph) -> None:
    """Topic -> node edges of ``flow``; a required input needs a publisher, and every publisher
    of an input's topic its type."""
    for rn in resolved:
        for port, topic in rn.inputs.items():
            decl = rn.iface.inputs[port]
            pubs = publishers.get(topic, [])
            if not pubs and topic != DIAGNOSTICS_TOPIC:
                if decl.required:
                    raise rn.spec.error(_blame_key(rn.spec, port, decl.topic),
                                        f"input {port!r} subscribes to topic {topic!r} that no node publishes"
                                        f"{did_you_mean(topic, list(publishers))}")
                continue
            for pub, t in pubs:
                if decl.msg_type is not None and t != decl.type_name:
                    raise rn.spec.error(_blame_key(rn.spec, port, decl.topic),
                                        f"input {port!r} wants {decl.type_name} on {topic!r}, but {pub} publishes {t}")
            flow.add_edge(("topic", topic), ("node", rn.name), type=decl.type_name)


def _check_machine_used(spec: GraphSpec, resolved: list[ResolvedNode], machine: str | None) -> None:
    """With --machine, at least one node runs on that machine (a typo would launch nothing)."""
    if machine is not None and not any(rn.spec.machine == machine for rn in resolved):
        known = sorted({rn.spec.machine for rn in resolved if rn.spec.machine})
        raise GraphError(spec.file, None, "machine", f"no node runs on machine {machine!r} "
                         f"(machines: {', '.join(known) or 'none named'})")


def check_graph(spec: GraphSpec, check_files: bool = True, machine: str | None = None) -> CheckedGraph:
    """Resolve and check ``spec``; raises GraphError naming file, line and key of the first fault.

    machine: the `--machine` this check is for: only its nodes' hosts must be addresses of this
    machine (the others' must resolve); None checks every node as local.

    check_files: also check that input-file params name readable files (off for drawing a graph).
    """
    seen: dict[str, NodeSpec] = {}
    resolved: list[ResolvedNode] = []
    for ns in spec.nodes:  # node by node, so the first fault in file order is the one named
        _check_name(ns, seen, machine)
        _check_host(ns, spec, machine)
        resolved.append(_resolve_node(ns, check_files))
    _check_processes(resolved)
    publishers = _outside_publishers(spec)
    flow = nx.DiGraph()
    _add_outputs(resolved, publishers, flow)
    _add_inputs(resolved, publishers, flow)
    _check_machine_used(spec, resolved, machine)
    return CheckedGraph(spec, resolved, flow)


def _check_processes(resolved: list[ResolvedNode]) -> None:
    """Nodes sharing a ``process:`` run on one machine, are restarted together (same respawn) and have one niceness."""
    first: dict[str, NodeSpec] = {}
    for rn in resolved:
        ns = rn.spec
        if not ns.process:
            continue
        lead = first.setdefault(ns.process, ns)
        if lead is ns:
            continue
        for key, why in (("machine", "the nodes of one process run on one machine"),
                         ("respawn", "a process is restarted as a whole"),
                         ("respawn_delay", "a process is restarted as a whole"),
                         ("respawn_max_delay", "a process is restarted as a whole"),
                         ("nice", "a process has one scheduling priority")):
            if getattr(ns, key) != getattr(lead, key):
                raise ns.error(key, f"{getattr(ns, key)!r} differs from {getattr(lead, key)!r} of nodes[{lead.name}] "
                               f"in process {ns.process!r} ({why})")


def process_groups(graph: CheckedGraph) -> dict[str, list[str]]:
    """The graph's OS processes: a key per process (``process:`` name, else the node's name) -> its
    nodes in graph order. Keys of groups are prefixed ``process:`` so no node name can clash."""
    groups: dict[str, list[str]] = {}
    for rn in graph.nodes:
        key = f"process:{rn.spec.process}" if rn.spec.process else rn.name
        groups.setdefault(key, []).append(rn.name)
    return groups


def shutdown_order(graph: CheckedGraph) -> list[str]:
    """Nodes upstream first, so that downstream nodes (recorders last) see every message."""
    nodes_only = nx.DiGraph()
    nodes_only.add_nodes_from(n.name for n in graph.nodes)
    for rn in graph.nodes:
        for topic in rn.outputs.values():
            for _, sub in graph.flow.out_edges(("topic", topic)):
                if sub[1] != rn.name:
                    nodes_only.add_edge(rn.name, sub[1])
    cond = nx.condensation(nodes_only)  # cycles (command/status loops) collapse to one step
    order: list[str] = []
    for c in nx.topological_sort(cond):
        order.extend(sorted(cond.nodes[c]["members"]))
    return order
