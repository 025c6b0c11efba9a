"""Writer, reader, recorder and recovery on synthetic bags; interop with the stock mcap reader."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from mcap.reader import make_reader

from bagutil import frame, layout, write_bag
from mocapgraph.bag.errors import BagError
from mocapgraph.bag.framing import MESSAGE_ENCODING, pack_frames, unpack_frames
from mocapgraph.bag.reader import BagReader
from mocapgraph.bag.recorder import Recorder
from mocapgraph.bag.recover import recover
from mocapgraph.bag.writer import BagWriter
from mocapgraph.messages import MarkerFrame, decode, encode
from mocapgraph.messages.codec import HEADER


def test_framing_round_trip_is_byte_exact():
    frames = encode("markers", frame(3), 7, 123, "src", 456)
    data = pack_frames(frames)
    n = int.from_bytes(data[:4], "little")
    assert n == len(frames) - 1
    back = unpack_frames(data, b"markers\0")
    assert [bytes(f) for f in back] == [bytes(f) for f in frames]
    with pytest.raises(BagError, match="frame lengths"):
        unpack_frames(data[:-1])


def test_stock_mcap_reader_lists_our_schemas_and_reads_messages(tmp_path):
    path = write_bag(tmp_path / "a.mcap", frames=20)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == {"MarkerFrame", "MarkerLayout"}
        for s in schemas.values():
            assert s.encoding == "jsonschema"
            js = json.loads(s.data)
            assert js["title"] == s.name and "properties" in js
        assert json.loads(schemas["MarkerFrame"].data)["properties"]["positions"]["x-dtype"] == "float64"
        chans = {c.topic: c for c in summary.channels.values()}
        assert chans["markers"].message_encoding == MESSAGE_ENCODING
        assert chans["marker_layout"].metadata["latched"] == "true"
        msgs = [(c.topic, m) for _, c, m in reader.iter_messages()]
    assert len(msgs) == 21
    topic, m = msgs[5]
    env, msg = decode(unpack_frames(m.data, topic.encode() + b"\0"))
    assert msg == frame(4) and env.seq == 5 and m.publish_time == env.publish_ns


def test_summary_counts_rates_and_losses(tmp_path):
    path = tmp_path / "a.mcap"
    with BagWriter(path) as w:
        rec = Recorder(w)
        for seq in [1, 2, 3, 6, 6, 7, 1, 2]:  # 2 lost, a repeat, then the sender restarted
            t = 10**9 + seq * 10**7
            rec.receive(encode("markers", frame(seq), seq, t, "src", t), log_ns=t)
        assert rec.lost == {"markers": 2} and rec.duplicates == 1 and rec.restarts == 1
        rec.close()
    with BagReader(path) as r:
        s = r.summary()
        assert s.count == 7 and s.losses == {"markers": 2}
        scan = r.scan()
        assert scan.seq_gaps == {"markers": 2}
        assert s.topics["markers"].type_name == "MarkerFrame" and s.topics["markers"].known


def test_split_files_are_each_complete(tmp_path):
    base = tmp_path / "s.mcap"
    with BagWriter(base, split_s=0.1) as w:
        w.write("marker_layout", layout(), seq=1, capture_ns=10**9)
        for i in range(30):
            w.write("markers", frame(i), seq=i + 1, capture_ns=10**9 + i * 10**7)
    paths = w.paths
    assert [p.name for p in paths] == ["s_000.mcap", "s_001.mcap", "s_002.mcap"]
    total = 0
    for p in paths:
        with BagReader(p) as r:
            topics = r.topic_infos()
            assert topics["marker_layout"].count == 1  # latched state repeated in every split
            total += topics["markers"].count
    assert total == 30


def test_recover_truncated_bag_keeps_whole_chunks(tmp_path):
    path = tmp_path / "a.mcap"
    with BagWriter(path, chunk_kb=16) as w:
        w.write("marker_layout", layout(), seq=1, capture_ns=10**9)
        for i in range(400):
            w.write("markers", frame(i, 32), seq=i + 1, capture_ns=10**9 + i * 10**7)
            if i % 50 == 49:
                w.flush()
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    with pytest.raises(BagError, match="truncated or unfinished.*bag recover") as err:
        BagReader(cut)
    assert err.value.damaged
    rep = recover(cut)
    assert not rep.was_complete and rep.chunks_bad == 1
    with BagReader(rep.output) as r:
        got = [m for _, m in r.decoded("markers")]
        assert r.summary().metadata["mocapgraph.recovery"]["saved"] == str(rep.saved)
    nums = [m.frame_number for m in got]
    assert nums == list(range(len(nums)))  # a clean prefix, nothing skipped
    assert rep.saved == len(got) + 1
    assert 100 < len(got) < 400
    assert got[10] == frame(10, 32)
    # the estimate of what the partial chunk held is of the right size
    assert 0 < rep.lost_estimate < 400 - len(got) + 20
    # a complete bag recovers to itself
    rep2 = recover(path, tmp_path / "whole.mcap")
    assert rep2.was_complete and rep2.saved == 401


def test_recover_via_cli_prints_counts(tmp_path):
    path = write_bag(tmp_path / "a.mcap", frames=100, chunk_kb=16)
    data = path.read_bytes()
    (tmp_path / "t.mcap").write_bytes(data[: len(data) - 200])
    r = subprocess.run([sys.executable, "-m", "mocapgraph", "bag", "recover", str(tmp_path / "t.mcap")],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    assert "saved 101 messages" in r.stdout and "t.recovered.mcap" in r.stdout


def test_existing_bag_is_never_destroyed_by_a_respawned_recorder(tmp_path):
    first = write_bag(tmp_path / "r.mcap", frames=3)
    w = BagWriter(first, on_exists="rename")
    assert w.paths == [tmp_path / "r_1.mcap"]
    w.close()
    with pytest.raises(BagError, match="already exists"):
        BagWriter(first, on_exists="error")
    with BagReader(first) as r:
        assert r.summary().count == 4


def test_recover_skips_a_damaged_region_in_the_middle(tmp_path):
    path = write_bag(tmp_path / "c.mcap", frames=2000, chunk_kb=16)
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 3000] = bytes(b ^ 0x5A for b in data[mid:mid + 3000])
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with BagReader(bad) as r:  # the index is intact, the data is not
        with pytest.raises(BagError, match="damaged data.*bag recover"):
            list(r.messages())
    rep = recover(bad)
    with BagReader(rep.output) as r:
        nums = np.array([m.frame_number for _, m in r.decoded("markers")])
    assert rep.chunks_bad >= 1 and not rep.was_complete
    assert len(nums) > 1800 and np.all(np.diff(nums) > 0)  # chunks after the damage are saved too
    assert nums[-1] == 1999 and np.count_nonzero(np.diff(nums) > 1) == 1
