"""``bag recover`` on damaged bags (issue 30 item 9), run as the user runs it (the CLI as a
subprocess), with the truth taken from the undamaged bag through the stock ``mcap`` library:
one bad byte in the first chunk (where the recorder wrote every channel record), ten flipped
bytes, and a one-chunk bag from ``bag convert`` cut inside its chunk."""
from __future__ import annotations

import io
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader

from lab_fixtures import PERSON_LABELS, person_frames, write_points_c3d
from mocapgraph.bag.reader import BagReader
from mocapgraph.bag.writer import BagWriter
from mocapgraph.messages import MarkerFrame, MarkerLayout

TOPICS = [f"markers_{k}" for k in range(16)]


def busy_bag(path: Path, frames: int = 360) -> Path:
    """17 channels (a latched layout + 16 marker streams), a chunk closed every 9 frames: 40 chunks."""
    lay = MarkerLayout(name="t", labels=[f"M{k}" for k in range(6)], limb_names=[],
                       marker_limb=np.full(6, -1), units_note="", unplaced=[], source="test")
    with BagWriter(path, chunk_kb=4096) as w:
        w.write("marker_layout", lay, seq=1, capture_ns=10**9)
        for i in range(frames):
            t = 10**9 + i * 10**7
            for k, topic in enumerate(TOPICS):
                pos = np.arange(18, dtype=float).reshape(6, 3) * (k + 1) + i
                w.write(topic, MarkerFrame(frame_number=i, rate_hz=100.0, positions=pos, valid=np.ones(6, bool),
                                           residual=np.zeros(6, np.float32)), seq=i + 1, capture_ns=t)
            if i % 9 == 8:
                w.flush()
    return path


def chunks_of(path: Path) -> list[tuple[int, int, set]]:
    """(start byte, end byte, {(channel id, sequence, log time)}) per chunk, by the stock mcap reader."""
    data = path.read_bytes()
    with open(path, "rb") as f:
        idx = make_reader(f).get_summary().chunk_indexes
    out = []
    for ci in idx:
        raw = data[ci.chunk_start_offset:ci.chunk_start_offset + ci.chunk_length]
        keys = set()
        try:
            for r in StreamReader(io.BytesIO(raw), skip_magic=True).records:
                if isinstance(r, Message):
                    keys.add((r.channel_id, r.sequence, r.log_time))
        except EndOfFile:  # the stream ends after the chunk record
            pass
        out.append((ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length, keys))
    return out


def recover_cli(src: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mocapgraph", "bag", "recover", str(src), "-o", str(out)],
                          capture_output=True, text=True, timeout=120)


def saved_keys(path: Path) -> set:
    """{(topic, sequence, log time)} in a recovered bag (read by the stock reader)."""
    with open(path, "rb") as f:
        return {(ch.topic, m.sequence, m.log_time) for _, ch, m in make_reader(f).iter_messages()}


def topic_keys(path: Path, keys: set) -> set:
    with open(path, "rb") as f:
        chans = {c.id: c.topic for c in make_reader(f).get_summary().channels.values()}
    return {(chans[c], s, t) for c, s, t in keys}


def test_one_bad_byte_in_the_first_chunk_loses_only_that_chunk(tmp_path: Path) -> None:
    src = busy_bag(tmp_path / "busy.mcap")
    chunks = chunks_of(src)
    assert len(chunks) == 40
    data = bytearray(src.read_bytes())
    a, b, first = chunks[0]
    data[(a + b) // 2] ^= 0x5A
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    r = recover_cli(bad, tmp_path / "saved.mcap")
    assert r.returncode == 0, r.stderr
    everything = set().union(*(k for _, _, k in chunks))
    want = topic_keys(src, everything - first)
    assert saved_keys(tmp_path / "saved.mcap") == want        # every message of the 39 intact chunks
    assert f"saved {len(want)} messages" in r.stdout
    assert f"lost: {len(first)} messages (counted from the bag's own index)" in r.stdout
    with BagReader(tmp_path / "saved.mcap") as rb:
        assert sorted(rb.topic_infos()) == sorted(TOPICS)      # channels from the summary: all 16 streams
    assert "  lost marker_layout: 1" in r.stdout               # the latched layout was in that chunk
    assert f"  lost markers_3: {len(first) // 16}" in r.stdout


def test_ten_flipped_bytes_lose_only_the_chunks_they_hit(tmp_path: Path) -> None:
    src = busy_bag(tmp_path / "busy.mcap")
    chunks = chunks_of(src)
    data = bytearray(src.read_bytes())
    rng = random.Random(30)
    a0, b0, _ = chunks[0]
    spots = [rng.randrange(a0 + 9, b0)] + [rng.randrange(8, len(data) - 8) for _ in range(9)]
    for s in spots:
        data[s] ^= 1 << rng.randrange(8)
    bad = tmp_path / "flipped.mcap"
    bad.write_bytes(bytes(data))
    hit = [k for a, b, k in chunks if any(a <= s < b for s in spots)]
    intact = [k for a, b, k in chunks if not any(a <= s < b for s in spots)]
    assert len(intact) >= 30 and hit
    r = recover_cli(bad, tmp_path / "saved.mcap")
    assert r.returncode == 0, r.stderr
    got = saved_keys(tmp_path / "saved.mcap")
    assert got >= topic_keys(src, set().union(*intact))        # nothing of an intact chunk is lost
    lost_true = sum(len(k) for k in hit)
    assert len(got) == sum(len(k) for k in intact)             # and nothing from a damaged one is made up
    line = next(ln for ln in r.stdout.splitlines() if ln.startswith("lost:"))
    n = int(line.split()[2] if "about" in line else line.split()[1])
    if "counted" in line:
        assert n == lost_true
    else:
        assert abs(n - lost_true) <= 0.3 * lost_true


def test_a_converted_short_trial_cut_inside_its_only_chunk_keeps_its_front(tmp_path: Path) -> None:
    truth = person_frames(600)
    c3d = write_points_c3d(tmp_path / "short.c3d", PERSON_LABELS, truth, y_screen="+Z")
    bag = tmp_path / "short.mcap"
    conv = subprocess.run([sys.executable, "-m", "mocapgraph", "bag", "convert", str(c3d), "-o", str(bag)],
                          capture_output=True, text=True, timeout=120)
    assert conv.returncode == 0, conv.stderr
    assert len(chunks_of(bag)) == 1                            # what bag convert writes: one lz4 chunk
    data = bag.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    r = recover_cli(cut, tmp_path / "saved.mcap")
    assert r.returncode == 0, r.stderr
    with BagReader(tmp_path / "saved.mcap") as rb:
        frames = [m for _, m in rb.decoded("markers")]
        layouts = [m for _, m in rb.decoded("marker_layout")]
    assert layouts and layouts[0].labels == list(PERSON_LABELS)
    n = len(frames)
    assert 100 < n < 600
    assert [f.frame_number for f in frames] == list(range(1, n + 1))   # a clean front, in order
    np.testing.assert_allclose(np.stack([f.positions for f in frames]), truth[:n], atol=1e-9)
    line = next(ln for ln in r.stdout.splitlines() if ln.startswith("lost:"))
    est = int(line.split()[2])
    assert "about" in line and abs(est - (600 - n)) <= 0.2 * (600 - n)
