"""Bad graph files as a new user writes them: one clear line naming file, line and key, exit 2."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mocapgraph.cli import main

GOOD = """\
args:
  rate: {default: 100.0}
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {rate_hz: "${rate}", n_markers: 4}
  - name: logger
    type: topic_logger
    params: {path: out.jsonl, topics: [markers]}
"""


def check(tmp_path: Path, text: str, capsys, *args: str, name: str = "g.yaml") -> tuple[int, str]:
    path = tmp_path / name
    path.write_text(text)
    code = main(["graph", "check", str(path), *args])
    out = capsys.readouterr()
    return code, (out.err + out.out).strip()


def test_good_graph_passes(tmp_path, capsys) -> None:
    code, text = check(tmp_path, GOOD, capsys)
    assert code == 0 and "OK, 2 nodes" in text


# Each message is asserted whole: a hint that names the wrong key, or a part of the message that
# goes missing, fails (``{path}`` stands for the graph file's path).
@pytest.mark.parametrize("text, line, key, message", [
    (GOOD.replace("type: topic_logger", "type: topic_loger"), 8, "nodes[logger].type",
     "unknown node type 'topic_loger' (did you mean 'topic_logger'?)"),
    (GOOD.replace("n_markers: 4", "n_markerz: 4"), 6, "nodes[pattern].params.n_markerz",
     "unknown parameter of marker_test_pattern (did you mean 'n_markers'?)"),
    (GOOD.replace('"${rate}"', "fast"), 6, "nodes[pattern].params.rate_hz",
     "parameter 'rate_hz' wants float, got str 'fast'"),
    (GOOD.replace("topics: [markers]", "topics: [markerz]"), 8, "nodes[logger].type",
     "input 'in0' subscribes to topic 'markerz' that no node publishes (did you mean 'markers'?)"),
    (GOOD.replace("- name: logger", "- name: pattern"), 7, "nodes[pattern].name",
     "duplicate node name (first at {path}:4)"),
    (GOOD.replace("    params: {path", "    parms: {path"), 9, "nodes[logger].parms", "unknown key (did you mean 'params'?)"),
    (GOOD.replace('"${rate}"', '"${rat}"'), 6, "nodes[pattern].params.rate_hz",
     "unknown arg ${rat} (did you mean 'rate'?)"),
])
def test_each_fault_names_file_line_and_key(tmp_path, capsys, text, line, key, message) -> None:
    code, msg = check(tmp_path, text, capsys)
    path = tmp_path / "g.yaml"
    assert code == 2
    assert msg == f"mocapgraph: {path}:{line}: {key}: " + message.replace("{path}", str(path))


def test_yaml_syntax_error(tmp_path, capsys) -> None:
    code, msg = check(tmp_path, GOOD.replace("params: {rate_hz", "params: {rate_hz: [1,"), capsys)
    assert code == 2 and "g.yaml:" in msg and "YAML syntax error" in msg and msg.count("\n") == 0


def test_type_mismatch_between_publisher_and_subscriber(tmp_path, capsys) -> None:
    text = GOOD + """  - name: relay
    type: marker_test_pattern
    remap: {marker_layout: markers}
"""
    code, msg = check(tmp_path, text, capsys)
    assert code == 2 and "g.yaml:12: nodes[relay].remap:" in msg
    assert "MarkerLayout" in msg and "MarkerFrame" in msg


def test_missing_include_and_include_cycle(tmp_path, capsys) -> None:
    code, msg = check(tmp_path, "include:\n  - file: nowhere.yaml\n", capsys)
    assert code == 2 and "g.yaml:2: include[0].file: nowhere.yaml does not exist" in msg
    (tmp_path / "a.yaml").write_text("include:\n  - file: b.yaml\n")
    (tmp_path / "b.yaml").write_text("include:\n  - a.yaml\n")
    code, msg = check(tmp_path, "include:\n  - file: a.yaml\n", capsys)
    assert code == 2 and "include cycle: g.yaml -> a.yaml -> b.yaml -> a.yaml" in msg


def test_unknown_command_line_arg_and_typed_override(tmp_path, capsys) -> None:
    code, msg = check(tmp_path, GOOD, capsys, "rat:=5")
    assert code == 2 and "args.rat: no such arg" in msg and "did you mean 'rate'" in msg
    code, msg = check(tmp_path, GOOD, capsys, "rate:=fast")
    assert code == 2 and "nodes[pattern].params.rate_hz: parameter 'rate_hz' wants float" in msg
    code, msg = check(tmp_path, GOOD, capsys, "rate:=240")
    assert code == 0


def test_cli_exit_code_and_no_traceback_from_a_real_process(tmp_path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(GOOD.replace("marker_test_pattern", "marker_test_patern"))
    r = subprocess.run([sys.executable, "-m", "mocapgraph", "launch", str(path)], capture_output=True, text=True,
                       timeout=30)
    assert r.returncode == 2
    assert r.stderr.strip().startswith("mocapgraph: ") and "bad.yaml:5: nodes[pattern].type" in r.stderr
    assert "Traceback" not in r.stderr + r.stdout


def test_if_leaves_nodes_and_includes_out(tmp_path, capsys) -> None:
    from mocapgraph.launch.graph import load_graph

    (tmp_path / "extra.yaml").write_text("nodes:\n  - {name: extra, type: marker_test_pattern}\n")
    text = GOOD.replace("  - name: logger\n", "  - name: logger\n    if: \"${log}\"\n").replace(
        "args:\n", "args:\n  log: {default: true}\n  more: {default: false}\n") + \
        "include:\n  - {file: extra.yaml, if: \"${more}\"}\n"
    path = tmp_path / "g.yaml"
    path.write_text(text)
    assert [n.name for n in load_graph(path).nodes] == ["pattern", "logger"]
    assert [n.name for n in load_graph(path, {"log": False, "more": True}).nodes] == ["extra", "pattern"]
    code, msg = check(tmp_path, text, capsys, "log:=maybe")
    assert code == 2 and "nodes[logger].if: wants true or false, got 'maybe'" in msg
