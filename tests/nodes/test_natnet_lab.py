"""lab_natnet.yaml: the same optical pipeline as lab_udp.yaml with only the reader swapped, and the
whole graph running from `mocapgraph device simulate natnet` (its own process): the synthetic
performer's markers arrive in the plug_in_gait layout, in metres, Z up."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from mocapgraph.cli import main as cli_main
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.launch.check import check_graph
from mocapgraph.launch.graph import load_graph

from graph_helpers import read_jsonl, wait_until
from tests.nodes.test_lab_graphs import CONFIGS, logged_graph
from tests.nodes.test_natnet_reader import free_udp_port


def test_lab_natnet_differs_from_lab_udp_in_the_reader_only() -> None:
    shapes = {}
    for name in ("lab_udp", "lab_natnet"):
        g = check_graph(load_graph(CONFIGS / f"{name}.yaml"), check_files=False)
        shapes[name] = sorted((n.name, n.spec.type, json.dumps(n.params, sort_keys=True))
                              for n in g.nodes if n.name != "reader")
        assert {"markers", "marker_layout"} <= set(g.node("reader").outputs.values())
    assert shapes["lab_udp"] == shapes["lab_natnet"]


def test_node_info_documents_every_param(capsys) -> None:
    assert cli_main(["node", "info", "natnet_reader"]) == 0
    params = capsys.readouterr().out.split("params:\n")[1].strip().splitlines()
    for line in params:
        name, _, rest = line.strip().partition(": ")
        assert "=" in rest and len(rest.split("  ", 1)[-1]) > 10, f"natnet_reader.{name} has no doc"


def test_lab_natnet_runs_from_the_natnet_simulator(launch_graph, tmp_path: Path) -> None:
    port = free_udp_port()
    sim = subprocess.Popen([sys.executable, "-m", "mocapgraph", "device", "simulate", "natnet", "--port", str(port),
                            "--rate", "120", "--natnet", "4.2"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert f"127.0.0.1:{port}" in sim.stdout.readline()
        g = launch_graph(logged_graph("lab_natnet", tmp_path, f"command_port: {port}",
                                      f"session_log: {tmp_path / 's.jsonl'}"))
        g.wait_ready(30)
        log = tmp_path / "lab_natnet.jsonl"
        wait_until(lambda: sum(r["topic"] == "markers" for r in read_jsonl(log)) >= 60, what="frames", timeout=30)
        assert g.stop() == 0
    finally:
        sim.kill()
        sim.wait()
    recs = read_jsonl(log)
    lay = [r for r in recs if r["topic"] == "marker_layout"][0]["msg"]
    sk = SkeletonDefinition.from_layout_file("plug_in_gait")
    assert lay["labels"] == list(sk.marker_labels) and not lay["unplaced"]
    pos = np.array([r["msg"]["positions"] for r in recs if r["topic"] == "markers"][:60], dtype=float)
    head = [i for i, m in enumerate(sk.marker_labels) if m in ("LFHD", "RFHD")]
    toes = [i for i, m in enumerate(sk.marker_labels) if m in ("LTOE", "RTOE")]
    # Motive's Y up made Z up: the head well above the higher toe in every frame, whatever the
    # performer does in the frames logged first (a bend takes the head to 0.75 m above the toes;
    # Y left as Z would put them level, within the body's depth)
    above = np.nanmean(pos[:, head, 2], axis=1) - np.nanmax(pos[:, toes, 2], axis=1)
    assert np.nanmin(above) > 0.5, above
