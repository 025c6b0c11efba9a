"""Process entry of one node, or of a ``process:`` group: ``python -m mocapgraph.bus.runtime WIRING.json...``.

The launcher writes one wiring file per node (node name, class, params, endpoints) and starts
this module as a child process with the files of every node that process runs (`process.serve`).
The child asks the kernel to send it SIGTERM when the launcher dies, so no node outlives its
launcher, even one killed with SIGKILL.
"""
from __future__ import annotations

import importlib
import json
import logging
import sys
from pathlib import Path
from typing import Any

from .node import LOG_FORMAT, Node, NodeConfigError
from .process import install_stop_handlers, serve
from .protocol import Wiring, die_with_parent  # noqa: F401  (die_with_parent: the launcher's preexec hook)


def _file_module(path: str) -> Any:
    """The module in the ``.py`` file ``path`` (its folder first on sys.path, as for a script)."""
    import importlib.util

    name = "mocapgraph_graph_node_" + "".join(c if c.isalnum() else "_" for c in path)
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path}")
    folder = str(Path(path).parent)
    if folder not in sys.path:
        sys.path.insert(0, folder)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def load_class(spec: str) -> type[Node]:
    """``package.module:ClassName`` or ``/path/to/file.py:ClassName`` -> the class."""
    module, _, attr = spec.rpartition(":")
    cls = getattr(_file_module(module) if module.endswith(".py") else importlib.import_module(module), attr)
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        raise TypeError(f"{spec} is not a mocapgraph Node")
    return cls


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    # several nodes in one process: each line names its node (the launcher prefixes the process)
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT if len(argv) == 1 else "%(name)s: " + LOG_FORMAT,
                        stream=sys.stderr)
    nodes: list[Node] = []
    for path in argv:
        with open(path) as f:
            spec: dict[str, Any] = json.load(f)
        wiring = Wiring(**spec["wiring"])
        cls = load_class(spec["class"])
        try:
            nodes.append(cls(wiring.node, spec.get("params", {}), wiring))
        except NodeConfigError as exc:
            logging.getLogger(wiring.node).error("%s", exc)
            return 2
    install_stop_handlers(nodes)
    return serve(nodes)


if __name__ == "__main__":
    sys.exit(main())
