"""The house rules a machine can check: every module states its job, no oversized runtime classes."""
from __future__ import annotations

import ast
from pathlib import Path

import mocapgraph

PACKAGE = Path(mocapgraph.__file__).resolve().parent
MAX_CLASS_LINES = 250
SIZE_CHECKED = ("bus", "launch", "nodes")


def _modules() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def test_every_module_first_docstring_line_states_its_job() -> None:
    missing = []
    for path in _modules():
        doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8")))
        first = doc.splitlines()[0].strip() if doc else ""
        if len(first.split()) < 4:  # "" or a stub such as "Helpers." says no job
            missing.append(f"{path.relative_to(PACKAGE.parent)}: {first!r}")
    assert len(_modules()) > 50  # the walk found the package
    assert not missing, "modules whose first docstring line does not say their job:\n" + "\n".join(missing)


def test_no_class_over_the_limit_in_the_runtime_parts() -> None:
    big, seen = [], 0
    for part in SIZE_CHECKED:
        for path in sorted((PACKAGE / part).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ClassDef):
                    seen += 1
                    lines = node.end_lineno - node.lineno + 1
                    if lines > MAX_CLASS_LINES:
                        big.append(f"{path.relative_to(PACKAGE.parent)}: {node.name} has {lines} lines")
    assert seen > 20  # the classes were found
    assert not big, f"classes over {MAX_CLASS_LINES} lines:\n" + "\n".join(big)
