"""Wire protocols: encode/decode, and fuzzing with garbage and arbitrary chunking."""
from __future__ import annotations

import zlib

import numpy as np
import pytest

from mocapgraph.formats.wire_protocol import (MAGIC, BinaryDecoder, TextDecoder, encode_binary,
                                              encode_text, make_decoder)


def _frames(rng, n_frames, max_markers=12):
    out = []
    for k in range(n_frames):
        n = int(rng.integers(0, max_markers + 1))
        p = rng.uniform(-3, 3, size=(n, 3)).round(6)
        p[rng.random(n) < 0.2] = np.nan
        out.append((1000 + k, 5_000_000 + 8333 * k, p))
    return out


def _same(decoded, sent, atol):
    assert [d.frame for d in decoded] == [s[0] for s in sent]
    for d, (frame, t_us, p) in zip(decoded, sent):
        assert d.device_time_ns == t_us * 1000
        assert d.positions.shape == p.shape
        assert np.array_equal(np.isnan(d.positions), np.isnan(p))
        assert np.allclose(d.positions[~np.isnan(p)], p[~np.isnan(p)], atol=atol)


def test_text_line_layout():
    line = encode_text(7, 1234, np.array([[0.1, -0.02, 1.5], [np.nan] * 3]))
    body, crc = line[:-1].rsplit(b" *", 1)
    assert body == b"F 7 1234 2 100.000 -20.000 1500.000 nan nan nan"
    assert int(crc, 16) == zlib.crc32(body)
    assert encode_text(7, 1234, np.zeros((0, 3)), checksum=False) == b"F 7 1234 0\n"


def test_binary_layout():
    b = encode_binary(5, 99, np.array([[0.001, 0.002, 0.003]]))
    assert len(b) == 24 + 12 and b[:4] == MAGIC and b[4] == 1 and b[5] == 0
    assert int.from_bytes(b[6:8], "little") == 1 and int.from_bytes(b[8:12], "little") == 5
    assert int.from_bytes(b[12:20], "little") == 99
    assert np.allclose(np.frombuffer(b[20:32], "<f4"), [1, 2, 3])
    assert int.from_bytes(b[32:36], "little") == zlib.crc32(b[:32])


@pytest.mark.parametrize("protocol", ["text", "binary"])
def test_clean_stream_round_trip(protocol):
    rng = np.random.default_rng(0)
    sent = _frames(rng, 50)
    enc = encode_text if protocol == "text" else encode_binary
    dec = make_decoder(protocol)
    got = dec.feed(b"".join(enc(*s) for s in sent))
    _same(got, sent, 1e-6 if protocol == "text" else 1e-6 * 3)
    assert dec.stats.frames == 50 and dec.stats.rejected_bytes == 0
    assert dec.stats.rejected_frames == 0


def _garbage(rng, protocol):
    n = int(rng.integers(1, 60))
    g = rng.integers(0, 256, size=n, dtype=np.uint8).tobytes()
    if rng.random() < 0.3:  # things that look like a frame start
        if protocol == "text":
            g += b"F 12 x"
        else:  # a plausible header promising a few markers: it overlaps the next real frame
            g += MAGIC + bytes([1, 0, int(rng.integers(0, 5)), 0]) + bytes(5)
    if protocol == "text" and rng.random() < 0.3:
        g += b"\n"
    return g


@pytest.mark.parametrize("protocol", ["text", "binary"])
@pytest.mark.parametrize("seed", range(5))
def test_fuzz_garbage_and_chunks_recovers_every_frame(protocol, seed):
    rng = np.random.default_rng(seed)
    sent = _frames(rng, 120)
    enc = encode_text if protocol == "text" else encode_binary
    stream = bytearray()
    junk = 0
    for s in sent:
        if rng.random() < 0.5:
            g = _garbage(rng, protocol)
            junk += len(g)
            stream += g
        stream += enc(*s)
    if protocol == "text":
        stream += b"\n"  # end the last garbage-free line for sure
    dec = make_decoder(protocol)
    got = []
    i = 0
    while i < len(stream):  # arbitrary chunk sizes, 1 byte to 700
        n = int(rng.integers(1, 700))
        got += dec.feed(bytes(stream[i:i + n]))
        i += n
    got += dec.flush()
    _same(got, sent, 1e-6 if protocol == "text" else 3e-6)
    assert dec.stats.frames == len(sent)
    assert dec.stats.rejected_bytes > 0
    assert dec.stats.rejected_bytes <= junk + 1


@pytest.mark.parametrize("protocol", ["text", "binary"])
def test_pure_noise_never_raises(protocol):
    rng = np.random.default_rng(42)
    dec = make_decoder(protocol)
    total = 0
    for _ in range(200):
        chunk = rng.integers(0, 256, size=int(rng.integers(0, 2000)), dtype=np.uint8).tobytes()
        total += len(chunk)
        assert dec.feed(chunk) == []
    dec.flush()
    assert dec.stats.frames == 0
    assert dec.stats.rejected_bytes > 0.9 * total


def test_corrupted_frames_are_counted_and_neighbours_survive():
    rng = np.random.default_rng(3)
    sent = _frames(rng, 30, max_markers=4)
    for protocol, enc in (("binary", encode_binary), ("text", encode_text)):
        blobs = [bytearray(enc(*s)) for s in sent]
        bad = [5, 6, 20]
        for k in bad:
            pos = len(blobs[k]) // 2
            blobs[k][pos] ^= 0x10  # one flipped bit, in the payload
        dec = make_decoder(protocol)
        got = dec.feed(b"".join(bytes(b) for b in blobs))
        want = [s for k, s in enumerate(sent) if k not in bad]
        _same(got, want, 3e-6)
        assert dec.stats.crc_errors >= len(bad) or dec.stats.rejected_frames >= len(bad)


def test_text_comments_no_checksum_and_crlf():
    dec = TextDecoder()
    got = dec.feed(b"# device v1.2\r\nF 1 10 1 1 2 3\r\n\nF 2 20 1 nan NaN nan\n")
    assert [g.frame for g in got] == [1, 2] and dec.stats.comments == 1
    assert np.allclose(got[0].positions, [[0.001, 0.002, 0.003]])
    assert np.isnan(got[1].positions).all()
    bad = dec.feed(b"F 3 30 2 1 2 3\nF 4 40 1 1 2 inf\nF 5 -1 0\n")
    assert bad == [] and dec.stats.rejected_frames == 3


def test_binary_header_claiming_huge_frame_does_not_swallow_the_next():
    good = encode_binary(9, 1, np.ones((2, 3)))
    fake = MAGIC + bytes([1, 0]) + (4000).to_bytes(2, "little") + bytes(12)  # promises 48 kB
    dec = BinaryDecoder()
    assert dec.feed(fake + good) == []  # still waiting for the fake frame's bytes
    got = dec.feed(bytes(48_100))  # zeros complete the fake frame: CRC fails, resync
    assert [g.frame for g in got] == [9] and dec.stats.crc_errors == 1


def test_encoders_reject_bad_input():
    with pytest.raises(ValueError):
        encode_binary(1, 1, np.full((1, 3), np.inf))
    with pytest.raises(ValueError):
        encode_text(-1, 1, np.zeros((1, 3)))
    with pytest.raises(ValueError):
        make_decoder("morse")
