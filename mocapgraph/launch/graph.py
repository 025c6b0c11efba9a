"""Launch graphs: YAML files of nodes, args and includes, resolved into one checked graph.

A graph file::

    args:                       # overridable on the command line as name:=value
      rate: {default: 240, doc: capture rate, Hz}
    include:                    # another graph, its args overridden; paths relative to this file
      - file: pipeline.yaml
        args: {rate: "${rate}"}
    external:                   # topics published by processes outside this graph
      - {topic: markers, type: MarkerFrame, endpoint: "tcp://10.0.0.5:7000"}
    expects:                    # a piece meant for inclusion: topics its includer publishes
      - {topic: markers, type: MarkerFrame, doc: "labelled markers of the reader"}
    nodes:
      - name: actor
        type: synthetic_actor   # registry name (mocapgraph node list), mocapgraph.module:Class, or path/to/file.py:Class (from this file)
        params: {rate_hz: "${rate}"}
        remap: {markers: raw_markers}   # port name or topic -> topic
        respawn: true           # restart with back-off when it dies
        required: false         # when it dies and does not respawn, stop the graph (exit 1)
        host: 127.0.0.1         # address its publisher binds (default loopback, ipc)
        process: pipeline       # nodes naming one process run in one OS process (below)
        nice: 10                # its process's niceness (0..19): a best-effort node yields the cores
        if: "${viewer}"         # a bool (after substitution): false leaves the node out

``process:`` composes nodes (ROS 2's component containers): they share one OS process and one
event loop, and what one publishes to another skips ZeroMQ (`mocapgraph.bus.process`): a hop
then costs a function call, not two processes' wake-ups. Each keeps its name, endpoint and
diagnostics. The process is restarted as a whole, so its nodes agree on ``respawn:`` (and on
``nice:``: one process, one priority); it is
required when any of them is; a crash takes all of them, so keep recorders on their own.

``if:`` also works on an include. ``expects:`` counts only in the file being checked (so
``graph check optical_pipeline.yaml`` passes); an includer must publish what its pieces expect.

``${name}`` is replaced by the arg's value; a string that is only ``${name}`` takes the arg's
type (so numbers stay numbers).
"""
from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..formats.yaml_source import GraphError, LinedDict, LinedList, load_yaml_file

NODE_KEYS = ("name", "type", "params", "remap", "respawn", "respawn_delay", "respawn_max_delay", "required", "host", "port", "machine",
             "process", "nice", "doc", "if")
SECONDS_KEYS = ("respawn_delay", "respawn_max_delay")
TOP_KEYS = ("args", "include", "nodes", "external", "expects", "description", "security")
SECURITY_KEYS = ("key", "authorized", "insecure")
EXPECTS_KEYS = ("topic", "type", "doc")
INCLUDE_KEYS = ("file", "args", "if")
EXTERNAL_KEYS = ("topic", "type", "endpoint")
_SUBST = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}")
#: node names become file names (wiring, sockets) and ZeroMQ identities: no '/', NUL, '..', spaces
NODE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]{0,63}")


@dataclass
class NodeSpec:
    """One node as written in a graph file, with where it was written."""

    name: str
    type: str
    params: dict[str, Any]
    remap: dict[str, str]
    respawn: bool = False
    respawn_delay: float = 0.5
    respawn_max_delay: float = 10.0  # the cap of the doubling back-off, s
    required: bool = False
    host: str = ""
    port: int = 0  # fixed tcp port (needed by nodes that others on other machines connect to)
    machine: str = ""  # which `launch --machine NAME` runs it ('' : every launch without --machine)
    process: str = ""  # the OS process it shares with the other nodes naming it ('' : its own)
    nice: int = 0      # its process's niceness, 0..19: higher yields the cores to the others (a viewer)
    file: str = ""
    line: int = 0
    key_lines: dict[str, int] = field(default_factory=dict)
    param_lines: dict[str, int] = field(default_factory=dict)

    def where(self, key: str = "") -> tuple[str, int]:
        if key.startswith("params."):
            return self.file, self.param_lines.get(key[7:], self.key_lines.get("params", self.line))
        return self.file, self.key_lines.get(key, self.line)

    def error(self, key: str, message: str) -> GraphError:
        file, line = self.where(key)
        return GraphError(file, line, f"nodes[{self.name}].{key}" if key else f"nodes[{self.name}]", message)


@dataclass
class ExternalTopic:
    """A topic published outside the graph, at a known endpoint."""

    topic: str
    type: str
    endpoint: str
    file: str = ""
    line: int = 0


@dataclass
class ExpectedTopic:
    """A topic a pipeline piece expects its includer to publish (honoured when the piece is the top file)."""

    topic: str
    type: str
    file: str = ""
    line: int = 0


@dataclass
class SecuritySpec:
    """The top file's ``security:``: CurveZMQ key pair and authorised public keys, or plaintext by choice."""

    key: str = ""  # the graph's .key_secret file (mocapgraph keys generate)
    authorized: str = ""  # folder of public keys (*.key) allowed to subscribe
    insecure: bool = False  # plaintext tcp beyond loopback, knowingly
    file: str = ""
    line: int = 0

    @property
    def curve(self) -> bool:
        return bool(self.key)


@dataclass
class GraphSpec:
    """A whole resolved graph: nodes from the file and everything it includes."""

    file: str
    nodes: list[NodeSpec] = field(default_factory=list)
    external: list[ExternalTopic] = field(default_factory=list)
    expects: list[ExpectedTopic] = field(default_factory=list)
    args: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    security: SecuritySpec = field(default_factory=SecuritySpec)


def did_you_mean(word: str, choices: list[str] | tuple[str, ...]) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _check_keys(d: LinedDict, allowed: tuple[str, ...], prefix: str) -> None:
    for key in d:
        if key not in allowed:
            raise GraphError(d.file, d.line_of(key), f"{prefix}{key}", f"unknown key{did_you_mean(str(key), allowed)}")


def _substitute(value: Any, args: dict[str, Any], file: str, line: int, key: str) -> Any:
    if isinstance(value, str):
        whole = _SUBST.fullmatch(value)
        if whole:
            name = whole.group(1)
            if name not in args:
                raise GraphError(file, line, key, f"unknown arg ${{{name}}}{did_you_mean(name, list(args))}")
            return args[name]

        def repl(m: re.Match) -> str:
            if m.group(1) not in args:
                raise GraphError(file, line, key, f"unknown arg ${{{m.group(1)}}}{did_you_mean(m.group(1), list(args))}")
            return str(args[m.group(1)])

        return _SUBST.sub(repl, value)
    if isinstance(value, dict):
        lines = getattr(value, "key_lines", {})
        return {k: _substitute(v, args, file, lines.get(k, line), f"{key}.{k}") for k, v in value.items()}
    if isinstance(value, list):
        return [_substitute(v, args, file, line, key) for v in value]
    return value


def _condition(d: LinedDict, args: dict[str, Any], file: str, key: str) -> bool:
    """The value of an optional ``if:`` key, which must be a bool after substitution."""
    if "if" not in d:
        return True
    value = _substitute(d["if"], args, file, d.line_of("if"), key)
    if isinstance(value, str) and value.lower() in ("true", "false"):
        value = value.lower() == "true"
    if not isinstance(value, bool):
        raise GraphError(file, d.line_of("if"), key, f"wants true or false, got {value!r}")
    return value


def _security(doc: LinedDict, path: Path, args: dict[str, Any]) -> SecuritySpec:
    sec = doc["security"]
    line = doc.line_of("security")
    if not isinstance(sec, dict):
        raise GraphError(path, line, "security", "must be a mapping {key:, authorized:} or {insecure: true}")
    _check_keys(sec, SECURITY_KEYS, "security.")
    sec = _substitute(sec, args, str(path), line, "security")
    out = SecuritySpec(file=str(path), line=line)
    insecure = sec.get("insecure", False)
    if not isinstance(insecure, bool):
        raise GraphError(path, line, "security.insecure", f"wants true or false, got {insecure!r}")
    out.insecure = insecure
    if "key" in sec or "authorized" in sec:
        for key in ("key", "authorized"):
            if not isinstance(sec.get(key), str) or not sec.get(key):
                raise GraphError(path, line, f"security.{key}", "needs a path (both key: and authorized:)")
        out.key = str((path.parent / sec["key"]).resolve())
        out.authorized = str((path.parent / sec["authorized"]).resolve())
        from ..bus.curve import CurveKeys, KeyError_

        try:
            CurveKeys.load(out.key, out.authorized)
        except KeyError_ as exc:
            raise GraphError(path, line, "security", str(exc)) from None
    return out


def load_graph(path: str | Path, overrides: dict[str, Any] | None = None) -> GraphSpec:
    """Read a graph file with its includes and args; GraphError names file, line and key."""
    path = Path(path).resolve()
    spec = GraphSpec(file=str(path))
    _load_into(spec, path, overrides or {}, stack=[], top=True)
    if not spec.nodes:
        raise GraphError(path, None, "nodes", "no node to run (every node is missing or switched off by if:)")
    return spec


def _resolve_args(doc: LinedDict, file: Path, overrides: dict[str, Any], top: bool) -> dict[str, Any]:
    declared = doc.get("args") or LinedDict()
    if not isinstance(declared, dict):
        raise GraphError(file, doc.line_of("args"), "args", "must be a mapping of name: {default: ...}")
    args: dict[str, Any] = {}
    for name, decl in declared.items():
        if isinstance(decl, dict):
            unknown = [k for k in decl if k not in ("default", "doc")]
            if unknown:
                raise GraphError(file, decl.line_of(unknown[0]), f"args.{name}.{unknown[0]}",
                                 "unknown key (an arg has 'default' and 'doc')")
            args[name] = decl.get("default")
        else:
            args[name] = decl
    for name, value in overrides.items():
        if name not in args:
            where = "command line" if top else "include"
            raise GraphError(file, doc.line_of("args"), f"args.{name}",
                             f"no such arg (set on the {where}){did_you_mean(name, list(args))}")
        args[name] = value
    for name, value in args.items():
        if value is None:
            raise GraphError(file, declared.line_of(name), f"args.{name}", "has no default and was not given")
    return args


def _load_into(spec: GraphSpec, path: Path, overrides: dict[str, Any], stack: list[Path], top: bool) -> None:
    if path in stack:
        chain = " -> ".join(p.name for p in stack + [path])
        raise GraphError(stack[-1], None, "include", f"include cycle: {chain}")
    doc = load_yaml_file(path)
    if doc is None:
        raise GraphError(path, None, "", "empty file: a graph file has nodes: (or include:)")
    if not isinstance(doc, dict):
        raise GraphError(path, getattr(doc, "line", 1), "", "a graph file is a mapping with nodes:, args:, include:")
    _check_keys(doc, TOP_KEYS, "")
    args = _resolve_args(doc, path, overrides, top)
    if top:
        spec.args = dict(args)
        spec.description = str(doc.get("description", ""))
        if "security" in doc:
            spec.security = _security(doc, path, args)
    includes = doc.get("include") or []
    if not isinstance(includes, list):
        raise GraphError(path, doc.line_of("include"), "include", "must be a list of {file:, args:}")
    for i, inc in enumerate(includes):
        line = includes.item_lines[i] if isinstance(includes, LinedList) else doc.line_of("include")
        if isinstance(inc, str):
            inc_file, inc_args = inc, {}
        elif isinstance(inc, dict):
            _check_keys(inc, INCLUDE_KEYS, f"include[{i}].")
            if "file" not in inc:
                raise GraphError(path, line, f"include[{i}]", "needs a 'file'")
            inc_file = inc["file"]
            inc_args = inc.get("args") or {}
            if not _condition(inc, args, str(path), f"include[{i}].if"):
                continue
        else:
            raise GraphError(path, line, f"include[{i}]", "must be a file name or {file:, args:}")
        inc_file = _substitute(inc_file, args, str(path), line, f"include[{i}].file")
        inc_args = _substitute(inc_args, args, str(path), line, f"include[{i}].args")
        target = (path.parent / str(inc_file)).resolve()
        if not target.exists():
            raise GraphError(path, line, f"include[{i}].file", f"{inc_file} does not exist")
        _load_into(spec, target, dict(inc_args), stack + [path], top=False)
    for i, exp in enumerate(doc.get("expects") or []):
        line = doc["expects"].item_lines[i]
        if not isinstance(exp, dict) or any(k not in exp for k in ("topic", "type")):
            raise GraphError(path, line, f"expects[{i}]", "needs topic and type")
        _check_keys(exp, EXPECTS_KEYS, f"expects[{i}].")
        if top:  # an includer publishes what its pieces expect; the check holds it to that
            spec.expects.append(ExpectedTopic(str(exp["topic"]), str(exp["type"]), str(path), line))
    for i, ext in enumerate(doc.get("external") or []):
        line = doc["external"].item_lines[i]
        if not isinstance(ext, dict) or any(k not in ext for k in EXTERNAL_KEYS):
            raise GraphError(path, line, f"external[{i}]", "needs topic, type and endpoint")
        _check_keys(ext, EXTERNAL_KEYS, f"external[{i}].")
        ext = _substitute(ext, args, str(path), line, f"external[{i}]")
        spec.external.append(ExternalTopic(str(ext["topic"]), str(ext["type"]), str(ext["endpoint"]), str(path), line))
    nodes = doc.get("nodes") or []
    if not isinstance(nodes, list):
        raise GraphError(path, doc.line_of("nodes"), "nodes", "must be a list of nodes")
    for i, raw in enumerate(nodes):
        node = _node_spec(path, i, raw, nodes.item_lines[i], args)
        if node is not None:
            spec.nodes.append(node)


def _node_spec(path: Path, i: int, raw: Any, line: int, args: dict[str, Any]) -> NodeSpec | None:
    """``nodes[i]`` of ``path`` (at ``line``) with the graph's args substituted; None when its ``if:`` is false."""
    if not isinstance(raw, dict):
        raise GraphError(path, line, f"nodes[{i}]", "a node is a mapping with name: and type:")
    _check_keys(raw, NODE_KEYS, f"nodes[{raw.get('name', i)}].")
    for key in ("name", "type"):
        if key not in raw:
            raise GraphError(path, line, f"nodes[{raw.get('name', i)}]", f"needs a '{key}'")
    name = _substitute(raw["name"], args, str(path), raw.line_of("name"), "name")
    if not isinstance(name, str) or not NODE_NAME.fullmatch(name):
        raise GraphError(path, raw.line_of("name"), f"nodes[{i}].name",
                         f"{str(name)[:80]!r} is not a node name (letters, digits, '_' and '-', at most 64, "
                         "starting with a letter or '_')")
    if not _condition(raw, args, str(path), f"nodes[{name}].if"):
        return None
    params = raw.get("params") or LinedDict()
    if not isinstance(params, dict):
        raise GraphError(path, raw.line_of("params"), f"nodes[{name}].params", "must be a mapping")
    remap = raw.get("remap") or {}
    if not isinstance(remap, dict):
        raise GraphError(path, raw.line_of("remap"), f"nodes[{name}].remap", "must be a mapping port: topic")
    node = NodeSpec(
        name=name,
        type=str(_substitute(raw["type"], args, str(path), raw.line_of("type"), f"nodes[{name}].type")),
        params=_substitute(params, args, str(path), raw.line_of("params"), f"nodes[{name}].params"),
        remap={str(k): str(v) for k, v in _substitute(remap, args, str(path), raw.line_of("remap"),
                                                      f"nodes[{name}].remap").items()},
        file=str(path),
        line=line,
        key_lines=dict(raw.key_lines),
        param_lines=dict(getattr(params, "key_lines", {})),
    )
    for key, kind in (("respawn", bool), ("required", bool), ("respawn_delay", (int, float)),
                      ("respawn_max_delay", (int, float)), ("host", str),
                      ("machine", str), ("port", int), ("process", str), ("nice", int)):
        if key in raw:
            value = _substitute(raw[key], args, str(path), raw.line_of(key), key)
            if (not isinstance(value, kind) or (kind is not bool and isinstance(value, bool))
                    or (key in SECONDS_KEYS and not (math.isfinite(value) and 0 <= value <= 3600))):
                raise node.error(key, f"wants {'a finite number of seconds in [0, 3600]' if key in SECONDS_KEYS else kind.__name__}, "
                                 f"got {value!r}")
            if key == "port" and not 1 <= value <= 65535:
                raise node.error(key, f"wants a tcp port in 1..65535, got {value!r}")
            if key == "nice" and not 0 <= value <= 19:   # (below 0 needs privileges a lab PC should not give)
                raise node.error(key, f"wants a niceness in 0..19 (higher: yields the CPU to the other nodes), "
                                 f"got {value!r}")
            if key == "process" and value and not NODE_NAME.fullmatch(value):   # '' : its own process
                raise node.error(key, f"{value[:80]!r} is not a process name (letters, digits, '_' and '-', "
                                 "at most 64, starting with a letter or '_')")
            setattr(node, key, float(value) if key in SECONDS_KEYS else value)
    if node.machine and not (node.host and node.port):
        raise node.error("machine", "a node on a named machine needs host: (that machine's address) and port: "
                         "so the other machines can connect to it")
    return node
