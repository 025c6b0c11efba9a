"""Bus benchmark: mocapgraph nodes against raw pyzmq, measured in the same run.

Prints:
- one-way latency p50/p99 of a 64-marker MarkerFrame between two processes, ping-pong
  ("back-to-back": the next frame leaves when the previous came back) and paced at 240 Hz,
  for mocapgraph nodes and for raw pyzmq multipart sending the same bytes, and the ratios
  (targets: p50 <= 1.3x, p99 <= 1.5x);
- 1 kHz from one publisher to 4 subscribers for --fanout-s seconds: sequence gaps (target 0);
- a 100k-message burst into a 1000-deep queue: reported gaps against actual loss (must be equal);
- time for a 7-node graph to be ready and to shut down (targets < 2 s each);
- one-way latency of the same frame at 240 Hz over ipc, plain tcp (loopback) and CurveZMQ tcp
  (a graph with a security: section), with ratios to ipc measured in the same run;
- with --soak-minutes N: 1 kHz to 4 subscribers for N minutes (CurveZMQ tcp), gaps and the memory
  slope of every process (MB/min, from RSS sampled every 5 s).

Usage: python benchmarks/bus.py [--count 3000] [--fanout-s 60] [--burst 100000] [--soak-minutes 10]
       [--only latency|startup|burst|fanout|transport|soak]
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import re
import signal
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zmq

HERE = Path(__file__).resolve().parent
BUS_NODES = HERE / "bus_nodes.py"  # named by file: the graph check loads only files a graph names
sys.path.insert(0, str(HERE))
from _context import print_context  # noqa: E402
from bus_nodes import frame  # noqa: E402

from mocapgraph.messages import encode  # noqa: E402
from mocapgraph.messages.codec import HEADER_AT  # noqa: E402

PUB_OFFSET = HEADER_AT["publish_ns"]  # where the publish stamp is in a header
SEED = "0 (bus_nodes.frame(64, 0): positions from np.random.default_rng(0))"
DATA = "one generated 64-marker MarkerFrame, sent again and again (only its frame number and stamps change)"


def _load() -> str:
    """The 1-minute load average on this machine's cores (beside each figure: it is shared)."""
    return f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores"


def run_graph(yaml_text: str, tmp: Path, wait_for: str | None = None, run_s: float | None = None,
              timeout: float = 600, master: str = "") -> str:
    """Launch a graph, wait for a line or a duration, stop it with SIGINT; returns its output."""
    path = tmp / f"g{time.monotonic_ns()}.yaml"
    path.write_text(yaml_text)
    env = dict(os.environ, PYTHONPATH=f"{HERE}:{os.environ.get('PYTHONPATH', '')}",
               MOCAPGRAPH_MASTER=master or f"ipc://{tmp / ('m' + str(time.monotonic_ns()))}")
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "launch", str(path)], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, env=env)
    lines: list[str] = []
    t_end = time.monotonic() + (run_s if run_s is not None else timeout)
    os.set_blocking(proc.stdout.fileno(), False)
    while time.monotonic() < t_end:
        chunk = proc.stdout.read()
        if chunk:
            lines.extend(chunk.decode(errors="replace").splitlines())
        if wait_for and any(wait_for in line for line in lines):
            break
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    proc.wait(30)
    os.set_blocking(proc.stdout.fileno(), True)
    lines.extend(proc.stdout.read().decode(errors="replace").splitlines())
    return "\n".join(lines)


def mocapgraph_latency(tmp: Path, rate_hz: float, count: int, head: str = "", host: str = "",
                       slack_s: float = 0.0) -> np.ndarray:
    out = tmp / f"lat{rate_hz}.npy"
    host_line = f"\n    host: {host}" if host else ""
    run_graph(f"""{head}
nodes:
  - name: sender
    type: {BUS_NODES}:BenchSender{host_line}
    params: {{rate_hz: {rate_hz}, count: {count}}}
  - name: receiver
    type: {BUS_NODES}:BenchReceiver
    params: {{echo: {str(rate_hz == 0).lower()}, out_file: "{out}"}}
""", tmp, run_s=0.6 + count / (rate_hz or 4000) + 1.5 + slack_s)
    return np.load(out)[20:]  # drop warm-up


def _raw_receiver(ep_in: str, ep_out: str, echo: bool, count: int, q) -> None:
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.connect(ep_in)
    pub = ctx.socket(zmq.PUB)
    pub.bind(ep_out)
    lat = []
    q.put("ready")
    while len(lat) < count:
        if not sub.poll(5000):
            break
        frames = sub.recv_multipart()
        lat.append(time.time_ns() - struct.unpack_from("<q", frames[1], PUB_OFFSET)[0])
        if echo:
            pub.send_multipart(frames)
    q.put(np.array(lat, np.int64))


def raw_latency(tmp: Path, rate_hz: float, count: int) -> np.ndarray:
    """Raw pyzmq: the same frames (stamp patched in place), PUB/SUB over ipc, no codec, no runtime."""
    ep_a, ep_b = f"ipc://{tmp / 'a'}", f"ipc://{tmp / 'b'}"
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.bind(ep_a)
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.connect(ep_b)
    q = mp.get_context("fork").Queue()
    proc = mp.get_context("fork").Process(target=_raw_receiver, args=(ep_a, ep_b, rate_hz == 0, count, q))
    proc.start()
    q.get(timeout=10)
    time.sleep(0.5)  # slow joiner: raw pyzmq has no handshake
    frames = [bytes(f) for f in encode("ping", frame(64, 0), 1, 0, "sender")]
    header = bytearray(frames[1])
    period = 1.0 / rate_hz if rate_hz else 0.0
    next_t = time.monotonic()
    for i in range(count):
        if rate_hz:
            next_t += period
            while True:
                wait = next_t - time.monotonic()
                if wait <= 0:
                    break
                time.sleep(wait if wait > 0.002 else wait * 0.9)
        struct.pack_into("<q", header, PUB_OFFSET, time.time_ns())
        frames[1] = bytes(header)
        pub.send_multipart(frames)
        if not rate_hz:
            if not sub.poll(5000):
                break
            sub.recv_multipart()
            time.sleep(0.0002)
    lat = q.get(timeout=30)
    proc.join()
    ctx.destroy(0)
    return lat[20:]


ROUNDS = 5


def pct(a: np.ndarray, p: float) -> float:
    return float(np.percentile(a, p)) / 1e3


def latency_section(tmp: Path, count: int) -> None:
    print_context(SEED, DATA, f"per mode {ROUNDS} rounds each of raw pyzmq and mocapgraph, {count // ROUNDS} frames a "
                  f"round back-to-back, {min(count, 2400) // ROUNDS} at 240 Hz; each round's first 20 dropped (warm-up)",
                  section="latency")
    print("one-way latency, 64-marker MarkerFrame, two processes (us)")
    print(f"{'mode':<14}{'raw p50':>9}{'raw p99':>9}{'mg p50':>9}{'mg p99':>9}{'p50 x':>8}{'p99 x':>8}")
    for label, rate in (("back-to-back", 0.0), ("240 Hz", 240.0)):
        n = count if rate == 0 else min(count, 2400)
        # Alternate rounds so that load from elsewhere on the machine hits both alike.
        raws, mgs = [], []
        for _ in range(ROUNDS):
            raws.append(raw_latency(tmp, rate, n // ROUNDS))
            mgs.append(mocapgraph_latency(tmp, rate, n // ROUNDS))
        raw, mg = np.concatenate(raws), np.concatenate(mgs)
        r50, r99, m50, m99 = pct(raw, 50), pct(raw, 99), pct(mg, 50), pct(mg, 99)
        print(f"{label:<14}{r50:9.1f}{r99:9.1f}{m50:9.1f}{m99:9.1f}{m50 / r50:8.2f}{m99 / r99:8.2f}"
              f"   (n raw {len(raw)}, mg {len(mg)}; targets 1.3x / 1.5x)")


def fanout_section(tmp: Path, seconds: float) -> None:
    count = int(seconds * 1000)
    print_context(SEED, DATA, f"{count} frames intended at 1 kHz, every one counted by each of 4 receivers",
                  section="fanout")
    files = [tmp / f"fan{i}.npy" for i in range(4)]
    sent_file = tmp / "fan_sent.txt"
    receivers = "".join(f"""
  - name: r{i}
    type: {BUS_NODES}:BenchReceiver
    params: {{out_file: "{f}"}}""" for i, f in enumerate(files))
    run_graph(f"""
nodes:
  - name: sender
    type: {BUS_NODES}:BenchSender
    params: {{rate_hz: 1000.0, count: {count}, out_file: "{sent_file}"}}{receivers}
""", tmp, run_s=seconds + 3.0)
    sent = int(sent_file.read_text().split()[0])   # the sender's own count, not the intended one
    results = [open(str(f) + ".counts").read().split() for f in files]
    got = [int(r[0]) for r in results]
    gaps = [int(r[1]) for r in results]
    # a frame the sender sent that a receiver never got: a gap inside its stream, or one after its last
    missed = [g + max(0, sent - int(r[2])) for g, r in zip(gaps, results)]
    verdict = "LOSS" if any(missed) else "OK"
    slow = f"; the sender sent {sent} of the {count} intended (a slow sender, not loss)" if sent < count else ""
    print(f"1 kHz to 4 subscribers for {seconds:.0f} s (load {_load()}): sent {sent}, received {got}, "
          f"gaps {gaps}, missed {missed} ({verdict}){slow}")


def burst_section(tmp: Path, n: int) -> None:
    out = tmp / "burst.npy"
    print_context(SEED, DATA, f"{n} frames in one burst (the last 0.3 s later), all counted", section="burst")
    run_graph(f"""
nodes:
  - name: sender
    type: {BUS_NODES}:BenchSender
    params: {{burst: true, count: {n}}}
  - name: receiver
    type: {BUS_NODES}:BenchReceiver
    params: {{out_file: "{out}", queue: 1000}}
""", tmp, run_s=4.0 + n / 50000)
    got, gaps, last = (int(x) for x in open(str(out) + ".counts").read().split())
    lost = n - got
    print(f"burst of {n} (the last sent 0.3 s later) into a 1000-deep queue: received {got}, actual loss {lost}, "
          f"reported gaps {gaps}, last seq {last} ({'counted exactly' if gaps == lost and last == n else 'MISMATCH'})")


def startup_section(tmp: Path) -> None:
    print_context(SEED, DATA + "; a 7-node graph (1 sender at 100 Hz, 6 receivers)", "one launch, timed once",
                  section="startup")
    nodes = "".join(f"""
  - name: n{i}
    type: {BUS_NODES}:BenchReceiver""" for i in range(6))
    t0 = time.monotonic()
    text = run_graph(f"""
nodes:
  - name: sender
    type: {BUS_NODES}:BenchSender
    params: {{rate_hz: 100.0, count: 1000000}}{nodes}
""", tmp, wait_for="nodes ready in")
    wall = time.monotonic() - t0
    ready = float(re.search(r"ready in ([\d.]+) s", text).group(1))
    stop = float(re.search(r"stopped in ([\d.]+) s", text).group(1))
    print(f"7-node graph: ready in {ready:.2f} s after spawn ({wall:.2f} s wall incl. launcher start and stop), "
          f"stopped in {stop:.2f} s (targets < 2 s)")


def _keys(tmp: Path) -> str:
    from mocapgraph.bus.curve import generate

    if not (tmp / "keys" / "graph.key_secret").exists():
        generate(tmp / "keys", "graph")
    return f"security: {{key: {tmp / 'keys' / 'graph.key_secret'}, authorized: {tmp / 'keys'}}}"


def transport_section(tmp: Path, count: int) -> None:
    print_context(SEED + "; CurveZMQ keys generated fresh", DATA,
                  f"{ROUNDS} interleaved rounds of {count // ROUNDS} frames at 240 Hz per transport (ipc, tcp, curve "
                  "tcp); each round's first 20 dropped (warm-up)", section="transport")
    print("one-way latency by transport, 64-marker MarkerFrame at 240 Hz, mocapgraph nodes (us)")
    curve = _keys(tmp)
    modes = (("ipc", "", ""), ("tcp", "", "127.0.0.1"), ("curve tcp", curve, "127.0.0.1"))
    got: dict[str, list[np.ndarray]] = {m: [] for m, _, _ in modes}
    for _ in range(ROUNDS):  # interleaved, so load from elsewhere hits all alike
        for label, head, host in modes:
            # slack: on a loaded machine start-up alone can take seconds
            got[label].append(mocapgraph_latency(tmp, 240.0, count // ROUNDS, head, host, slack_s=6.0))
    ipc = np.concatenate(got["ipc"])
    for label, _, _ in modes:
        a = np.concatenate(got[label])
        print(f"  {label:<10} p50 {pct(a, 50):8.1f}  p99 {pct(a, 99):8.1f}   x ipc: p50 {pct(a, 50) / pct(ipc, 50):5.2f}, "
              f"p99 {pct(a, 99) / pct(ipc, 99):5.2f}   (n {len(a)})")


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(x.split()[1]) / 1024 for x in f if x.startswith("VmRSS:"))
    except (OSError, StopIteration):
        return float("nan")


def soak_section(tmp: Path, minutes: float) -> None:
    """1 kHz to 4 subscribers over CurveZMQ tcp for ``minutes``: gaps and memory slope per process."""
    import threading

    from mocapgraph.bus.manifest import fetch_manifest

    seconds = minutes * 60
    count = int(seconds * 1000)
    print_context(SEED + "; CurveZMQ keys generated fresh", DATA,
                  f"{count} frames planned at 1 kHz to 4 receivers; RSS slope over the second half of the run",
                  section="soak")
    files = [tmp / f"soak{i}.npy" for i in range(4)]
    receivers = "".join(f"""
  - name: r{i}
    type: {BUS_NODES}:BenchReceiver
    params: {{out_file: "{f}"}}""" for i, f in enumerate(files))
    master = f"ipc://{tmp / 'soak-master'}"
    samples: dict[str, list[tuple[float, float]]] = {}
    done = threading.Event()

    def sample() -> None:
        pids: dict[str, int] = {}
        t0 = time.monotonic()
        while not done.wait(5.0):
            if not pids:
                try:
                    pids = {n["name"]: n["pid"] for n in fetch_manifest(master, 1.0)["nodes"]}
                except Exception:  # noqa: BLE001 - not up yet
                    continue
            for name, pid in pids.items():
                samples.setdefault(name, []).append((time.monotonic() - t0, _rss_mb(pid)))

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    run_graph(f"""{_keys(tmp)}
nodes:
  - name: sender
    type: {BUS_NODES}:BenchSender
    host: 127.0.0.1
    params: {{rate_hz: 1000.0, count: {count}}}{receivers}
""", tmp, run_s=seconds + 3.0, master=master)
    done.set()
    th.join()
    results = [open(str(f) + ".counts").read().split() for f in files]
    got = [int(r[0]) for r in results]
    gaps = [int(r[1]) for r in results]
    verdict = "no gaps" if sum(gaps) == 0 else "GAPS"
    if max(got) < count:
        verdict += f"; the sender reached only {max(got)} of {count} in time (CPU-starved machine)"
    print(f"soak, CurveZMQ tcp, 1 kHz to 4 subscribers for {minutes:g} min: planned {count}, received {got}, "
          f"gaps {gaps} ({verdict}); receivers keep every latency sample (a Python int each), so their RSS grows "
          "by design")
    for name, pts in sorted(samples.items()):
        t, mb = np.array(pts).T
        ok = np.isfinite(mb) & (t > t.max() / 2)  # the second half: what still grows is a leak
        slope = np.polyfit(t[ok], mb[ok], 1)[0] * 60 if ok.sum() >= 3 else float("nan")
        print(f"  {name:<7} RSS {np.nanmin(mb):6.1f} -> {mb[-1]:6.1f} MB, slope over the second half "
              f"{slope:+.3f} MB/min")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=3000, help="latency samples per mode")
    ap.add_argument("--fanout-s", type=float, default=60.0)
    ap.add_argument("--burst", type=int, default=100_000)
    ap.add_argument("--soak-minutes", type=float, default=0.0, help="also soak 1 kHz to 4 subscribers for N minutes")
    ap.add_argument("--only", choices=["latency", "startup", "burst", "fanout", "transport", "soak"],
                    help="run one section")
    a = ap.parse_args()
    print(f"machine: {os.cpu_count()} cores, pyzmq {zmq.pyzmq_version()}, libzmq {zmq.zmq_version()}; "
          f"load {_load()}")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        sections = {"latency": lambda: latency_section(tmp, a.count), "startup": lambda: startup_section(tmp),
                    "burst": lambda: burst_section(tmp, a.burst), "fanout": lambda: fanout_section(tmp, a.fanout_s),
                    "transport": lambda: transport_section(tmp, min(a.count, 2400)),
                    "soak": lambda: soak_section(tmp, a.soak_minutes or 1.0)}
        for name, run in sections.items():
            wanted = a.only == name if a.only else (name != "soak" or a.soak_minutes > 0)
            if wanted:
                run()


if __name__ == "__main__":
    main()
