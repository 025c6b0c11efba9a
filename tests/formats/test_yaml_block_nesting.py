"""A graph file nested deeper than MAX_DEPTH in block style (indentation, no brackets) is refused by the
YAML loader itself, in one line naming the file and the line where the nesting passes the limit.

Flow style (``[[[``) is refused by a byte pre-scan before YAML sees it (tests/launch/test_graph_check_refusals);
block nesting has no brackets to count, so only the composer's depth check stands in its way.
"""
from __future__ import annotations

from pathlib import Path

from graph_helpers import graph_error

from mocapgraph.cli import main
from mocapgraph.formats.yaml_source import MAX_DEPTH

HEAD = "nodes:\n  - name: pattern\n    type: marker_test_pattern\n    params:\n"


def nested_params(levels: int) -> str:
    """A graph whose node's params nest ``levels`` mappings deep, two spaces a level. From line 5 on,
    line k holds the key at nesting depth k (root mapping, nodes list, node mapping, params: 4)."""
    keys = [f"      {'  ' * k}level{k}:" for k in range(levels)]
    keys[-1] += " 1"
    return HEAD + "\n".join(keys) + "\n"


def test_block_nesting_80_deep_is_refused_with_file_and_line(tmp_path: Path, capsys) -> None:
    path = tmp_path / "deep.yaml"
    assert "[" not in nested_params(80) and "{" not in nested_params(80)
    msg = graph_error(path, nested_params(80))
    assert msg == f"{path}:{MAX_DEPTH + 1}: nested deeper than {MAX_DEPTH} levels", msg
    # what a user runs: one line, exit 2
    assert main(["graph", "check", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"mocapgraph: {path}:{MAX_DEPTH + 1}: nested deeper than {MAX_DEPTH} levels", err


def test_block_nesting_exactly_at_the_limit_is_read_one_more_is_not(tmp_path: Path) -> None:
    # MAX_DEPTH - 4 levels under params: the deepest key sits at depth MAX_DEPTH (line MAX_DEPTH).
    # Read whole, the graph check gets to the params and refuses the made-up one by name.
    msg = graph_error(tmp_path / "ok.yaml", nested_params(MAX_DEPTH - 4))
    assert "nested deeper" not in msg and "params.level0: unknown parameter" in msg, msg
    msg = graph_error(tmp_path / "one_more.yaml", nested_params(MAX_DEPTH - 3))
    assert msg.endswith(f"one_more.yaml:{MAX_DEPTH + 1}: nested deeper than {MAX_DEPTH} levels"), msg
