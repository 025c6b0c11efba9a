"""Bad input as a new user would try it: each gets one clear line, exit code 2, no traceback."""
from __future__ import annotations

import struct
import subprocess
import sys

import pytest

from bagutil import frame, write_bag
from mocapgraph.bag.writer import BagWriter
from mocapgraph.messages import encode
from mocapgraph.messages.codec import HEADER


def cli(*args: str, timeout: float = 30) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mocapgraph", "bag", *args], capture_output=True, text=True,
                          timeout=timeout)


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
    assert_clear(cli(command, str(junk)), "notes.mcap", "not an MCAP file")
    assert_clear(cli(command, str(empty)), "empty file")
    assert_clear(cli(command, str(tmp_path / "nope.mcap")), "no such file")
    assert_clear(cli(command, str(trc)), "looks like TRC", "bag convert")


def test_truncated_bag_says_how_to_recover(tmp_path):
    path = write_bag(tmp_path / "a.mcap", frames=200, chunk_kb=16)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:5000])
    for args in (["info", str(cut)], ["play", str(cut)], ["convert", str(cut), "-o", str(tmp_path / "o.trc")]):
        assert_clear(cli(*args), "truncated or unfinished", f"mocapgraph bag recover {cut}")
    assert_clear(cli("recover", str(tmp_path / "empty.mcap")), "no such file")


def test_topics_of_unknown_type_or_schema_version(tmp_path):
    path = tmp_path / "future.mcap"
    with BagWriter(path) as w:
        for i in range(5):
            t = 10**9 + i * 10**7
            w.write_frames(encode("markers", frame(i), i + 1, t, "src", t), t)
            w.write_frames(renamed(encode("gaze", frame(i), i + 1, t, "eye", t), "GazeRay", 1), t)
            w.write_frames(renamed(encode("markers2", frame(i), i + 1, t, "src", t), "MarkerFrame", 2), t)
    r = cli("info", str(path))
    assert r.returncode == 0, r.stderr
    gaze = next(line for line in r.stdout.splitlines() if line.strip().startswith("gaze"))
    assert "GazeRay" in gaze and "unknown to this mocapgraph version" in gaze
    m2 = next(line for line in r.stdout.splitlines() if line.strip().startswith("markers2"))
    assert "schema version 2 in the bag, this mocapgraph knows version 1" in m2
    # play names what it skips and why, then plays the rest
    r = cli("play", str(path), "--no-wait", "--no-manifest", "--rate", "10")
    assert r.returncode == 0, r.stderr
    assert "not playing gaze: type 'GazeRay' is unknown" in r.stdout
    assert "played 5 messages" in r.stdout
    # asking for it explicitly is a clear error
    assert_clear(cli("play", str(path), "--topics", "gaze"), "gaze", "unknown to this mocapgraph version")
    assert_clear(cli("convert", str(path), "-o", str(tmp_path / "g.csv"), "--topic", "gaze"), "GazeRay")
    # the stored schema record still describes it for other tools
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        names = {s.name for s in make_reader(f).get_summary().schemas.values()}
    assert names == {"MarkerFrame", "GazeRay"}


def test_convert_bad_arguments(tmp_path, shared_data):
    bvh = shared_data / "bvh" / "mixamo" / "test_freebvh.bvh"
    assert_clear(cli("convert", str(bvh), "-o", str(tmp_path / "x.trc")), "one side of a conversion is a bag")
    assert_clear(cli("convert", str(tmp_path / "x.xyz"), "-o", str(tmp_path / "x.mcap")), "converts into a bag from")
    broken = shared_data / "c3d" / "btkdata" / "mocap36.c3d"
    assert_clear(cli("convert", str(broken), "-o", str(tmp_path / "m.mcap")), "mocap36.c3d")
    kin = sorted((shared_data / "kinect2").glob("*.csv"))[0]
    assert cli("convert", str(kin), "-o", str(tmp_path / "k.mcap")).returncode == 0
    assert_clear(cli("convert", str(tmp_path / "k.mcap"), "-o", str(tmp_path / "k.bvh")),
                 "orientations are missing", "Kinect")
    assert_clear(cli("convert", str(tmp_path / "k.mcap"), "-o", str(tmp_path / "k.trc")), "has no MarkerFrame topic")
