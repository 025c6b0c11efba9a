"""The house rules a machine can check, for every part of mocapgraph/: each module states its job,
no class over 300 lines, no function over 100, no compiled kernel over 12 parameters, every kernel
module warmed, no import cycle between files, and the parts tie one way (nodes never import launch;
the math never imports the bus)."""
from __future__ import annotations

import ast
from functools import lru_cache
from pathlib import Path

import networkx as nx

import mocapgraph
from mocapgraph.jit import KERNEL_MODULES, WARMED_BY

PACKAGE = Path(mocapgraph.__file__).resolve().parent
MAX_CLASS_LINES = 300
MAX_FUNCTION_LINES = 100
MAX_KERNEL_PARAMS = 12
#: part -> parts it may never import, even inside a function (the layers of mocapgraph/__init__.py)
NEVER_IMPORTS = {
    "nodes": ("launch", "cli"),
    "bus": ("nodes", "launch", "cli"),
    "kinematics": ("retarget", "physics", "bus", "nodes", "launch", "cli", "bag", "viewer", "net"),
    "retarget": ("physics", "bus", "nodes", "launch", "cli", "bag", "viewer", "net"),
    "physics": ("bus", "nodes", "launch", "cli", "bag", "viewer", "net"),
}


def _modules() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _part(path: Path) -> str:
    """The part a file belongs to: its first folder under mocapgraph/ (or the file, at the top)."""
    rel = path.relative_to(PACKAGE)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


@lru_cache(maxsize=None)
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"))


def _where(path: Path, node: ast.AST) -> str:
    return f"{path.relative_to(PACKAGE.parent)}:{node.lineno}"


def _by_part(found: list[tuple[Path, str]]) -> str:
    """Offences grouped by part, one line each."""
    lines = []
    for part in sorted({_part(p) for p, _ in found}):
        lines.append(f"[{part}]")
        lines += [f"  {what}" for p, what in found if _part(p) == part]
    return "\n".join(lines)


def test_every_module_first_docstring_line_states_its_job() -> None:
    missing = []
    for path in _modules():
        doc = ast.get_docstring(_tree(path))
        first = doc.splitlines()[0].strip() if doc else ""
        if len(first.split()) < 4:  # "" or a stub such as "Helpers." says no job
            missing.append(f"{path.relative_to(PACKAGE.parent)}: {first!r}")
    assert len(_modules()) > 50  # the walk found the package
    assert not missing, "modules whose first docstring line does not say their job:\n" + "\n".join(missing)


def test_no_class_over_300_lines_in_any_part() -> None:
    big, seen = [], set()
    for path in _modules():
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.ClassDef):
                seen.add(_part(path))
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_CLASS_LINES:
                    big.append((path, f"{_where(path, node)} class {node.name}: {lines} lines"))
    assert {"bus", "nodes", "kinematics", "physics", "formats", "bag"} <= seen  # the classes were found
    assert not big, f"classes over {MAX_CLASS_LINES} lines:\n" + _by_part(big)


def test_no_function_over_100_lines_in_any_part() -> None:
    long, seen = [], 0
    for path in _modules():
        for node in ast.walk(_tree(path)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):   # methods and nested ones too
                seen += 1
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    long.append((path, f"{_where(path, node)} {node.name}(): {lines} lines"))
    assert seen > 1000
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + _by_part(long)


def _kernel_decorators(tree: ast.Module) -> set[str]:
    """Names that stand for `mocapgraph.jit.kernel` in a module: imported (maybe renamed), or bound
    at the top to a `kernel_calling(...)`."""
    names = set()
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and (node.module or "").endswith("jit"):
            names |= {a.asname or a.name for a in node.names if a.name == "kernel"}
        elif isinstance(node, ast.Assign) and isinstance(node.value, ast.Call):
            func = node.value.func
            if (func.id if isinstance(func, ast.Name) else getattr(func, "attr", "")) == "kernel_calling":
                names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return names


def _kernels() -> list[tuple[Path, ast.FunctionDef]]:
    """Every function compiled through jit.py: decorated with `kernel`, its alias, or `kernel_calling(...)`."""
    found = []
    for path in _modules():
        tree = _tree(path)
        names = _kernel_decorators(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef):
                for dec in node.decorator_list:
                    call = dec.func if isinstance(dec, ast.Call) else None
                    if (isinstance(dec, ast.Name) and dec.id in names) or (
                            isinstance(call, ast.Name) and call.id == "kernel_calling"):
                        found.append((path, node))
    return found


def test_no_kernel_over_12_parameters() -> None:
    wide = []
    kernels = _kernels()
    for path, fn in kernels:
        a = fn.args
        n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
        if n > MAX_KERNEL_PARAMS:
            wide.append((path, f"{_where(path, fn)} {fn.name}: {n} parameters"))
    assert len(kernels) > 30   # the kernels were found
    assert not wide, f"kernels over {MAX_KERNEL_PARAMS} parameters:\n" + _by_part(wide)


def test_every_kernel_module_is_warmed_and_compiles_through_jit() -> None:
    """A module with kernels that KERNEL_MODULES misses compiles in a running node (seconds of stall);
    a numba decorator used directly escapes the cache, the run-time compile report and these rules."""
    with_kernels = {_module_name(path) for path, _ in _kernels()}
    assert with_kernels <= set(KERNEL_MODULES), f"kernel modules not in jit.KERNEL_MODULES: {sorted(with_kernels - set(KERNEL_MODULES))}"
    assert set(KERNEL_MODULES) <= {_module_name(p) for p in _modules()}, "KERNEL_MODULES names a module that is gone"
    for module, warmer in WARMED_BY.items():   # a warm-up named for a module is a function that exists
        where, _, func = warmer.partition(":")
        assert module in KERNEL_MODULES and func in {n.name for n in _tree(PACKAGE.parent / (where.replace(".", "/") + ".py")).body
                                                     if isinstance(n, ast.FunctionDef)}, f"WARMED_BY: {module} -> {warmer}"
    direct = [f"{_where(p, n)}: {ast.unparse(n)}" for p in _modules() if p.name != "jit.py"
              for n in ast.walk(_tree(p)) if isinstance(n, (ast.Attribute, ast.Name))
              and (n.attr if isinstance(n, ast.Attribute) else n.id) in ("njit", "jit", "vectorize", "guvectorize", "cfunc")
              and "numba" in ast.unparse(n)]
    assert not direct, "numba used directly (use mocapgraph.jit.kernel):\n" + "\n".join(direct)


def _type_checking_only(tree: ast.Module) -> set[int]:
    """ids of the nodes under ``if TYPE_CHECKING:`` (imports for annotations, never run)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            out |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    return out


@lru_cache(maxsize=None)
def import_graph(type_checking: bool = False) -> nx.DiGraph:
    """File -> file imports of mocapgraph/ from the AST, function-level imports included; an edge
    carries the line. ``from pkg import mod`` ties to the module ``mod``; ``from pkg import name``
    to ``pkg``'s __init__. Imports under ``if TYPE_CHECKING:`` only when ``type_checking``."""
    files = {_module_name(p): p for p in _modules()}
    graph = nx.DiGraph()
    graph.add_nodes_from(files)
    for mod, path in files.items():
        tree = _tree(path)
        skip = set() if type_checking else _type_checking_only(tree)
        pkg = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        for node in ast.walk(tree):
            if id(node) in skip:
                continue
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1] if node.level else []
                src = ".".join(base + ([node.module] if node.module else []))
                targets = [f"{src}.{a.name}" if f"{src}.{a.name}" in files else src for a in node.names]
            else:
                continue
            for target in targets:
                if target in files and target != mod:
                    graph.add_edge(mod, target, line=f"{path.relative_to(PACKAGE.parent)}:{node.lineno}")
    return graph


def test_no_import_cycle_between_files() -> None:
    """Imports that run (at load or in a function) form no circle; type-only imports are not loads."""
    graph = import_graph()
    assert graph.number_of_edges() > 300   # the graph was built
    circles = []
    for scc in sorted(nx.strongly_connected_components(graph), key=sorted):
        if len(scc) > 1:
            ties = [f"    {a} -> {b} ({graph.edges[a, b]['line']})" for a, b in sorted(graph.subgraph(scc).edges)]
            circles.append(f"  circle of {len(scc)} files:\n" + "\n".join(ties))
    assert not circles, "import cycles between files:\n" + "\n".join(circles)


def _ties(graph: nx.DiGraph, part: str, other: str) -> list[str]:
    return [f"{a} -> {b} ({graph.edges[a, b]['line']})" for a, b in graph.edges
            if a.split(".")[1] == part and b.split(".")[1] == other]


def test_launch_and_nodes_tie_one_way() -> None:
    """The launcher imports the node registry to check graphs; nodes never import the launcher
    (what both need, the run dir and the manifest, lives below both in bus/)."""
    graph = import_graph(type_checking=True)
    assert _ties(graph, "launch", "nodes")   # the tie that is meant (check.py -> nodes.registry) is seen
    assert not _ties(graph, "nodes", "launch"), "nodes importing launch/:\n" + "\n".join(_ties(graph, "nodes", "launch"))


def test_no_part_imports_a_layer_above_it() -> None:
    graph = import_graph(type_checking=True)
    upward = [tie for part, above in NEVER_IMPORTS.items() for other in above for tie in _ties(graph, part, other)]
    assert _ties(graph, "nodes", "bus") and _ties(graph, "kinematics", "messages")   # the parts were read
    assert not upward, "imports of a layer above:\n" + "\n".join(upward)
