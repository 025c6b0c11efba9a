"""Bags with real graphs: record -> replay round trip (bytes, sequence, timing), a recorder killed
with SIGKILL then recovered, and the player node driven by NodeCommand messages."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
import zmq

from bagutil import write_bag
from graph_helpers import run_concurrently
from mocapgraph.bag.reader import BagReader
from mocapgraph.bag.recover import recover
from mocapgraph.launch.check import check_graph
from mocapgraph.launch.graph import load_graph
from mocapgraph.bus.manifest import fetch_manifest, subscribe
from mocapgraph.formats.yaml_source import GraphError
from mocapgraph.messages import NodeCommand, decode, decode_envelope, encode
from mocapgraph.messages.codec import topic_frame
from mocapgraph.testing.marker_pattern import pattern_positions

pytestmark = pytest.mark.slow  # live recording and playback processes

N_MARKERS = 64
RATE = 240.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def play_into_subscriber(bag, *args: str, topics=("markers", "marker_layout"), timeout=30.0):
    """Run `bag play` and collect (arrival ns, frames) with a fresh SUB socket."""
    ep = f"tcp://127.0.0.1:{free_port()}"
    ctx = zmq.Context.instance()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.setsockopt(zmq.LINGER, 0)
    for t in topics:
        sub.setsockopt(zmq.SUBSCRIBE, topic_frame(t))
    sub.connect(ep)
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "bag", "play", str(bag), "--bind", ep,
                             "--no-manifest", "-q", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    got = []
    t_end = time.monotonic() + timeout
    try:
        while time.monotonic() < t_end:
            if sub.poll(50):
                while True:
                    try:
                        frames = sub.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    got.append((time.time_ns(), frames))
            elif proc.poll() is not None:
                break
        out, err = proc.communicate(timeout=5)
    finally:
        if proc.poll() is None:
            proc.kill()
        sub.close(0)
    assert proc.returncode == 0, err
    return got, out


def timing_errors_ms(replayed_ns, recorded_ns, rate):
    """Lateness of each message against its recorded offset / rate, ms. The schedule's origin is the
    least late message (the player never sends early), so one late first message cannot skew it."""
    rep = np.asarray(replayed_ns, np.int64)
    rec = np.asarray(recorded_ns, np.int64)
    d = ((rep - rep[0]) - (rec - rec[0]) / rate) / 1e6
    return d - d.min()


@pytest.mark.timing
def test_record_then_replay_round_trip(tmp_path, launch_graph):
    bag = tmp_path / "session.mcap"
    g = launch_graph(f"""
nodes:
  - name: src
    type: marker_test_pattern
    params: {{rate_hz: {RATE}, n_markers: {N_MARKERS}, count: 240, missing_every: 7}}
  - name: rec
    type: bag_recorder
    params: {{path: "{bag}", topics: [markers, marker_layout]}}
""")
    g.wait_ready()
    g.wait_for("node src exited")
    assert g.stop() == 0
    with BagReader(bag) as r:
        stored = {t: [raw for raw in r.messages([t])] for t in ("markers", "marker_layout")}
        meta = r.summary().metadata["mocapgraph"]
        assert r.summary().losses == {}
    assert meta["writer"] == "bag_recorder node" and meta["graph"].endswith("graph_0.yaml")
    assert len(stored["markers"]) == 240 and len(stored["marker_layout"]) == 1
    recorded = [raw.frames() for raw in stored["markers"]]
    recorded_pub = [raw.publish_ns for raw in stored["markers"]]

    for rate in (1.0, 4.0):
        # exactness is checked on every replay; timing on a shared 2-core machine (other suites
        # running) may suffer one preemption, so a second replay may stand in for the first
        verdicts = []
        for _attempt in range(2):
            verdicts.append(replay_and_check(bag, rate, recorded, recorded_pub))
            if verdicts[-1] is None:
                break
        assert verdicts[-1] is None, verdicts


# The machine's own wake-up lateness, measured beside each replay: a process sleeping to deadlines
# at the recorded 240 Hz (the player waits the same way: poll, then sleep the rest). Not at the
# replay's cadence: at 4x (1 ms) such a process hardly sleeps, so it measures a busy loop's luck,
# while the player, which does work for every message, is preempted like any busy process.
PACER = """
import json, sys, time
period, seconds = float(sys.argv[1]), float(sys.argv[2])
t0 = time.monotonic() + 0.02
late = []
for k in range(int(seconds / period)):
    due = t0 + k * period
    while (wait := due - time.monotonic()) > 0:
        time.sleep(wait)
    late.append((time.monotonic() - due) * 1e3)
print(json.dumps(late))
"""


def baseline_lateness_ms(period_s: float, seconds: float) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", PACER, str(period_s), str(seconds)], stdout=subprocess.PIPE,
                            text=True)


def replay_and_check(bag, rate, recorded, recorded_pub) -> str | None:
    """Replay at ``rate``; asserts exact bytes and order, returns what was wrong with the timing (None: ok)."""
    pacer = baseline_lateness_ms(1 / RATE, 1.0 / rate + 0.5)
    got, out = play_into_subscriber(bag, "--rate", str(rate))
    base = np.array(json.loads(pacer.communicate(timeout=30)[0]))
    markers = [(t, f) for t, f in got if bytes(f[0]) == b"markers\0"]
    layouts = [f for _, f in got if bytes(f[0]) == b"marker_layout\0"]
    assert len(layouts) == 1 and len(markers) == 240
    assert "played 241 messages" in out
    envs = [decode_envelope(f) for _, f in markers]
    assert [e.seq for e in envs] == list(range(1, 241))  # original sequence numbers, in order
    for (_, f), rec in zip(markers, recorded):
        # identical bytes: every frame but the header's publish stamp (bytes 26..34)
        assert bytes(f[0]) == bytes(rec[0])
        assert bytes(f[1][:26]) == bytes(rec[1][:26]) and bytes(f[1][34:]) == bytes(rec[1][34:])
        assert [bytes(x) for x in f[2:]] == [bytes(x) for x in rec[2:]]
    env, msg = decode(markers[7][1])  # and the values are the pattern's own
    expect = pattern_positions(7, N_MARKERS, RATE)
    expect[0] = np.nan
    assert np.array_equal(msg.positions, expect, equal_nan=True) and not msg.valid[0]
    # timing: each message at its recorded offset scaled by the rate (so proportional)
    sent_err = timing_errors_ms([e.publish_ns for e in envs], recorded_pub, rate)
    arrive_err = timing_errors_ms([t for t, _ in markers], recorded_pub, rate)
    b50, b90 = np.percentile(base, [50, 90])
    half = len(sent_err) // 2
    drift = abs(np.median(sent_err[half:]) - np.median(sent_err[:half]))  # a wrong rate drifts
    text = (f"rate {rate}: send lateness p50 {np.median(sent_err):.3f} ms, p90 {np.percentile(sent_err, 90):.3f} "
            f"ms, max {sent_err.max():.3f} ms, drift {drift:.3f} ms; arrival p50 {np.median(arrive_err):.3f} ms; "
            f"machine baseline (a process sleeping to 240 Hz deadlines) p50 {b50:.3f} ms, p90 {b90:.3f} ms")
    print(text)
    # On a quiet machine the player's p90 is ~0.3 ms and the baseline's ~0.1 ms (benchmarks/bags.py);
    # with four busy loops on the two cores the baseline's p90 reaches 8-13 ms and the player's 12-21
    # ms (it works for every message, so it is preempted more). So the player is judged against
    # the baseline: a few times its lateness plus 1-2 ms, and no drift between the two halves of
    # the replay beyond the baseline's lateness (arrival also waits for this test process). Ignoring
    # the rate, or a rate 10 % off, drifts by 25-750 ms; sending in bursts is late by 100s of ms.
    # The baseline process has its own luck on a very busy machine (load 20: p50 3.9 ms beside a
    # player at 13 ms, then 12 ms beside 14 ms), so each bound takes both of its percentiles.
    ok = (np.median(sent_err) < 1.0 + 2 * b50 + b90 and np.percentile(sent_err, 90) < 2.0 + 4 * b90
          and drift < 1.0 + 2 * b50 + b90 and np.median(arrive_err) < 2.0 + 2 * b50 + 2 * b90)
    return None if ok else text


FLUSH_S = 0.25  # the README's promise: a chunk closes every 0.25 s
# The recorder checks its flush deadline on a 50 ms timer, and a woken process may wait for a core
# on a busy machine (measured up to ~60 ms with four busy loops on the two cores): the slack.
FLUSH_SLACK_S = 0.05 + 0.1


@pytest.mark.timing
def test_recorder_closes_a_chunk_every_flush_period(tmp_path, launch_graph):
    from mcap.reader import make_reader  # the stock library's view of the chunks, not ours

    bag = tmp_path / "chunks.mcap"
    g = launch_graph(f"""
nodes:
  - name: src
    type: marker_test_pattern
    params: {{rate_hz: {RATE}, n_markers: 8, count: 720}}
  - name: rec
    type: bag_recorder
    params: {{path: "{bag}", topics: [markers]}}
""")
    g.wait_ready()
    g.wait_for("node src exited", timeout=30)
    assert g.stop() == 0
    with open(bag, "rb") as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.message_start_time)
    starts = np.array([c.message_start_time for c in chunks], np.int64) / 1e9
    spans = np.array([c.message_end_time - c.message_start_time for c in chunks], np.int64) / 1e9
    spacing = np.diff(starts)
    print(f"{len(chunks)} chunks: spacing median {np.median(spacing) * 1e3:.0f} ms, mean {np.mean(spacing) * 1e3:.1f} ms, "
          f"max {spacing.max() * 1e3:.0f} ms; span max {spans.max() * 1e3:.0f} ms")
    # 720 frames at 240 Hz: 3 s or more on a busy machine, so 12 chunks or more, closed by time
    # (far below the size limit)
    assert len(chunks) >= 11
    # On schedule (no drift): late flushes are followed by early ones, so the median holds the
    # period within 30 ms even on a busy machine (measured 250-251 ms); one stretched by the 50 ms
    # tick each time would be 300 ms.
    assert FLUSH_S - 0.01 <= np.median(spacing) <= FLUSH_S + 0.03
    # and on average exactly the period: the last flush's lateness spread over all the periods
    # (a schedule restarted from each late flush drifts: 273-300 ms measured)
    assert np.mean(spacing) <= FLUSH_S + 0.012
    assert spans.max() <= FLUSH_S + 2 * FLUSH_SLACK_S


@pytest.mark.timing
def test_recorder_killed_then_recovered(tmp_path, launch_graph):
    import random

    bag = tmp_path / "killed.mcap"
    g = launch_graph(f"""
nodes:
  - name: src
    type: marker_test_pattern
    params: {{rate_hz: {RATE}, n_markers: 32}}
  - name: rec
    type: bag_recorder
    params: {{path: "{bag}", topics: [markers, marker_layout]}}
""")
    g.wait_ready()
    nodes = {n["name"]: n for n in fetch_manifest(g.master)["nodes"]}
    # Killed at a random moment of a flush period, once a second of frames is in.
    t_kill = time.monotonic() + 1.0 + random.uniform(0.0, FLUSH_S)
    while time.monotonic() < t_kill:
        time.sleep(0.005)
    kill_ns = time.time_ns()
    os.kill(nodes["rec"]["pid"], signal.SIGKILL)
    g.wait_for("node rec exited")
    g.stop()
    # info reads the killed bag, recover writes a new file beside it: independent, so run at once
    mg = [sys.executable, "-m", "mocapgraph", "bag"]
    info, rec = run_concurrently([mg + ["info", str(bag)], mg + ["recover", str(bag)]], timeout=90, env=g.env)
    assert info.returncode == 2 and "truncated or unfinished" in info.stderr and "bag recover" in info.stderr
    assert rec.returncode == 0, rec.stderr
    assert "saved" in rec.stdout and "lost" in rec.stdout
    with BagReader(tmp_path / "killed.recovered.mcap") as r:
        layout = [m for _, m in r.decoded("marker_layout")]
        envs = [e for e, _ in r.decoded("markers")]
    assert len(layout) == 1
    seqs = np.array([e.seq for e in envs])
    assert seqs[0] == 1 and np.all(np.diff(seqs) == 1)  # everything up to the last flushed chunk
    lost_s = (kill_ns - envs[-1].publish_ns) / 1e9
    print(f"recovered {len(envs)} frames; the last one was published {lost_s * 1e3:.0f} ms before the kill")
    # At most one flush period plus the slack stated above, and one frame period in between.
    assert 0 <= lost_s <= FLUSH_S + FLUSH_SLACK_S + 1 / RATE
    assert len(envs) >= RATE * (1.0 - FLUSH_S - FLUSH_SLACK_S)


@pytest.mark.timing  # a rate: over 100 frames of a 240 Hz stream in its one second
def test_bag_record_cli_against_a_running_graph(tmp_path, launch_graph):
    g = launch_graph(f"""
nodes:
  - name: src
    type: marker_test_pattern
    params: {{rate_hz: {RATE}, n_markers: 8}}
""")
    g.wait_ready()
    bag = tmp_path / "cli.mcap"
    # the refused recording runs beside the real one (independent; their start-ups share the cores)
    mg = [sys.executable, "-m", "mocapgraph", "bag", "record"]
    r, bad = run_concurrently([mg + ["-o", str(bag), "--all", "--exclude", "^diag", "--duration", "1.0"],
                               mg + ["nosuchtopic", "--duration", "0.1"]], timeout=90, env=g.env)
    assert r.returncode == 0, r.stderr
    assert "recording 2 topic(s)" in r.stdout and "lost 0" in r.stdout
    with BagReader(bag) as rd:
        s = rd.summary()
        envs = [e for e, _ in rd.decoded("markers")]
        layouts = [m for _, m in rd.decoded("marker_layout")]
    assert set(s.topics) == {"markers", "marker_layout"}
    assert len(layouts) == 1 and layouts[0].labels[0] == "P0"  # latched: resent to the late joiner
    seqs = np.array([e.seq for e in envs])
    # every frame of a one-second stretch of the stream (however fast a busy machine let the
    # pattern publish: 179 frames seen at load 13, 240 when quiet)
    span_s = (envs[-1].publish_ns - envs[0].publish_ns) / 1e9
    assert np.all(np.diff(seqs) == 1) and 0.8 < span_s < 1.3 and len(seqs) > 100, (len(seqs), span_s)
    assert s.metadata["mocapgraph"]["writer"] == "bag record"
    assert s.metadata["mocapgraph"]["graph"].endswith("graph_0.yaml")
    assert bad.returncode == 2 and "no topic 'nosuchtopic'" in bad.stderr and "markers" in bad.stderr


def test_player_node_commands_and_status(tmp_path, launch_graph):
    bag = write_bag(tmp_path / "p.mcap", frames=100, period_ns=10_000_000)
    ep = f"tcp://127.0.0.1:{free_port()}"
    ctx = zmq.Context.instance()
    cmd = ctx.socket(zmq.XPUB)
    cmd.setsockopt(zmq.LINGER, 0)
    cmd.bind(ep)
    g = launch_graph(f"""
external:
  - {{topic: player_command, type: NodeCommand, endpoint: "{ep}"}}
nodes:
  - name: player
    type: bag_player
    params: {{file: "{bag}", paused: true, stop_at_end: false}}
    remap: {{markers: replayed}}
""")
    g.wait_ready()
    assert cmd.poll(5000), "the player never subscribed to its commands"
    cmd.recv()
    m = fetch_manifest(g.master)
    assert m["topics"]["replayed"]["type"] == "MarkerFrame"
    sub = subscribe(m, ["replayed", "marker_layout", "player_status"])

    sent = [0]

    def send(command: str, **args) -> None:
        import json

        sent[0] += 1
        cmd.send_multipart(encode("player_command", NodeCommand(target="player", command=command,
                                                                args_json=json.dumps(args)), sent[0], time.time_ns()))

    got: list = []

    def collect_until(cond, timeout: float = 15.0) -> list:
        """Messages from now on until ``cond(messages)`` holds (waits on events, not a fixed time)."""
        out, t_end = [], time.monotonic() + timeout
        while time.monotonic() < t_end:
            if sub.poll(20):
                out.append(decode(sub.recv_multipart()))
                if cond(out):
                    return out
        raise AssertionError(f"timed out; got {[(e.topic, getattr(m, 'state', '')) for e, m in out][-10:]}")

    def frames(msgs):
        return [m.frame_number for e, m in msgs if e.topic == "replayed"]

    def statuses(msgs):
        import json

        return [(m.state, json.loads(m.data_json)) for e, m in msgs if e.topic == "player_status"]

    # Two status reports while paused (~0.4 s apart): nothing played yet, but the latched layout
    # reached us.
    got = collect_until(lambda ms: len(statuses(ms)) >= 2 and any(e.topic == "marker_layout" for e, _ in ms))
    assert frames(got) == [] and statuses(got)[-1][0] == "paused"
    assert [e.topic for e, _ in got].count("marker_layout") == 1
    send("step")
    send("step")
    got = collect_until(lambda ms: len(frames(ms)) >= 2 and statuses(ms)
                        and statuses(ms)[-1][1]["position_s"] > 0)
    assert frames(got) == [0, 1]
    send("seek", position_s=0.5)
    got = collect_until(lambda ms: statuses(ms) and statuses(ms)[-1][1]["position_s"] == pytest.approx(0.5))
    assert statuses(got)[-1][0] == "paused" and frames(got) == []
    pacer = baseline_lateness_ms(0.01, 1.0)  # the machine's wake-up lateness meanwhile
    send("play")
    got = collect_until(lambda ms: statuses(ms) and statuses(ms)[-1][0] == "finished")
    base = np.array(json.loads(pacer.communicate(timeout=30)[0]))
    assert frames(got) == list(range(50, 100))
    state, data = statuses(got)[-1]
    print(f"player lag p50 {data['lag_p50_ms']:.3f} ms; machine baseline p50 {np.median(base):.3f} ms")
    # ~0.1 ms on a quiet machine; judged against the baseline, as in the round trip above
    assert data["sent"] == 53 and data["lag_p50_ms"] < 2.0 + 3 * np.median(base)
    sub.close(0)
    cmd.close(0)


def test_graph_check_sees_the_bag_topics_and_names_a_bad_file(tmp_path):
    bag = write_bag(tmp_path / "p.mcap", frames=3)
    good = tmp_path / "g.yaml"
    good.write_text(f"""
nodes:
  - name: player
    type: bag_player
    params: {{file: "{bag}"}}
  - name: log
    type: topic_logger
    params: {{path: "{tmp_path / 'l.jsonl'}", topics: [markers, marker_layout]}}
""")
    types = check_graph(load_graph(good)).topic_types()
    assert types["markers"] == "MarkerFrame" and types["marker_layout"] == "MarkerLayout"
    bad = tmp_path / "b.yaml"
    bad.write_text(good.read_text().replace(str(bag), str(tmp_path / "missing.mcap")))
    with pytest.raises(GraphError) as err:
        check_graph(load_graph(bad))
    text = str(err.value)
    assert "b.yaml" in text and "params.file" in text and "no such file" in text


def test_terminal_keys_step_and_quit(tmp_path):
    import pty
    import select

    bag = write_bag(tmp_path / "k.mcap", frames=50)
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "bag", "play", str(bag), "--paused", "--no-wait",
                             "--no-manifest"], stdin=slave, stdout=slave, stderr=slave, close_fds=True)
    os.close(slave)
    out = b""

    def read_until(text: bytes, timeout: float = 60.0) -> None:  # a deadline against hangs
        nonlocal out
        t_end = time.monotonic() + timeout
        while text not in out and time.monotonic() < t_end:
            if select.select([master], [], [], 0.05)[0]:
                try:
                    out += os.read(master, 4096)
                except OSError:
                    return

    try:
        read_until(b"keys: space")
        os.write(master, b"s")
        read_until(b"sent 2")  # the latched layout first, then one step: frame 0
        os.write(master, b"q")
        read_until(b"played ")
        read_until(b"\n", timeout=1.0)
        assert proc.wait(10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    text = out.decode(errors="replace")
    assert "played 2 messages" in text, text
