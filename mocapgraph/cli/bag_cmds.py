"""``mocapgraph bag record|play|info|convert|recover``: MCAP topic recordings."""
from __future__ import annotations

import argparse
import json
import os
import re
import select
import signal
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zmq

from ..bag.errors import BagError
from .progress import Progress
from . import UserError

if TYPE_CHECKING:
    from ..bag.player import Playback
    from ..bag.recorder import Recorder
    from ..bag.writer import BagWriter
    from ..bus.manifest import Manifest, ManifestServer
    from ..bus.ports import Interface
    from ..nodes.bag_player import BagPlayer


def _fail(exc: BagError) -> UserError:
    return UserError(str(exc))


class _StopSignals:
    """SIGINT and SIGTERM turned into a flag the command's loop polls, until :meth:`restore`."""

    def __init__(self) -> None:
        self.flag = False
        self._old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}

    def _on_signal(self, signum: int, frame: Any) -> None:
        self.flag = True

    def restore(self) -> None:
        """Put back the handlers that were there before."""
        for s, h in self._old.items():
            signal.signal(s, h)


def _status_to_terminal(line: str) -> None:
    """Overwrite the terminal's last line with ``line`` (stderr, so stdout stays a log)."""
    sys.stderr.write(f"\r{line}   ")
    sys.stderr.flush()


# ----- record ------------------------------------------------------------------------------------
def _record_topics(args: argparse.Namespace, known: dict[str, Any]) -> list[str]:
    """The topics to record: ``--all`` or those named (each must be in the running graph),
    less those matching ``--exclude``; UserError when none are left."""
    if args.all:
        topics = sorted(known)
    elif args.topics:
        missing = [t for t in args.topics if t not in known]
        if missing:
            raise UserError(f"no topic {missing[0]!r} in the running graph (topics: {', '.join(sorted(known))})")
        topics = list(dict.fromkeys(args.topics))
    else:
        raise UserError("name the topics to record, or --all (topics: " + ", ".join(sorted(known)) + ")")
    if args.exclude:
        try:
            rx = re.compile(args.exclude)
        except re.error as exc:
            raise UserError(f"--exclude {args.exclude!r} is not a regular expression ({exc})") from None
        topics = [t for t in topics if not rx.search(t)]
    if not topics:
        raise UserError("nothing to record: every topic was excluded")
    return topics


def _open_bag(args: argparse.Namespace, manifest: dict[str, Any], topics: list[str]) -> BagWriter:
    """The bag to record into, its metadata saying which graph, command, topics and nodes."""
    from ..bag.writer import BagWriter, base_metadata
    from ..nodes.bag_recorder import default_bag_name

    out = args.output or default_bag_name()
    meta = base_metadata("bag record", graph=str(manifest.get("graph", "")), command=" ".join(sys.argv),
                         topics_json=json.dumps(topics),
                         nodes_json=json.dumps([{k: n.get(k) for k in ("name", "type", "params")}
                                                for n in manifest.get("nodes", [])]))
    try:
        return BagWriter(out, compression=args.compression, chunk_kb=args.chunk_kb, split_mb=args.split_mb,
                         split_s=args.split_s, metadata=meta, on_exists="overwrite" if args.force else "error")
    except BagError as exc:
        raise _fail(exc) from None


def _drain(sock: zmq.Socket, rec: Recorder) -> BagError | None:
    """Hand the waiting messages to the recorder, at most 2000 so the loop still looks at the
    clock; the disk's refusal (full, gone) if it gave one."""
    for _ in range(2000):
        try:
            frames = sock.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            break
        try:
            rec.receive(frames)
        except BagError as exc:
            return exc
    return None


def _graph_gone(master: str | None) -> bool:
    """True when no graph answers at ``master`` any more (asked with a 0.5 s timeout)."""
    from ..bus.manifest import NoGraphError, fetch_manifest

    try:
        fetch_manifest(master, timeout_s=0.5)
    except NoGraphError:
        return True
    return False


def _record_until_stopped(args: argparse.Namespace, sock: zmq.Socket, rec: Recorder,
                          stop: _StopSignals, tty: bool) -> BagError | None:
    """Record until a signal, ``--duration`` s, the graph stopping or the disk refusing (the
    refusal is returned: what was written is kept)."""
    t_end = time.monotonic() + args.duration if args.duration else None
    next_status = time.monotonic() + 1.0
    last_msg = time.monotonic()
    failure: BagError | None = None
    while not stop.flag and failure is None:
        if sock.poll(20):
            failure = _drain(sock, rec)
            last_msg = time.monotonic()
        now = time.monotonic()
        try:
            if failure is None:
                rec.tick(now)
        except BagError as exc:
            failure = exc
        if now - last_msg > 2.0:  # quiet: is the graph still there?
            last_msg = now
            if _graph_gone(args.master):
                print("the graph has stopped", flush=True)
                break
        if now >= next_status:
            next_status = now + 1.0
            if tty:
                _status_to_terminal(rec.status())
        if t_end is not None and now >= t_end:
            break
    return failure


def _report_recording(rec: Recorder, paths: list[Path]) -> None:
    """What was recorded where, and the sequence gaps seen upstream."""
    print(f"recorded {rec.status()} to {', '.join(map(str, paths))}")
    if rec.lost:
        print("lost upstream (sequence gaps, written into the bag): "
              + ", ".join(f"{t} {n}" for t, n in sorted(rec.lost.items())))


def cmd_record(args: argparse.Namespace) -> int:
    from ..bag.recorder import Recorder
    from ..bus.manifest import NoGraphError, fetch_manifest, subscribe

    try:
        manifest = fetch_manifest(args.master)
    except NoGraphError as exc:
        raise UserError(str(exc)) from None
    topics = _record_topics(args, manifest.get("topics", {}))
    writer = _open_bag(args, manifest, topics)
    rec = Recorder(writer, args.flush_s)
    sock = subscribe(manifest, topics, hwm=0)
    stop = _StopSignals()
    tty = sys.stderr.isatty()
    print(f"recording {len(topics)} topic(s) to {writer.paths[0]}: {', '.join(topics)}", flush=True)
    failure: BagError | None = None
    try:
        failure = _record_until_stopped(args, sock, rec, stop, tty)
    finally:
        stop.restore()
        sock.close(0)
        try:
            paths = rec.close()
        except BagError as exc:
            failure = failure or exc
        if tty:
            sys.stderr.write("\n")
    if failure is not None:
        raise _fail(failure)
    _report_recording(rec, paths)
    return 0


# ----- play --------------------------------------------------------------------------------------------
def _player_manifest(node: BagPlayer, file: str) -> Manifest:
    """The manifest a standalone player serves, so topic echo / bag record find it."""
    from ..bus.manifest import Manifest, NodeEntry

    ep = node.wiring.pub_endpoint
    m = Manifest(graph=f"bag play {file}")
    for name, decl in node.iface.outputs.items():
        m.add_publisher(node.output_ports[name].topic, decl.type_name, node.name, ep, decl.is_latched)
    m.add_publisher("diagnostics", "Diagnostics", node.name, ep)
    m.nodes = [NodeEntry(node.name, "bag_player", "mocapgraph.nodes.bag_player:BagPlayer", os.getpid(), ep,
                         node.params, {}, {n: p.topic for n, p in node.output_ports.items()})]
    return m


class _Keys:
    """Single key presses from a terminal (space pause, s step, q quit, + / - rate)."""

    def __init__(self) -> None:
        self.fd = None
        if sys.stdin.isatty():
            import termios
            import tty

            self.fd = sys.stdin.fileno()
            self.saved = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)

    def read(self) -> str:
        if self.fd is None:
            return ""
        r, _, _ = select.select([self.fd], [], [], 0)
        return os.read(self.fd, 32).decode(errors="ignore") if r else ""

    def close(self) -> None:
        if self.fd is not None:
            import termios

            termios.tcsetattr(self.fd, termios.TCSADRAIN, self.saved)


def _player_params(args: argparse.Namespace) -> tuple[dict[str, str], dict[str, Any]]:
    """(bag topic -> topic to play it on, the bag_player node's params) from the command line."""
    from ..bag.player import parse_remaps

    try:
        remap = parse_remaps(args.remap or [])
    except ValueError as exc:
        raise UserError(str(exc)) from None
    params = {"file": args.file, "rate": args.rate, "loop": args.loop, "start": args.start, "end": args.end or 0.0,
              "topics": args.topics or [], "exclude": args.exclude or "", "paused": args.paused,
              "stop_at_end": not args.stay, "realtime": args.realtime}
    if not args.rate > 0:
        raise UserError(f"--rate must be positive, got {args.rate}")
    return remap, params


def _player_interface(params: dict[str, Any], remap: dict[str, str]) -> Interface:
    """The player's ports for the bag (it opens the file), with the params and every remapped
    topic checked against them."""
    from ..bus.node import NodeConfigError
    from ..nodes.bag_player import BagPlayer

    try:
        iface = BagPlayer.interface(params)
        BagPlayer.check_params(params, iface)
    except NodeConfigError as exc:
        raise UserError(str(exc).removeprefix("parameter 'file': ")) from None
    unknown = [a for a in remap if a not in iface.outputs]
    if unknown:
        raise UserError(f"--remap {unknown[0]}: the bag plays no topic {unknown[0]!r} "
                        f"(topics: {', '.join(n for n in iface.outputs if n != 'status')})")
    return iface


def _check_bind(args: argparse.Namespace) -> None:
    """A ``--bind`` other machines can reach needs ``--insecure``: bag play has no CurveZMQ keys."""
    if args.bind and args.bind.startswith("tcp://") and not args.insecure:
        from ..launch.check import _loopback

        host = args.bind[6:].rsplit(":", 1)[0].strip("[]")
        if host in ("*", "") or not _loopback(host):
            raise UserError(f"--bind {args.bind} is reachable from other machines and bag play has no keys: "
                            "bind a loopback address, or pass --insecure to publish plaintext knowingly")


def _start_player(args: argparse.Namespace, params: dict[str, Any], iface: Interface,
                  remap: dict[str, str]) -> tuple[BagPlayer, dict[str, dict[str, Any]]]:
    """(the player node, bound and set up, its wiring's outputs: port -> topic and subscribers)."""
    from ..bus.node import NodeConfigError, Wiring
    from ..nodes.bag_player import BagPlayer

    outputs = {name: {"topic": remap.get(name, decl.topic), "subscribers": 0} for name, decl in iface.outputs.items()}
    wiring = Wiring(node="bag_play", pub_endpoint=args.bind or "", outputs=outputs)
    try:
        node = BagPlayer("bag_play", params, wiring)
    except NodeConfigError as exc:
        raise UserError(str(exc)) from None
    try:
        node.setup()
    except zmq.ZMQError as exc:
        raise UserError(f"cannot bind {args.bind}: {exc}") from None
    return node, outputs


def _serve_manifest(args: argparse.Namespace, node: BagPlayer) -> tuple[ManifestServer | None, Manifest | None]:
    """(server, manifest) answering topic echo / bag record at the master address, unless
    ``--no-manifest`` or a graph already serves it (server None when another process took the
    address meanwhile)."""
    from ..bus.manifest import ManifestBusyError, ManifestServer, NoGraphError, default_master, fetch_manifest

    if args.no_manifest:
        return None, None
    master = args.master or default_master()
    try:
        fetch_manifest(master, timeout_s=0.3)
        print(f"note: a graph already serves {master}; this player is reachable at {node.wiring.pub_endpoint} only")
        return None, None
    except NoGraphError:
        pass
    try:
        server = ManifestServer(master)
    except ManifestBusyError:
        server = None
    return server, _player_manifest(node, args.file)


def _announce_playback(args: argparse.Namespace, node: BagPlayer, outputs: dict[str, dict[str, Any]]) -> None:
    """Which bag topics are skipped and why, and what plays where at which rate."""
    pb = node.playback
    for topic, why in pb.skipped.items():
        print(f"not playing {topic}: {why}")
    played = ", ".join(f"{outputs[t]['topic']} [{i.type_name}]" for t, i in pb.topics.items())
    print(f"playing {args.file} ({pb.duration_s:.2f} s) at {pb.rate:g}x on {node.wiring.pub_endpoint}: {played}",
          flush=True)


def _on_key(node: BagPlayer, key: str, start_s: float) -> bool:
    """Act on one key press (see :class:`_Keys`); True when it asks to quit."""
    pb = node.playback
    if key == " ":
        node.handle("toggle")
    elif key == "s":
        node.handle("step")
    elif key == "+":
        node.handle("rate", {"rate": pb.rate * 2})
    elif key == "-":
        node.handle("rate", {"rate": pb.rate / 2})
    elif key == "r":
        node.handle("seek", {"position_s": start_s})
    elif key == "q":
        return True
    return False


def _play_until_stopped(args: argparse.Namespace, node: BagPlayer, server: ManifestServer | None,
                        manifest: Manifest | None, keys: _Keys, stop: _StopSignals, tty: bool) -> None:
    """Spin the player until a signal, ``q`` or the player's own stop (bag end without --stay),
    serving the manifest, reading keys and showing a status line each second."""
    next_status = time.monotonic() + 1.0
    while not stop.flag and not node.stopping:
        node.spin_once(0.02)
        if server is not None:
            server.serve(lambda: manifest)
        for k in keys.read():
            if _on_key(node, k, args.start):
                stop.flag = True
        now = time.monotonic()
        if now >= next_status and node.started:
            next_status = now + 1.0
            line = _status_line(node)
            if tty:
                _status_to_terminal(line)
            elif not args.quiet:
                print(line, flush=True)


def _report_playback(pb: Playback) -> None:
    """Messages played, loops, where it ended, the rate achieved and the lag behind schedule."""
    p50, p99, pmax = pb.lag_ms()
    print(f"played {pb.sent} messages ({pb.loops} loops), position {pb.position_s:.2f} s; achieved rate "
          f"{pb.achieved_rate:.3f}x; lag behind schedule p50 {p50:.3f} ms, p99 {p99:.3f} ms, max {pmax:.3f} ms")


def cmd_play(args: argparse.Namespace) -> int:
    remap, params = _player_params(args)
    iface = _player_interface(params, remap)
    _check_bind(args)
    node, outputs = _start_player(args, params, iface, remap)
    server, manifest = _serve_manifest(args, node)
    _announce_playback(args, node, outputs)
    stop = _StopSignals()
    keys = _Keys()
    if keys.fd is not None:
        print("keys: space pause/resume, s step, + / - rate x2 / x0.5, r restart, q quit", flush=True)
    if args.no_wait:
        node.announce_ready()
    else:
        print("waiting for a subscriber (--no-wait starts at once)", flush=True)
    tty = sys.stderr.isatty()
    try:
        _play_until_stopped(args, node, server, manifest, keys, stop, tty)
    finally:
        keys.close()
        stop.restore()
        if tty:
            sys.stderr.write("\n")
        try:
            node.on_stop()
        finally:
            node.close()
            if server is not None:
                server.close()
    if node.error:
        raise UserError(node.error)
    _report_playback(node.playback)
    return 0


def _status_line(node) -> str:
    d = node.status_data()
    pb = node.playback
    rate = "-" if d["achieved_rate"] is None else f"{d['achieved_rate']:.2f}x"
    lag = "-" if d["lag_p50_ms"] is None else f"{d['lag_p50_ms']:.2f}/{d['lag_max_ms']:.2f} ms"
    return (f"{pb.state:<8} {d['position_s']:8.2f}/{d['duration_s']:.2f} s  rate {pb.rate:g}x "
            f"(achieved {rate})  lag p50/max {lag}  sent {d['sent']}")


# ----- info ---------------------------------------------------------------------------------------------
def _stamp_text(ns: int) -> str:
    if ns > 10 ** 18:  # an epoch time stamp (after 2001)
        return datetime.fromtimestamp(ns / 1e9, timezone.utc).isoformat(timespec="milliseconds")
    return f"t={ns / 1e9:.3f} s"


def cmd_info(args: argparse.Namespace) -> int:
    from ..bag.reader import BagReader

    try:
        with BagReader(args.file) as r:
            s = r.summary()
            scan = None
            if not args.fast:
                with Progress("scanning", unit="msg") as bar:
                    scan = r.scan(progress=lambda i: bar(i, s.count))
    except BagError as exc:
        raise _fail(exc) from None
    if args.json:
        print(json.dumps({
            "file": str(s.path), "size_bytes": s.size_bytes, "duration_s": s.duration_s, "start_ns": s.start_ns,
            "end_ns": s.end_ns, "messages": s.count, "chunks": s.chunks, "compression": s.compression,
            "library": s.library, "losses": s.losses, "metadata": s.metadata,
            "seq_gaps": scan.seq_gaps if scan else None,
            "time_gaps": scan.time_gaps if scan else None,
            "topics": {t: {"type": i.type_name, "schema_version": i.schema_version, "count": i.count,
                           "rate_hz": i.rate_hz, "latched": i.latched, "known": i.known, "problem": i.problem}
                       for t, i in s.topics.items()}}, indent=1))
        return 0
    print(f"file:        {s.path} ({s.size_bytes / 1e6:.2f} MB, {s.chunks} chunks, {s.compression})")
    print(f"duration:    {s.duration_s:.3f} s, from {_stamp_text(s.start_ns)} to {_stamp_text(s.end_ns)}")
    print(f"messages:    {s.count}")
    info = s.metadata.get("mocapgraph", {})
    if info:
        print(f"written by:  {info.get('writer', '?')}, mocapgraph {info.get('mocapgraph_version', '?')} on "
              f"{info.get('host', '?')} at {info.get('created', '?')}")
        for key in ("graph", "source", "command", "node"):
            if info.get(key):
                print(f"{key + ':':<13}{info[key]}")
    else:
        print(f"written by:  {s.library or '?'} (not a mocapgraph bag)")
    width = max([len(t) for t in s.topics] + [5])
    print("topics:")
    for t, i in sorted(s.topics.items()):
        extra = " latched" if i.latched else ""
        if not i.known:
            extra += f"  [cannot decode: {i.problem}]"
        rate = f"{i.rate_hz:9.2f} Hz" if i.rate_hz else " " * 12
        print(f"  {t:<{width}}  {i.type_name:<14} {i.count:8d} msgs {rate}{extra}")
    lost = ", ".join(f"{t} {n}" for t, n in sorted(s.losses.items())) or "none"
    print(f"lost while recording (sequence gaps seen by the recorder): {lost}")
    if scan is not None:
        sg = ", ".join(f"{t} {n}" for t, n in sorted(scan.seq_gaps.items())) or "none"
        print(f"sequence gaps in the stored messages: {sg}")
        tg = {t: g for t, g in scan.time_gaps.items() if g}
        if tg:
            print("time gaps (> 3x the topic's median interval):")
            for t, gaps in sorted(tg.items()):
                longest = max(gaps, key=lambda g: g[1])
                print(f"  {t}: {len(gaps)}{'+' if len(gaps) >= 50 else ''}, longest {longest[1] * 1e3:.1f} ms "
                      f"at {longest[0]:.3f} s (median interval {scan.periods_s[t] * 1e3:.2f} ms)")
        else:
            print("time gaps: none")
    others = {k: v for k, v in s.metadata.items() if k not in ("mocapgraph", "mocapgraph.losses")}
    if info:
        extra = {k: v for k, v in info.items() if k not in ("writer", "mocapgraph_version", "host", "created",
                                                             "graph", "source", "command", "node", "framing",
                                                             "split_index")}
        if extra:
            others = {"mocapgraph": extra, **others}
    if others:
        print("metadata:")
        for name, kv in others.items():
            for k, v in kv.items():
                text = v if len(v) <= 200 or args.verbose else v[:200] + f"... ({len(v)} chars, -v shows all)"
                print(f"  {name}.{k}: {text}")
    return 0


# ----- convert / recover -------------------------------------------------------------------------------
def cmd_convert(args: argparse.Namespace) -> int:
    from ..bag.convert import INPUT_KINDS, OUTPUT_KINDS, bag_to_file, file_to_bag

    if args.output and args.legacy_output:
        raise UserError(f"two outputs ({args.legacy_output} and -o {args.output}): give one, as -o OUT")
    if not (args.output or args.legacy_output):
        raise UserError("no output: bag convert IN -o OUT (e.g. trial.c3d -o trial.mcap)")
    if args.legacy_output:
        print(f"note: the output is now given as -o: mocapgraph bag convert {args.input} -o {args.legacy_output}",
              file=sys.stderr)
    src, dst = Path(args.input), Path(args.output or args.legacy_output)
    try:
        with Progress("converting") as bar:
            if src.suffix.lower() == ".mcap":
                if dst.suffix.lower() not in OUTPUT_KINDS:
                    raise UserError(f"{dst}: a bag converts to {', '.join(sorted(OUTPUT_KINDS))}")
                rep = bag_to_file(src, dst, topic=args.topic, units=args.units, progress=bar)
            elif dst.suffix.lower() == ".mcap":
                if src.suffix.lower() not in INPUT_KINDS:
                    raise UserError(f"{src}: converts into a bag from {', '.join(sorted(INPUT_KINDS))}")
                rep = file_to_bag(src, dst, compression=args.compression, start_ns=args.start_ns, progress=bar,
                                  up_axis=args.up)
            else:
                raise UserError("one side of a conversion is a bag (.mcap): "
                                "FILE.c3d -o OUT.mcap or BAG.mcap -o OUT.trc")
    except BagError as exc:
        raise _fail(exc) from None
    print(rep.text())
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
    from ..bag.recover import recover

    try:
        with Progress("recovering", unit="bytes") as bar:
            rep = recover(args.file, args.output, progress=bar, force=args.force)
    except BagError as exc:
        raise _fail(exc) from None
    print(rep.text())
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("bag", help="record, replay, inspect, convert and recover MCAP bags")
    bs = b.add_subparsers(dest="bag_command", required=True)

    p = bs.add_parser("record", help="record topics of the running graph into a bag")
    p.add_argument("topics", nargs="*", metavar="TOPIC")
    p.add_argument("-o", "--output", help="bag file (default mocapgraph_<date>_<time>.mcap)")
    p.add_argument("-a", "--all", action="store_true", help="every topic of the graph")
    p.add_argument("--exclude", help="regular expression of topics not to record")
    p.add_argument("--compression", choices=["lz4", "none"], default="lz4")
    p.add_argument("--chunk-kb", type=int, default=256, help="chunk size, KiB (chunks also close every --flush-s)")
    p.add_argument("--flush-s", type=float, default=0.25, help="close and flush a chunk this often, s")
    p.add_argument("--split-mb", type=float, default=0.0, help="new file after this many MB")
    p.add_argument("--split-s", type=float, default=0.0, help="new file after this many seconds")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds")
    p.add_argument("-f", "--force", action="store_true", help="overwrite an existing bag")
    p.add_argument("--master", help="manifest endpoint of the running graph")
    p.set_defaults(func=cmd_record)

    p = bs.add_parser("play", help="replay a bag with its recorded timing")
    p.add_argument("file")
    p.add_argument("-r", "--rate", type=float, default=1.0, help="speed factor")
    p.add_argument("-l", "--loop", action="store_true")
    p.add_argument("--start", type=float, default=0.0, help="seconds into the bag")
    p.add_argument("--end", type=float, default=0.0, help="seconds into the bag (0: its end)")
    p.add_argument("--topics", nargs="+", help="only these topics")
    p.add_argument("--exclude", help="regular expression of topics not to play")
    p.add_argument("--remap", nargs="+", metavar="OLD:=NEW", help="publish a topic under another name")
    p.add_argument("--paused", action="store_true", help="start paused (space resumes, s steps)")
    p.add_argument("--bind", help="publisher endpoint (default tcp://127.0.0.1:<free port>)")
    p.add_argument("--insecure", action="store_true", help="allow --bind beyond loopback (plaintext, no keys)")
    p.add_argument("--no-wait", action="store_true", help="start at once instead of at the first subscriber")
    p.add_argument("--stay", action="store_true", help="keep running at the end (seek/restart from the keys)")
    p.add_argument("--realtime", action="store_true",
                   help="real-time scheduling (SCHED_FIFO) for steady timing on a busy machine")
    p.add_argument("--master", help="serve the manifest here (default $MOCAPGRAPH_MASTER) when no graph does")
    p.add_argument("--no-manifest", action="store_true", help="do not serve a manifest")
    p.add_argument("-q", "--quiet", action="store_true", help="no status lines when not on a terminal")
    p.set_defaults(func=cmd_play)

    p = bs.add_parser("info", help="duration, topics, types, counts, rates, gaps and metadata of a bag")
    p.add_argument("file")
    p.add_argument("--fast", action="store_true", help="index only: no scan for gaps")
    p.add_argument("--json", action="store_true")
    p.add_argument("-v", "--verbose", action="store_true", help="show long metadata in full")
    p.set_defaults(func=cmd_info)

    p = bs.add_parser("convert", help="C3D/TRC/BVH/Kinect CSV -> bag, or bag -> CSV/TRC/C3D/BVH")
    p.add_argument("input", metavar="IN", help="C3D, TRC, BVH or Kinect CSV file, or a bag (.mcap)")
    p.add_argument("legacy_output", nargs="?", help=argparse.SUPPRESS)  # the old positional OUT, still read
    p.add_argument("-o", "--output", metavar="OUT", help="the bag to write, or CSV/TRC/C3D/BVH from a bag")
    p.add_argument("--topic", help="bag topic to export (default: the only one of the right type)")
    p.add_argument("--units", choices=["mm", "m", "cm"], default="mm", help="TRC/C3D output units")
    p.add_argument("--compression", choices=["lz4", "none"], default="lz4")
    p.add_argument("--start-ns", type=int, default=0, help="capture stamp of the first frame, ns")
    p.add_argument("--up", choices=("auto", "y", "z"), default="auto", type=str.lower,
                   help="a C3D/TRC input's up axis, made world Z (auto: POINT:Y_SCREEN, else Z; TRC: Y)")
    p.set_defaults(func=cmd_convert)

    p = bs.add_parser("recover", help="save every whole chunk of a truncated or unfinished bag")
    p.add_argument("file")
    p.add_argument("-o", "--output", help="new bag (default <name>.recovered.mcap)")
    p.add_argument("-f", "--force", action="store_true", help="overwrite an existing output file")
    p.set_defaults(func=cmd_recover)

    from .foxglove_cmds import register_bag as register_foxglove
    register_foxglove(bs)
