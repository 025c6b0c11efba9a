"""``mocapgraph topic list|info|echo|hz`` against a running graph (found via its manifest)."""
from __future__ import annotations

import argparse
import json
import time

import numpy as np
import zmq

from ..bus.manifest import NoGraphError, fetch_manifest, subscribe, topic_entry
from ..messages import DecodeError, decode, decode_envelope
from ..messages.registry import UnknownTypeError, lookup
from ..messages.sequence import StreamTracker
from . import UserError


def _manifest(args: argparse.Namespace) -> dict:
    try:
        return fetch_manifest(args.master)
    except NoGraphError as exc:
        raise UserError(str(exc)) from None


def _entry(manifest: dict, topic: str) -> dict:
    try:
        return topic_entry(manifest, topic)
    except KeyError as exc:
        raise UserError(exc.args[0]) from None


def cmd_list(args: argparse.Namespace) -> int:
    m = _manifest(args)
    for topic, e in sorted(m["topics"].items()):
        pubs = ",".join(p["node"] for p in e["publishers"])
        print(f"{topic:<24} {e['type']:<16} from {pubs}" if args.verbose else topic)
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    m = _manifest(args)
    e = _entry(m, args.topic)
    print(f"topic: {args.topic}\ntype: {e['type']}")
    print("publishers:")
    for p in e["publishers"]:
        print(f"  {p['node']} at {p['endpoint']}{' (latched)' if p.get('latched') else ''}")
    print("subscribers:")
    for s in e["subscribers"]:
        print(f"  {s['node']} (port {s['port']})")
    try:
        cls = lookup(e["type"])
        print("fields:")
        for name, spec in cls.fields().items():
            kind = getattr(spec, "kind", None) or (f"{spec.dtype}{spec.shape_text()}" if hasattr(spec, "dtype")
                                                   else "list[str]")
            print(f"  {name}: {kind}  {spec.doc}")
    except UnknownTypeError:
        pass
    return 0


def cmd_echo(args: argparse.Namespace) -> int:
    m = _manifest(args)
    _entry(m, args.topic)
    sock = subscribe(m, [args.topic])
    np.set_printoptions(precision=4, suppress=True, threshold=60)
    shown = 0
    deadline = time.monotonic() + args.timeout if args.timeout else None
    while args.count == 0 or shown < args.count:
        if deadline and time.monotonic() > deadline:
            break
        if not sock.poll(200):
            continue
        frames = sock.recv_multipart()
        try:
            env, msg = decode(frames)
        except DecodeError as exc:
            print(f"# skipped a malformed message: {exc}")
            continue
        if args.json:
            print(json.dumps({"seq": env.seq, "sender": env.sender, "capture_ns": env.capture_ns,
                              "type": env.type_name, "msg": msg.to_dict()}), flush=True)
        else:
            print(f"--- {env.topic} [{env.type_name}] seq {env.seq} from {env.sender} "
                  f"capture {env.capture_ns}")
            for name in msg.fields():
                print(f"{name}: {getattr(msg, name)!r}" if not isinstance(getattr(msg, name), np.ndarray)
                      else f"{name}: {getattr(msg, name)}")
            print(flush=True)
        shown += 1
    sock.close(0)
    return 0


def cmd_hz(args: argparse.Namespace) -> int:
    m = _manifest(args)
    _entry(m, args.topic)
    sock = subscribe(m, [args.topic])
    stamps: list[int] = []
    streams: dict[str, StreamTracker] = {}
    t_end = time.monotonic() + args.duration
    next_report = time.monotonic() + 1.0
    while time.monotonic() < t_end:
        if sock.poll(100):
            try:
                env = decode_envelope(sock.recv_multipart())
            except DecodeError:
                continue
            if env.sender not in streams and len(streams) < 64:   # a few senders; bounded against junk names
                streams[env.sender] = StreamTracker()
            if env.sender in streams:
                streams[env.sender].take(env.stream, env.seq, env.publish_ns)
            stamps.append(env.publish_ns)
            stamps = stamps[-args.window:]
        if time.monotonic() >= next_report:
            next_report += 1.0
            if len(stamps) > 2:
                d = np.diff(np.asarray(stamps, np.float64)) / 1e9
                gaps = sum(t.gaps for t in streams.values())
                print(f"rate {1 / d.mean():.2f} Hz  min {d.min() * 1e3:.3f} ms  max {d.max() * 1e3:.3f} ms  "
                      f"std {d.std() * 1e3:.3f} ms  window {len(stamps)}  gaps {gaps}", flush=True)
            else:
                print("no messages yet", flush=True)
    sock.close(0)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    t = sub.add_parser("topic", help="inspect the topics of a running graph")
    t.add_argument("--master", help="manifest endpoint of the running graph")
    ts = t.add_subparsers(dest="topic_command", required=True)
    p = ts.add_parser("list", help="topics of the running graph")
    p.add_argument("-v", "--verbose", action="store_true", help="with type and publishers")
    p.set_defaults(func=cmd_list)
    p = ts.add_parser("info", help="type, fields, publishers and subscribers of a topic")
    p.add_argument("topic")
    p.set_defaults(func=cmd_info)
    p = ts.add_parser("echo", help="print messages of a topic")
    p.add_argument("topic")
    p.add_argument("-n", "--count", type=int, default=0, help="stop after N messages (0: forever)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.add_argument("--timeout", type=float, default=0.0, help="stop after this many seconds")
    p.set_defaults(func=cmd_echo)
    p = ts.add_parser("hz", help="rate of a topic from sender stamps, with sequence gaps")
    p.add_argument("topic")
    p.add_argument("--window", type=int, default=1000)
    p.add_argument("--duration", type=float, default=1e9, help="seconds to run")
    p.set_defaults(func=cmd_hz)
