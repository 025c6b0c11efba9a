"""The ``mocapgraph`` command. Each command family registers itself from its own module."""
from __future__ import annotations

import argparse
import sys
from importlib import import_module

# Command-family modules inside this package, each with register(subparsers).
COMMAND_MODULES = ("graph_cmds", "topic_cmds", "bag_cmds", "actor_cmds", "device_cmds", "retarget_cmds",
                   "physics_cmds")


class UserError(Exception):
    """A problem to report in one line, exit code 2, no traceback."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mocapgraph",
        description="Motion capture as a graph of processes: run graphs, inspect topics, bags, batch jobs.",
        epilog="Start with: mocapgraph launch graph_configs/demo.yaml (then open http://127.0.0.1:8765/)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        import_module(f"{__name__}.{name}").register(sub)
    from .examples import attach
    attach(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
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
