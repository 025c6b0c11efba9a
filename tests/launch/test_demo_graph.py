"""The demo runs unattended for anyone (issue 30, item 11): every stage respawns when it dies, and
its session log is the launching user's file in the working folder, not one fixed /tmp name
shared (and pre-creatable) by every user. The real demo graph is launched and a stage killed."""
from __future__ import annotations

import os
import signal
from pathlib import Path

from graph_helpers import node_pids, read_jsonl, wait_until
from mocapgraph.launch.graph import load_graph

DEMO = Path(__file__).resolve().parents[2] / "graph_configs" / "demo.yaml"


def test_every_demo_stage_respawns_and_the_session_log_is_not_a_shared_tmp_file():
    spec = load_graph(DEMO)
    assert {n.name for n in spec.nodes if not n.respawn} == set(), [n.name for n in spec.nodes if not n.respawn]
    log = next(n for n in spec.nodes if n.type == "topic_logger").params["path"]
    assert not os.path.isabs(log) and "/tmp" not in log, log


def test_a_killed_demo_stage_comes_back_and_the_log_is_written_where_the_user_launched(launch_graph, tmp_path):
    g = launch_graph(DEMO, "port:=0", f"model_file:={tmp_path / 'model.json'}")
    g.wait_ready(timeout=180)
    wait_until(lambda: read_jsonl(tmp_path / "mocapgraph_demo_session.jsonl", "reader_status"), timeout=60,
               what="the session log in the working folder", graph=g)
    pid = node_pids(g)["solver"]
    os.kill(pid, signal.SIGKILL)
    g.wait_for("respawning solver", timeout=30)
    wait_until(lambda: (p := node_pids(g).get("solver")) and p != pid, timeout=60, what="a new solver", graph=g)
    assert g.proc.poll() is None
    g.stop()
