"""Paths from the bus and from params stay in the folders the graph names (issue 30, item 1).

A real calibration node (with a real synthetic actor feeding it) takes ``save``/``load``
commands from an ``external:`` publisher this test binds, as any peer on the bus could: absolute
paths elsewhere, ``..``, a symlink planted in the model's folder, /dev/null, a device node and a
fifo in that folder are refused in one line each and counted, nothing outside is written, and
the node stays alive and still saves where the graph says. Params naming a symlink to elsewhere
or a fifo are refused at start, in one line, with nothing written.
"""
from __future__ import annotations

import json
import os
import stat
import time
import warnings
from pathlib import Path

import pytest

from graph_helpers import CommandSender, read_jsonl, wait_until
from mocapgraph.messages import NodeCommand


def _model_file(path: Path) -> None:
    """A real kiip_full_body model calibrated from a short synthetic gym, saved to ``path``."""
    from mocapgraph.kinematics.calibration.calibrate import CalibrationWarning, calibrate
    from mocapgraph.kinematics.model import save_model
    from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
    from mocapgraph.kinematics.synthetic.motion import MotionScript

    cap = SyntheticActor("kiip_full_body", rate=60.0, seed=0, script=MotionScript(gym_block_s=1.0),
                         options=CaptureOptions(noise_mm=1.0)).capture(0, 300)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        save_model(calibrate(cap.skeleton, cap.markers, rate_hz=60.0), path)


def _status(log: Path) -> dict:
    recs = [r["msg"] for r in read_jsonl(log, "calibration_status")]
    return recs[-1] if recs else {}


def test_save_and_load_commands_never_leave_the_model_folder(launch_graph, tmp_path):
    models, outside = tmp_path / "models", tmp_path / "outside"
    models.mkdir()
    outside.mkdir()
    model_file = models / "actor_model.json"
    _model_file(model_file)
    victim = outside / "victim.json"
    victim.write_text("precious\n")
    (models / "link.json").symlink_to(victim)              # planted in the model's own folder
    (models / "dirlink").symlink_to(outside, target_is_directory=True)
    os.mkfifo(models / "pipe.json")                        # an open for writing would block the node
    os.mknod(models / "null.json", 0o600 | stat.S_IFCHR, os.makedev(1, 3))  # a /dev/null of its own
    system = Path("/etc") / f"mocapgraph_probe_{os.getpid()}.json"
    log = tmp_path / "status.jsonl"
    cmd = CommandSender("calibration_command")
    g = launch_graph(cmd.external + f"""\
nodes:
  - name: reader
    type: synthetic_actor
    params: {{layout: kiip_full_body, rate_hz: 30.0, loop: true}}
  - name: cal
    type: calibration
    params: {{model_file: {model_file}}}
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [calibration_status]}}
""")
    g.wait_ready()
    cmd.wait_subscriber()
    wait_until(lambda: _status(log).get("state") == "calibrated", timeout=30, what="the model loaded", graph=g)
    hostile = [("save", str(system)), ("save", str(victim)), ("save", str(models / ".." / "outside" / "new.json")),
               ("save", str(models / "link.json")), ("save", str(models / "dirlink" / "new.json")),
               ("save", "/dev/null"), ("save", str(models / "pipe.json")), ("save", str(models / "null.json")),
               ("load", "/etc/passwd"), ("load", str(models / "link.json")), ("load", str(models / "pipe.json")),
               ("save", "relative_to_the_working_folder.json")]
    try:
        for i, (command, path) in enumerate(hostile, 1):
            cmd.send(command, path=path)
            st = wait_until(lambda: (s := _status(log)) and json.loads(s["data_json"]).get("commands_refused") == i
                            and s, timeout=20, what=f"refusal of {command} {path}", graph=g)
            assert "refused" in st["detail"] and "\n" not in st["detail"], st["detail"]
            assert ("outside the folders" in st["detail"]) or ("not a regular file" in st["detail"]), st["detail"]
    finally:
        written = system.exists()
        system.unlink(missing_ok=True)   # what the code before this rule wrote, as root
    assert not written
    assert victim.read_text() == "precious\n"
    assert not (outside / "new.json").exists()
    assert not (tmp_path / "relative_to_the_working_folder.json").exists()
    assert stat.S_ISFIFO(os.lstat(models / "pipe.json").st_mode)
    assert g.proc.poll() is None
    # where the graph says, saving still works, and the node is the one that was there all along
    cmd.send("save", path=str(models / "copy.json"))
    wait_until(lambda: "saved to" in _status(log).get("detail", ""), timeout=20, what="the save", graph=g)
    assert json.loads((models / "copy.json").read_text())["layout"] == "kiip_full_body"
    assert "restart" not in g.output and "exited" not in g.output, g.output
    assert g.stop() == 0
    cmd.close()


def _refusing_graph(tmp: Path, kind: str) -> str:
    """A graph whose logger's path param is a symlink to a file outside (or a fifo): in ``tmp``."""
    outside = tmp / "outside"
    outside.mkdir()
    victim = outside / "victim.jsonl"
    victim.write_bytes(b"precious")
    out = tmp / "logs"
    out.mkdir()
    target = out / "session.jsonl"
    if kind == "symlink":
        target.symlink_to(victim)
    else:
        os.mkfifo(target)
    return f"""\
nodes:
  - name: reader
    type: synthetic_actor
    params: {{layout: kiip_full_body, rate_hz: 30.0, loop: true}}
  - name: rec
    type: topic_logger
    params: {{path: {target}, topics: [marker_layout]}}
    required: true
"""


def _file_params_graph(tmp: Path) -> str:
    """A graph whose solver's model file is a fifo and whose calibration's files are /dev/zero."""
    fifo = tmp / "model.json"
    os.mkfifo(fifo)
    return f"""\
nodes:
  - name: reader
    type: synthetic_actor
    params: {{layout: kiip_full_body, rate_hz: 30.0, loop: true}}
  - name: cal
    type: calibration
    params: {{model_file: /dev/zero, subject_file: /dev/zero}}
  - name: solver
    type: frame_solver
    params: {{model_file: {fifo}}}
"""


def _replay_graph(tmp: Path) -> str:
    """A bag holding ``save`` commands aimed outside, replayed by a bag player into a calibration."""
    from mocapgraph.bag.writer import BagWriter

    models, outside = tmp / "models", tmp / "outside"
    models.mkdir()
    outside.mkdir()
    model_file = models / "actor_model.json"
    _model_file(model_file)
    victim = outside / "victim.json"
    victim.write_text("precious\n")
    bag = tmp / "commands.mcap"
    targets = [str(victim), str(models / ".." / "outside" / "x.json"), "/dev/null"]
    with BagWriter(str(bag)) as w:
        for i, p in enumerate(targets * 3):
            w.write("calibration_command", NodeCommand(target="", command="save", args_json=json.dumps({"path": p})),
                    seq=i + 1, capture_ns=int((1 + i * 0.2) * 1e9))
    return f"""\
nodes:
  - name: reader
    type: synthetic_actor
    params: {{layout: kiip_full_body, rate_hz: 30.0, loop: true}}
  - name: cal
    type: calibration
    params: {{model_file: {model_file}}}
  - name: player
    type: bag_player
    params: {{file: {bag}, loop: true}}
  - name: logger
    type: topic_logger
    params: {{path: {tmp / "status.jsonl"}, topics: [calibration_status]}}
"""


@pytest.fixture(scope="module")
def graphs(launch_module_graph, tmp_path_factory) -> dict:
    """The graphs of the tests below (none judged on time), launched together: each spends seconds
    starting up, and each test looks at its own. name -> (graph, its folder)."""
    out = {}
    for name, make in (("symlink", lambda t: _refusing_graph(t, "symlink")),
                       ("fifo", lambda t: _refusing_graph(t, "fifo")),
                       ("file_params", _file_params_graph), ("replay", _replay_graph)):
        tmp = tmp_path_factory.mktemp(name)
        out[name] = launch_module_graph(make(tmp)), tmp
    return out


@pytest.mark.parametrize("kind", ["symlink", "fifo"])
def test_a_log_path_param_naming_a_symlink_elsewhere_or_a_fifo_is_refused_at_start(graphs, kind):
    g, tmp_path = graphs[kind]
    victim = tmp_path / "outside" / "victim.jsonl"
    t0 = time.monotonic()
    while g.proc.poll() is None and time.monotonic() - t0 < 60:
        time.sleep(0.1)
    assert g.proc.poll() not in (None, 0), g.output
    refusal = [line for line in g.lines if "[rec]" in line and ("outside the folders" in line or "a fifo" in line)]
    assert refusal, g.output
    assert "Traceback" not in g.output
    assert victim.read_bytes() == b"precious"


def test_file_params_naming_a_fifo_or_a_device_are_refused_not_waited_on(graphs, tmp_path):
    """A reader's capture, a solver's and a calibration's model file, a subject file: a fifo (whose
    open blocks for ever) or /dev/zero (endless) is refused in one line; the graph comes up."""
    capture = tmp_path / "take.c3d"
    os.mkfifo(capture)
    graph = tmp_path / "reader.yaml"
    graph.write_text(f"nodes:\n  - name: r\n    type: c3d_reader\n    params: {{file: {capture}}}\n")
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "mocapgraph", "graph", "check", str(graph)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode != 0 and "not a regular file" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    g, _ = graphs["file_params"]
    g.wait_ready(timeout=60)
    g.wait_for("[solver]", timeout=20)
    solver = [ln for ln in g.lines if ln.startswith("[solver]") and "ERROR" in ln]
    assert solver and "a fifo, not a regular file" in solver[0], g.output
    cal = g.wait_for("[cal] ERROR", timeout=20)
    assert "a character device, not a regular file" in cal, cal
    assert g.proc.poll() is None and "Traceback" not in g.output
    assert g.stop() == 0


def test_a_replayed_bag_of_save_commands_writes_nothing_outside(graphs):
    """A bag holding ``save`` commands aimed outside (a recording of an attack, or a forged bag),
    replayed by a real bag player into a real calibration node: every one refused and counted."""
    g, tmp_path = graphs["replay"]
    log, outside = tmp_path / "status.jsonl", tmp_path / "outside"
    victim = outside / "victim.json"
    g.wait_ready()
    wait_until(lambda: json.loads(_status(log).get("data_json") or "{}").get("commands_refused", 0) >= 12,
               timeout=60, what="the replayed saves refused", graph=g)
    assert victim.read_text() == "precious\n" and not (outside / "x.json").exists()
    assert "saved to" not in g.output and g.proc.poll() is None
    assert g.stop() == 0
