"""NaN or inf in a device file fails ``graph check`` with the device file's line (issue 30, item 8).

Before, ``yaw_deg: .nan`` or ``translation_m: [.inf, 0, 0]`` passed the check and the reader
published markers that were all NaN (or infinitely far) with no word. The real CLI checks a
graph of each device reader against each bad file.
"""
from __future__ import annotations

import subprocess
import sys

import pytest

BAD = {  # key -> (device file text, the line holding the fault)
    "rate_hz": ("name: probe\nrate_hz: .nan\n", 2),
    "rate_hz_inf": ("name: probe\nrate_hz: .inf\n", 2),
    "to_world.yaw_deg": ("name: probe\nto_world:\n  up: '+Y'\n  yaw_deg: .nan\n", 4),
    "to_world.yaw_deg_inf": ("name: probe\nto_world:\n  yaw_deg: -.inf\n", 3),
    "to_world.translation_m": ("name: probe\nto_world:\n  up: '+Z'\n  translation_m: [.inf, 0, 0]\n", 4),
    "to_world.translation_m_nan": ("name: probe\nto_world:\n  translation_m: [0, .NaN, 0]\n", 3),
}
READERS = {"udp_reader": "port: 9871", "serial_reader": "port: /dev/ttyUSB9", "lsl_reader": "stream_name: x"}


@pytest.mark.parametrize("reader", sorted(READERS))
def test_graph_check_refuses_nan_and_inf_in_a_device_file(tmp_path, reader):
    procs = {}
    for key, (text, line) in BAD.items():
        dev = tmp_path / f"{key}.yaml"
        dev.write_text(text)
        graph = tmp_path / f"graph_{key}.yaml"
        graph.write_text(f"nodes:\n  - name: reader\n    type: {reader}\n"
                         f"    params: {{{READERS[reader]}, device: {dev}}}\n")
        procs[key] = subprocess.Popen([sys.executable, "-m", "mocapgraph", "graph", "check", str(graph)],
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for key, p in procs.items():
        out, err = p.communicate(timeout=120)
        lines = [ln for ln in err.splitlines() if ln.strip()]
        text, line = BAD[key]
        assert p.returncode != 0, (key, out, err)
        assert len(lines) == 1 and "Traceback" not in err, err
        want = key.removesuffix("_inf").removesuffix("_nan")
        assert f"{tmp_path / key}.yaml:{line}: {want}:" in lines[0], lines[0]
        assert "finite" in lines[0] and f"graph_{key}.yaml:4: nodes[reader].params.device" in lines[0], lines[0]


def test_the_shipped_device_files_still_pass(tmp_path):
    from mocapgraph.formats.device_file import DEVICE_DIR, load_device_config

    files = sorted(DEVICE_DIR.glob("*.yaml"))
    assert files
    for f in files:
        load_device_config(f)
