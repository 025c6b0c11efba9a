"""The ``mocapgraph`` command. Each command family registers itself from its own module.

A run imports only the module of the command it names (`COMMANDS`): every node and test starts
this interpreter, and the families' imports (the graph checker, scipy, numba, the bus) cost about
a second a start. ``mocapgraph --help``, an unknown command and a command missing from the table
build the whole parser, so every output reads as it would with all families loaded.
"""
from __future__ import annotations

import argparse
import sys
from importlib import import_module

# Command-family modules inside this package, each with register(subparsers), in --help order.
COMMAND_MODULES = ("graph_cmds", "topic_cmds", "bag_cmds", "actor_cmds", "device_cmds", "retarget_cmds",
                   "physics_cmds", "key_cmds")

# Top-level command -> the module that registers it (a test checks it against the registrations).
COMMANDS: dict[str, str] = {
    "launch": "graph_cmds", "graph": "graph_cmds", "node": "graph_cmds", "topic": "topic_cmds",
    "bag": "bag_cmds", "calibrate": "actor_cmds", "solve": "actor_cmds", "device": "device_cmds",
    "retarget": "retarget_cmds", "physics": "physics_cmds", "posture-db": "physics_cmds", "keys": "key_cmds",
}


class UserError(Exception):
    """A problem to report in one line, exit code 2, no traceback."""


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The command's parser: every family's commands, or (``command`` named in `COMMANDS`) only
    those of the family that registers ``command``."""
    parser = argparse.ArgumentParser(
        prog="mocapgraph",
        description="Motion capture as a graph of processes: run graphs, inspect topics, bags, batch jobs.",
        epilog="Start with: mocapgraph launch graph_configs/demo.yaml (then open http://127.0.0.1:8765/)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in (COMMANDS[command],) if command in COMMANDS else COMMAND_MODULES:
        import_module(f"{__name__}.{name}").register(sub)
    from .examples import attach
    attach(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    # the command is the first word: the top-level parser has no option but -h
    parser = build_parser(argv[0] if argv and not argv[0].startswith("-") else None)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"mocapgraph: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
