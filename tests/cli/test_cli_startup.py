"""A command imports only its own family: same parser, same help and errors as the whole
parser, and a family's run does not load the others' (the graph checker, scipy)."""
from __future__ import annotations

import argparse
import contextlib
import io
import subprocess
import sys
from importlib import import_module

import pytest

from mocapgraph.cli import COMMAND_MODULES, COMMANDS, build_parser
from mocapgraph.cli.examples import leaves

FULL = build_parser()


def _top_level(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def test_the_table_names_the_module_that_registers_each_command():
    for module in COMMAND_MODULES:
        p = argparse.ArgumentParser(prog="mocapgraph")
        import_module(f"mocapgraph.cli.{module}").register(p.add_subparsers())
        assert set(_top_level(p)) == {c for c, m in COMMANDS.items() if m == module}, module
    assert set(_top_level(FULL)) == set(COMMANDS)


def _outcome(parser: argparse.ArgumentParser, argv: list[str]) -> tuple[object, str, str]:
    """(exit code or parsed namespace as text, stdout, stderr) of parsing argv."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            ns = vars(parser.parse_args(argv))
            result: object = {k: (v.__qualname__ if callable(v) else v) for k, v in ns.items()}
        except SystemExit as exc:
            result = exc.code
    return result, out.getvalue(), err.getvalue()


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_command_parses_helps_and_fails_as_with_every_family_loaded(command):
    lazy = build_parser(command)
    assert set(_top_level(lazy)) == {c for c, m in COMMANDS.items() if m == COMMANDS[command]}
    full_leaves = {path: p for path, p in leaves(FULL).items() if path.split()[0] == command}
    lazy_leaves = {path: p for path, p in leaves(lazy).items() if path.split()[0] == command}
    assert list(lazy_leaves) == list(full_leaves)
    for path, p in full_leaves.items():
        assert lazy_leaves[path].format_help() == p.format_help(), path
        assert lazy_leaves[path].format_usage() == p.format_usage(), path
    for argv in ([command], [command, "--help"], [command, "--no-such-option"], [command, "no-such-word"],
                 *([*path.split(), "--help"] for path in full_leaves),
                 *([*path.split(), "--no-such-option"] for path in full_leaves)):
        got, want = _outcome(lazy, argv), _outcome(FULL, argv)
        assert got == want, argv


def _loaded_after(*argvs: list[str]) -> set[str]:
    """Modules a fresh interpreter holds after running ``main`` on each of ``argvs``."""
    code = ("import sys\nfrom mocapgraph.cli import main\n"
            f"for argv in {argvs!r}:\n"
            "    try:\n        main(argv)\n    except SystemExit:\n        pass\n"
            "print(' '.join(sorted(sys.modules)))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    return set(run.stdout.splitlines()[-1].split())


HEAVY = {"mocapgraph.launch.check", "scipy", "numba", "networkx", "mujoco"}


def test_a_command_loads_only_its_family():
    loaded = _loaded_after(["topic", "--help"], ["device", "simulate", "--help"], ["bag", "info", "--help"])
    assert {"mocapgraph.cli.topic_cmds", "mocapgraph.cli.device_cmds", "mocapgraph.cli.bag_cmds"} <= loaded
    assert not loaded & ({"mocapgraph.cli.graph_cmds", "mocapgraph.cli.actor_cmds"} | HEAVY), sorted(loaded)


def test_the_whole_help_loads_no_graph_checker():
    loaded = _loaded_after(["--help"], ["graph", "--help"], ["launch", "--help"])
    assert {f"mocapgraph.cli.{m}" for m in COMMAND_MODULES} <= loaded
    assert not loaded & HEAVY, sorted(loaded & HEAVY)
