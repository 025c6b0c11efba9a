"""``mocapgraph bag export-foxglove``: a bag of ours as a Foxglove-native MCAP (3D scene, plots)."""
from __future__ import annotations

import argparse
from pathlib import Path

from . import UserError
from .progress import Progress


def cmd_export_foxglove(args: argparse.Namespace) -> int:
    from ..bag.errors import BagError
    from ..bag.foxglove_export import export_foxglove

    out = Path(args.output) if args.output else Path(args.file).with_suffix(".foxglove.mcap")
    if out.exists() and not args.force:
        raise UserError(f"{out}: exists (-f overwrites)")
    try:
        with Progress("exporting", unit="msg") as bar:
            rep = export_foxglove(args.file, out, topics=args.topics, progress=bar)
    except BagError as exc:
        raise UserError(str(exc)) from None
    print(rep.text())
    return 1 if rep.stopped else 0


def register_bag(bs: argparse._SubParsersAction) -> None:
    """Add ``export-foxglove`` to the ``bag`` subcommands."""
    p = bs.add_parser("export-foxglove", help="rewrite a bag with Foxglove's schemas (SceneUpdate, JSON plots)",
                      description="Write a new MCAP file that Foxglove's 3D and Plot panels decode: markers, "
                                  "actors, skeletons, characters and physics bodies as foxglove.SceneUpdate, "
                                  "diagnostics as JSON. The source bag is not changed.",
                      epilog="Then open the output in Foxglove (Open local file) and add a 3D panel.")
    p.add_argument("file", metavar="BAG", help="a bag recorded or converted by mocapgraph")
    p.add_argument("-o", "--output", help="output MCAP (default <name>.foxglove.mcap)")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics (latched ones included)")
    p.add_argument("-f", "--force", action="store_true", help="overwrite an existing output")
    p.set_defaults(func=cmd_export_foxglove)
