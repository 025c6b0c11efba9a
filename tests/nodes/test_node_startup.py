"""A node process imports only what its node uses: the runtime loading a node class in a fresh
interpreter leaves out the heavy packages that node never touches (scipy, numba, ezc3d, mujoco...),
and the lazy package names (``from mocapgraph.formats import read_bvh``) still resolve."""
from __future__ import annotations

import importlib
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

import mocapgraph.formats as formats
from mocapgraph.nodes.registry import NODE_TYPES

pytestmark = pytest.mark.slow  # one node process per node type

# Heavy packages: scipy.spatial ~0.3 s, numba ~0.25 s, mujoco ~0.2 s, ezc3d, networkx (the graph
# checker), asyncio (the ZAP thread of a secured graph; websockets nodes need it).
NOT_FOR_READERS = {"scipy", "numba", "ezc3d", "mujoco", "networkx", "asyncio", "mcap"}
NOT_FOR_OUTLETS = {"scipy", "numba", "ezc3d", "mujoco", "networkx"}

# node type -> packages its process must not have loaded once the runtime has its class
MUST_NOT_LOAD: dict[str, set[str]] = {
    **{t: NOT_FOR_READERS for t in ("c3d_reader", "trc_reader", "serial_reader", "udp_reader",
                                    "lsl_reader", "kinect_reader", "topic_logger", "marker_test_pattern",
                                    "qtm_reader", "natnet_reader")},
    "synthetic_actor": {"numba", "ezc3d", "mujoco", "networkx", "asyncio", "mocapgraph.kinematics.solving.solver"},
    # (their math comes when the node is built or calibrates: the launcher's check loads the class only)
    "calibration": {"scipy", "numba", "ezc3d", "mujoco", "networkx", "mocapgraph.kinematics.calibration.calibrate"},
    "frame_solver": {"scipy", "numba", "ezc3d", "mujoco", "networkx", "mocapgraph.kinematics.solving.solver"},
    "retargeter": {"scipy", "numba", "ezc3d", "mujoco", "networkx", "mocapgraph.retarget.retargeter"},
    "bvh_player": {"numba", "ezc3d", "mujoco", "networkx", "asyncio"},
    "bag_recorder": NOT_FOR_OUTLETS | {"asyncio"},
    "bag_player": NOT_FOR_OUTLETS | {"asyncio"},
    "visualizer": NOT_FOR_OUTLETS,
    "osc_outlet": NOT_FOR_OUTLETS | {"asyncio"},
    "vmc_outlet": NOT_FOR_OUTLETS | {"asyncio"},
    "lsl_outlet": NOT_FOR_OUTLETS | {"asyncio"},
    "foxglove_bridge": {"numba", "ezc3d", "mujoco", "networkx"},
}


def _loaded_after(code: str) -> set[str]:
    """Modules a fresh interpreter holds after running ``code``."""
    run = subprocess.run([sys.executable, "-c", code + "\nimport sys, json\nprint(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    return set(json.loads(run.stdout.splitlines()[-1]))


# One fresh interpreter imports what every node process imports first (the runtime), then forks a
# child per node type that loads the class as `runtime.load_class` does and reports sys.modules:
# the same as one interpreter per type, in a fraction of the time.
_PER_TYPE = """
import json, os, sys
from mocapgraph.bus.runtime import load_class
out = {}
for spec in SPECS:
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        try:
            load_class(spec)
            report = sorted(sys.modules)
        except BaseException as exc:
            report = {"error": f"{type(exc).__name__}: {exc}"}
        with os.fdopen(w, "w") as f:
            json.dump(report, f)
        os._exit(0)
    os.close(w)
    with os.fdopen(r) as f:
        out[spec] = json.load(f)
    os.waitpid(pid, 0)
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def loaded_by_type() -> dict[str, set[str]]:
    specs = [NODE_TYPES[t] for t in MUST_NOT_LOAD]
    run = subprocess.run([sys.executable, "-c", f"SPECS = {specs!r}\n" + _PER_TYPE],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout.splitlines()[-1])
    bad = {s: r["error"] for s, r in out.items() if isinstance(r, dict)}
    assert not bad, bad
    return {t: set(out[NODE_TYPES[t]]) for t in MUST_NOT_LOAD}


def _heavy(loaded: set[str], banned: set[str]) -> list[str]:
    return sorted(b for b in banned if b in loaded)


@pytest.mark.parametrize("node_type", sorted(MUST_NOT_LOAD))
def test_a_node_process_loads_only_what_its_node_uses(node_type, loaded_by_type):
    loaded = loaded_by_type[node_type]
    assert NODE_TYPES[node_type].partition(":")[0] in loaded
    assert not _heavy(loaded, MUST_NOT_LOAD[node_type]), (node_type, _heavy(loaded, MUST_NOT_LOAD[node_type]))


def test_the_heavy_nodes_do_load_their_math(loaded_by_type):
    """The check above sees real imports: the nodes that need scipy load it with their class."""
    assert "scipy" in loaded_by_type["synthetic_actor"] and "scipy" in loaded_by_type["bvh_player"]


def test_a_built_solver_node_has_its_solver_and_warm_kernels_before_any_frame():
    """What the frame solver's module leaves out, building the node (before it reports ready) loads:
    the solver, and every solver kernel module warmed (compiled code loaded, not compiled later)."""
    code = ("from mocapgraph.nodes.frame_solver import SOLVER_KERNELS, FrameSolverNode\n"
            "import sys, numba\n"
            "from mocapgraph import jit\n"
            "node = FrameSolverNode('solver', {'fit': 'global'})\n"
            "for name in SOLVER_KERNELS:\n"
            "    kernels = [k for k in vars(sys.modules[name]).values() if isinstance(k, numba.core.registry.CPUDispatcher)]\n"
            "    assert kernels and any(k.signatures for k in kernels), name\n"
            "assert not jit.runtime_compiles, jit.runtime_compiles\n"
            "assert node._new_solver.__module__ == 'mocapgraph.kinematics.solving.solver'")
    assert "mocapgraph.kinematics.solving.solver" in _loaded_after(code)


def test_a_built_calibration_node_has_its_math_before_the_gym_ends():
    """Processing races the stream: the calibration (scipy) and the solver it measures bone lengths
    with are loaded when the node is built, not when the gym capture ends."""
    loaded = _loaded_after("from mocapgraph.nodes.calibration import CalibrationNode\n"
                           "import sys\nassert 'scipy' not in sys.modules\n"
                           "CalibrationNode('calibration', {})")
    assert {"scipy", "mocapgraph.kinematics.calibration.calibrate", "mocapgraph.kinematics.solving.solver"} <= loaded


def test_the_launchers_check_of_a_lab_graph_loads_no_solver_math():
    """`mocapgraph launch` checks a graph against its node classes before starting anything: for a lab
    graph (reader, calibration, solver, viewer) that costs no scipy, numba or MuJoCo."""
    graph = Path(__file__).resolve().parents[2] / "graph_configs" / "lab_trc.yaml"
    loaded = _loaded_after("from mocapgraph.cli.graph_cmds import load_checked\n"
                           f"graph = load_checked({str(graph)!r}, [], check_files=False)\n"
                           "assert {n.spec.type for n in graph.nodes} >= {'calibration', 'frame_solver'}")
    assert not _heavy(loaded, {"scipy", "numba", "mujoco"})


def test_one_format_module_does_not_load_the_others():
    loaded = _loaded_after("import mocapgraph.formats.trc_file\nfrom mocapgraph.formats import FormatError, read_c3d")
    assert "mocapgraph.formats.c3d_file" in loaded
    others = {"mocapgraph.formats.bvh_file", "mocapgraph.formats.c3d_segments", "mocapgraph.formats.kinect_csv"}
    assert not _heavy(loaded, others | {"scipy", "ezc3d"})


def test_every_public_format_name_resolves_to_its_module():
    """Each name of ``__all__`` is the object its module defines (the lazy table names the right module)."""
    for name in formats.__all__:
        value = getattr(formats, name)
        where = formats._LAZY.get(name)
        if where is not None:
            assert value is getattr(importlib.import_module(f"mocapgraph.formats.{where}"), name), name
    assert set(formats._LAZY) <= set(formats.__all__)
    assert set(formats.__all__) <= set(dir(formats))
    # a lazy name that is also a submodule's would become the module once that one is imported
    assert not {n for n in formats._LAZY if importlib.util.find_spec(f"mocapgraph.formats.{n}")}
    with pytest.raises(AttributeError, match="no attribute 'read_nothing'"):
        formats.read_nothing  # noqa: B018
    star: dict = {}
    exec("from mocapgraph.formats import *", star)
    assert {n for n in star if not n.startswith("__")} == set(formats.__all__)


def test_a_turned_device_loads_scipy_with_its_config_not_on_a_frame():
    """scipy is imported by the node building a turned device's config, so no frame pays for it."""
    loaded = _loaded_after("from mocapgraph.formats.device_file import device_or_default\n"
                           "device_or_default('')\nimport sys\nassert 'scipy' not in sys.modules\n"
                           "d = device_or_default('example_serial_bridge')\nassert not d.is_identity")
    assert "scipy.spatial.transform" in loaded
