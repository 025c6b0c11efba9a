"""Bad input as a new user would try it: each gets one clear line, exit code 2, no traceback."""
from __future__ import annotations

import struct
import subprocess
import sys

import pytest

from bagutil import frame, write_bag
from graph_helpers import run_concurrently
from mocapgraph.bag.writer import BagWriter
from mocapgraph.messages import encode
from mocapgraph.messages.codec import HEADER

pytestmark = pytest.mark.slow  # each case runs the bag CLI as a process


def clis(*arg_lists: list[str], timeout: float = 30) -> list[subprocess.CompletedProcess]:
    """Several independent `mocapgraph bag` calls run at once (their start-ups share the cores), in order."""
    return run_concurrently([[sys.executable, "-m", "mocapgraph", "bag", *a] for a in arg_lists], timeout)


def renamed(frames: list, type_name: str, version: int) -> list:
    """The same message claiming another type name / schema version (as a newer build would send)."""
    head = bytes(frames[1])
    fields = list(HEADER.unpack_from(head))
    sender = head[HEADER.size + fields[4]:]
    fields[3], fields[4] = version, len(type_name)
    return [frames[0], HEADER.pack(*fields) + type_name.encode() + sender, *frames[2:]]


def assert_clear(r: subprocess.CompletedProcess, *needles: str) -> None:
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr
    line = r.stderr.strip()
    assert line.count("\n") == 0, line
    for n in needles:
        assert n in line, line


@pytest.mark.parametrize("command", ["info", "play"])
def test_not_mcap_empty_missing(tmp_path, command):
    junk = tmp_path / "notes.mcap"
    junk.write_text("just some text\n")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    trc = tmp_path / "walk.trc"
    trc.write_text("PathFileType\t4\t(X/Y/Z)\twalk.trc\n")
    r_junk, r_empty, r_missing, r_trc = clis([command, str(junk)], [command, str(empty)],
                                             [command, str(tmp_path / "nope.mcap")], [command, str(trc)])
    assert_clear(r_junk, "notes.mcap", "not an MCAP file")
    assert_clear(r_empty, "empty file")
    assert_clear(r_missing, "no such file")
    assert_clear(r_trc, "looks like TRC", "bag convert")


def test_truncated_bag_says_how_to_recover(tmp_path):
    path = write_bag(tmp_path / "a.mcap", frames=200, chunk_kb=16)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:5000])
    *cut_runs, r_missing = clis(["info", str(cut)], ["play", str(cut)],
                                ["convert", str(cut), "-o", str(tmp_path / "o.trc")],
                                ["recover", str(tmp_path / "empty.mcap")])
    for r in cut_runs:
        assert_clear(r, "truncated or unfinished", f"mocapgraph bag recover {cut}")
    assert_clear(r_missing, "no such file")


def test_topics_of_unknown_type_or_schema_version(tmp_path):
    path = tmp_path / "future.mcap"
    with BagWriter(path) as w:
        for i in range(5):
            t = 10**9 + i * 10**7
            w.write_frames(encode("markers", frame(i), i + 1, t, "src", t), t)
            w.write_frames(renamed(encode("gaze", frame(i), i + 1, t, "eye", t), "GazeRay", 1), t)
            w.write_frames(renamed(encode("markers2", frame(i), i + 1, t, "src", t), "MarkerFrame", 2), t)
    r, r_play, r_asked, r_convert = clis(["info", str(path)],
                                         ["play", str(path), "--no-wait", "--no-manifest", "--rate", "10"],
                                         ["play", str(path), "--topics", "gaze"],
                                         ["convert", str(path), "-o", str(tmp_path / "g.csv"), "--topic", "gaze"])
    assert r.returncode == 0, r.stderr
    gaze = next(line for line in r.stdout.splitlines() if line.strip().startswith("gaze"))
    assert "GazeRay" in gaze and "unknown to this mocapgraph version" in gaze
    m2 = next(line for line in r.stdout.splitlines() if line.strip().startswith("markers2"))
    assert "schema version 2 in the bag, this mocapgraph knows version 1" in m2
    # play names what it skips and why, then plays the rest
    r = r_play
    assert r.returncode == 0, r.stderr
    assert "not playing gaze: type 'GazeRay' is unknown" in r.stdout
    assert "played 5 messages" in r.stdout
    # asking for it explicitly is a clear error
    assert_clear(r_asked, "gaze", "unknown to this mocapgraph version")
    assert_clear(r_convert, "GazeRay")
    # the stored schema record still describes it for other tools
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        names = {s.name for s in make_reader(f).get_summary().schemas.values()}
    assert names == {"MarkerFrame", "GazeRay"}


def test_convert_bad_arguments(tmp_path, shared_data):
    bvh = shared_data / "bvh" / "mixamo" / "test_freebvh.bvh"
    broken = shared_data / "c3d" / "btkdata" / "mocap36.c3d"
    kin = sorted((shared_data / "kinect2").glob("*.csv"))[0]
    r_bvh, r_xyz, r_broken, r_kin = clis(["convert", str(bvh), "-o", str(tmp_path / "x.trc")],
                                         ["convert", str(tmp_path / "x.xyz"), "-o", str(tmp_path / "x.mcap")],
                                         ["convert", str(broken), "-o", str(tmp_path / "m.mcap")],
                                         ["convert", str(kin), "-o", str(tmp_path / "k.mcap")])
    assert_clear(r_bvh, "one side of a conversion is a bag")
    assert_clear(r_xyz, "converts into a bag from")
    assert_clear(r_broken, "mocap36.c3d")
    assert r_kin.returncode == 0
    # these two read the bag just written
    r_kbvh, r_ktrc = clis(["convert", str(tmp_path / "k.mcap"), "-o", str(tmp_path / "k.bvh")],
                          ["convert", str(tmp_path / "k.mcap"), "-o", str(tmp_path / "k.trc")])
    assert_clear(r_kbvh, "orientations are missing", "Kinect")
    assert_clear(r_ktrc, "has no MarkerFrame topic")
