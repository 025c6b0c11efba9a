"""The physics world as parts: the house rules on its files, and the references' signatures are the kernels'.

Sizes read from the source (no class over 300 lines, no function over 100, no kernel over 12
parameters) for the physics package and the live global fit; every numpy reference the tests run
takes the parameters of the kernel it stands for, name for name, so a world built on either calls
them alike.
"""
from __future__ import annotations

import ast
import inspect
from pathlib import Path

import mocapgraph
from mocapgraph.physics import reference
from mocapgraph.physics.world import COMPILED, Kernels

PACKAGE = Path(mocapgraph.__file__).resolve().parent
PARTS = sorted((PACKAGE / "physics").glob("*.py")) + [PACKAGE / "kinematics" / "solving" / n for n in
                                                      ("global_track.py", "global_track_numpy.py",
                                                       "global_fit_kernels.py")]


def _sizes():
    for path in PARTS:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
                kernel = any("kernel" in ast.unparse(d) for d in getattr(node, "decorator_list", []))
                n_args = len(node.args.args) if isinstance(node, ast.FunctionDef) else 0
                yield path.relative_to(PACKAGE.parent), node, node.end_lineno - node.lineno + 1, kernel, n_args


def test_no_class_function_or_kernel_over_the_limits():
    big, kernels = [], 0
    for path, node, lines, kernel, n_args in _sizes():
        kernels += kernel
        if isinstance(node, ast.ClassDef) and lines > 300:
            big.append(f"{path}: class {node.name} has {lines} lines")
        if isinstance(node, ast.FunctionDef) and lines > 100:
            big.append(f"{path}: {node.name} has {lines} lines")
        if kernel and n_args > 12:
            big.append(f"{path}: kernel {node.name} takes {n_args} parameters")
    assert kernels > 20   # the kernels were found
    assert not big, "\n".join(big)


def test_every_reference_takes_its_kernels_parameters():
    for name in Kernels._fields:
        fast, ref = getattr(COMPILED, name), getattr(reference.REFERENCE, name)
        assert list(inspect.signature(fast.py_func).parameters) == list(inspect.signature(ref).parameters), name
        assert ref.__module__ == reference.__name__ and not hasattr(ref, "py_func"), name   # numpy, not numba
