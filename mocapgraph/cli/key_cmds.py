"""``mocapgraph keys generate``: CurveZMQ key pairs for a graph's ``security:`` section."""
from __future__ import annotations

import argparse
from pathlib import Path

from . import UserError


def cmd_generate(args: argparse.Namespace) -> int:
    from ..bus.curve import generate

    folder = Path(args.folder)
    for suffix in (".key", ".key_secret"):
        if (folder / f"{args.name}{suffix}").exists() and not args.force:
            raise UserError(f"{folder / (args.name + suffix)} exists; pass --force to replace it")
    public, secret = generate(folder, args.name)
    print(f"wrote {public} (public: copy it into the authorized folder of every machine) and {secret} "
          "(secret, mode 0600: keep it on the machines of this graph only)")
    print(f"graph file:  security: {{key: {secret}, authorized: {folder}}}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    k = sub.add_parser("keys", help="CurveZMQ keys for graphs that span machines")
    ks = k.add_subparsers(dest="keys_command", required=True)
    p = ks.add_parser("generate", help="write NAME.key (public) and NAME.key_secret into FOLDER")
    p.add_argument("folder")
    p.add_argument("--name", default="graph", help="file name of the pair (default graph)")
    p.add_argument("-f", "--force", action="store_true", help="replace an existing pair")
    p.set_defaults(func=cmd_generate)
