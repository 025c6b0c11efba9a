"""``mocapgraph device simulate serial|udp|lsl|qtm|natnet`` and ``device replay``: simulated and replayed marker devices."""
from __future__ import annotations

import argparse
import os
import sys

from . import UserError


def _sim(args: argparse.Namespace):
    from ..formats.device_file import DeviceConfigError
    from ..kinematics.layout import LayoutError
    from ..testing.device_simulator import SimulatedDevice

    try:
        return SimulatedDevice(args.layout, args.device, args.rate, args.seed, args.noise_mm,
                               drift_ppm=args.drift_ppm, delay_ms=args.delay_ms)
    except (DeviceConfigError, LayoutError, ValueError) as exc:
        raise UserError(str(exc)) from None


def cmd_serial(args: argparse.Namespace) -> int:
    from ..testing.device_simulator import open_pty, run_serial

    sim = _sim(args)
    if args.port == "pty":
        master, _slave, path = open_pty()
        print(f"simulated {args.protocol} serial device on {path} "
              f"(launch with port:={path} protocol:={args.protocol})", flush=True)
        write = lambda data: os.write(master, data)  # noqa: E731
    else:
        import serial

        try:
            port = serial.Serial(args.port, args.baud, write_timeout=1.0)
        except (serial.SerialException, OSError) as exc:
            raise UserError(f"cannot open {args.port}: {exc}") from None
        write = port.write
        print(f"sending {args.protocol} frames to {args.port}", flush=True)
    try:
        n = run_serial(sim, write, args.protocol, args.count, args.garbage_every, args.seed)
    except OSError as exc:
        raise UserError(f"serial write failed: {exc}") from None
    print(f"sent {n} frames", file=sys.stderr)
    return 0


def cmd_udp(args: argparse.Namespace) -> int:
    from ..testing.device_simulator import run_udp

    sim = _sim(args)
    host, _, port = args.to.rpartition(":")
    print(f"sending {args.protocol} datagrams to {host or '127.0.0.1'}:{port}", flush=True)
    n = run_udp(sim, host or "127.0.0.1", int(port), args.protocol, args.count)
    print(f"sent {n} frames", file=sys.stderr)
    return 0


def cmd_lsl(args: argparse.Namespace) -> int:
    from ..testing.device_simulator import run_lsl

    sim = _sim(args)
    print(f"LSL outlet '{args.name}' ({args.type}): {3 * len(sim.channels)} channels at {args.rate:g} Hz",
          flush=True)
    n = run_lsl(sim, args.name, args.type, args.count)
    print(f"sent {n} frames", file=sys.stderr)
    return 0


def _delay_range(text: str) -> tuple[float, float]:
    try:
        lo, _, hi = text.partition(",")
        out = (float(lo), float(hi or lo))
    except ValueError:
        raise UserError(f"--delay-ms {text!r}: want LO,HI in milliseconds, e.g. 0,20") from None
    if not 0 <= out[0] <= out[1]:
        raise UserError(f"--delay-ms {text!r}: want 0 <= LO <= HI")
    return out


def cmd_qtm(args: argparse.Namespace) -> int:
    from ..bag.errors import BagError
    from ..formats import FormatError
    from ..kinematics.layout import LayoutError
    from ..testing.qtm_server import ActorQTMSource, QTMSimServer, TrialQTMSource

    try:
        if args.file:
            src = TrialQTMSource(args.file, args.axis_up, args.topic or None)
        else:
            src = ActorQTMSource(args.layout, args.rate, args.seed, args.noise_mm, args.bodies, args.axis_up,
                                 occlude_every=args.occlude_every)
        srv = QTMSimServer(src, args.host, args.port, loss=args.loss, seed=args.seed, frames=args.count,
                           bad_every=args.bad_every, restart_every_s=args.restart_every,
                           restart_down_s=args.restart_down, start_frame=args.start_frame,
                           delay_ms=_delay_range(args.delay_ms), drift_ppm=args.drift_ppm)
    except (LayoutError, FormatError, BagError, ValueError) as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:
        raise UserError(f"cannot listen on tcp {args.host}:{args.port}: {exc.strerror or exc}") from None
    print(f"simulated QTM RT server on tcp {args.host}:{srv.port}: {len(src.labels)} labelled markers, "
          f"{len(src.body_names)} 6DOF bodies at {src.rate_hz:g} Hz "
          f"(launch with host:={args.host} port:={srv.port})", flush=True)
    try:
        srv.serve()
    except KeyboardInterrupt:
        pass
    print(f"sent {srv.sent_frames} frames ({srv.lost_frames} dropped, {srv.restarts} restarts)", file=sys.stderr)
    return 0


def _host_port(text: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    try:
        return host or default_host, int(port)
    except ValueError:
        raise UserError(f"{text!r}: expected HOST:PORT") from None


def cmd_natnet(args: argparse.Namespace) -> int:
    from ..bag.errors import BagError
    from ..formats import FormatError
    from ..testing.natnet_server import ActorStream, Faults, simulate

    try:
        version = tuple(int(x) for x in args.natnet.split("."))[:2]
        stream = ActorStream(args.layout, args.rate, args.bodies, seed=args.seed,
                             dropout_rate_hz=args.dropout_hz, noise_mm=args.noise_mm, device=args.device,
                             source=args.file, topic=args.topic, bone_dropout_every=args.bone_dropout_every,
                             skeleton=not args.no_skeleton, skeleton_local=args.skeleton_local)
        faults = Faults(args.loss, args.restart_after, args.restart_gap, args.seed, delay_ms=(0.0, args.delay_ms),
                        drift_ppm=args.drift_ppm)
    except (ValueError, OSError, FormatError, BagError) as exc:
        raise UserError(f"natnet simulator: {exc}") from None
    mode = f"multicast {args.multicast_group}:{args.data_port}" if args.multicast_group else "unicast"

    def ready(server) -> None:
        print(f"NatNet {args.natnet} server (Motive simulator) on {args.host}:{server.command_port}, {mode}, "
              f"{len(stream.labels)} markers + {stream.n_bodies} rigid bodies"
              + (f" + a skeleton of {len(stream.bone_names)} bones" if stream.bone_names else "")
              + f" at {stream.rate_hz:g} Hz"
              + (f" from {args.file}" if args.file else ""), flush=True)

    try:
        n = simulate(stream, version, args.host, args.port, args.multicast_group, args.data_port, args.count,
                     faults, on_ready=ready, wait_s=args.wait)
    except OSError as exc:
        raise UserError(f"natnet simulator: {args.host}:{args.port}: {exc.strerror or exc}") from None
    print(f"sent {n} frames, dropped {len(faults.dropped)}", file=sys.stderr)
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from ..testing.natnet_server import NatNetServer, capture_packets, paced_send, wait_until_ready
    from ..testing.pcapng import PcapngError

    try:
        info, defs, frames = capture_packets(args.file)
    except ValueError as exc:
        if isinstance(exc, PcapngError):
            raise UserError(str(exc)) from None
        return _replay_qtm(args, str(exc))
    except OSError as exc:
        raise UserError(str(exc)) from None
    port = 1510 if args.port is None else args.port
    targets = [_host_port(t) for t in args.to]
    try:
        server = NatNetServer(info, defs, args.host, port, targets=targets)
    except OSError as exc:
        raise UserError(f"replay: cannot serve on {args.host}:{port}: {exc.strerror or exc}") from None
    span = frames[-1][0] - frames[0][0]
    print(f"replaying {len(frames)} NatNet frames ({span:.1f} s) from {args.file} x{args.speed:g}; command "
          f"channel on {args.host}:{server.command_port}", flush=True)
    if targets:
        for packet in (info, defs):
            server.send(packet)
    elif not wait_until_ready(server, args.wait):
        server.close()
        raise UserError(f"replay: no reader connected to {args.host}:{server.command_port} in {args.wait:g} s")
    n = paced_send(server, iter(frames), args.speed)
    server.close()
    print(f"sent {n} frames", file=sys.stderr)
    return 0


def _replay_qtm(args: argparse.Namespace, not_natnet: str) -> int:
    """``device replay`` of a capture holding a QTM RT session (TCP) rather than NatNet."""
    from ..testing.qtm_replay import QTM_PORT, QTMReplayServer, capture_qtm

    try:
        cap = capture_qtm(args.file)
    except (ValueError, OSError) as exc:
        raise UserError(f"{not_natnet}; {exc}") from None
    if args.to:
        raise UserError("replay: --to sends NatNet datagrams; a QTM session is served over TCP to a reader that "
                        "connects (qtm_reader port:=...)")
    port = QTM_PORT if args.port is None else args.port
    try:
        server = QTMReplayServer(cap, args.host, port, args.speed)
    except OSError as exc:
        raise UserError(f"replay: cannot listen on tcp {args.host}:{port}: {exc.strerror or exc}") from None
    span = cap.frames[-1][0] - cap.frames[0][0]
    print(f"replaying {len(cap.frames)} QTM frames ({span:.1f} s) from {args.file} x{args.speed:g}; QTM RT on tcp "
          f"{args.host}:{server.port} (launch with host:={args.host} port:={server.port})", flush=True)
    n = server.serve(timeout_s=args.wait + (span / args.speed if args.speed > 0 else 0.0) + 5.0)
    server.close()
    if not n:
        raise UserError(f"replay: no reader streamed from tcp {args.host}:{server.port} in {args.wait:g} s")
    print(f"sent {n} frames", file=sys.stderr)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    d = sub.add_parser("device", help="simulated marker devices for trying lab graphs without hardware")
    ds = d.add_subparsers(dest="device_command", required=True)
    sim = ds.add_parser("simulate", help="send a synthetic performer (or a recording) as a serial, UDP, LSL, "
                                         "QTM or NatNet device")
    ss = sim.add_subparsers(dest="transport", required=True)

    def common(p: argparse.ArgumentParser, device: str) -> None:
        p.add_argument("--layout", default="plug_in_gait", help="marker layout worn by the performer")
        p.add_argument("--device", default=device, help="device file (channel order, frame, units); '' = world")
        p.add_argument("--rate", type=float, default=120.0, help="frames per second")
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--noise-mm", type=float, default=0.0, help="marker noise, mm")
        p.add_argument("--count", type=int, default=0, help="frames to send (0 = until Ctrl-C)")
        p.add_argument("--drift-ppm", type=float, default=0.0, help="the device clock runs this fast, ppm")
        p.add_argument("--delay-ms", type=float, default=0.0,
                       help="each frame leaves 0..this late (uniform, per frame: frames may overtake)")

    s = ss.add_parser("serial", help="wire protocol on a serial port, or on a new pseudo-terminal")
    s.add_argument("--port", default="pty", help="serial port to write to, or 'pty' to create one")
    s.add_argument("--baud", type=int, default=115200)
    s.add_argument("--protocol", choices=["text", "binary"], default="text")
    s.add_argument("--garbage-every", type=int, default=0, help="random bytes before every Nth frame")
    common(s, "example_serial_bridge")
    s.set_defaults(func=cmd_serial)
    u = ss.add_parser("udp", help="one datagram per frame")
    u.add_argument("--to", default="127.0.0.1:9870", help="host:port of the udp_reader")
    u.add_argument("--protocol", choices=["text", "binary"], default="binary")
    common(u, "example_udp_bridge")
    u.set_defaults(func=cmd_udp)
    lsl = ss.add_parser("lsl", help="a LabStreamingLayer outlet, x y z per marker")
    lsl.add_argument("--name", default="mocapgraph_sim", help="stream name")
    lsl.add_argument("--type", default="Mocap", help="stream type")
    common(lsl, "example_lsl_mocap")
    lsl.set_defaults(func=cmd_lsl)
    qtm = ss.add_parser("qtm", help="a Qualisys QTM real-time server (TCP, protocol 1.19-1.26)")
    qtm.add_argument("--host", default="127.0.0.1", help="address to listen on")
    qtm.add_argument("--port", type=int, default=22223, help="TCP port (QTM's little-endian port: 22223)")
    qtm.add_argument("--bodies", type=int, default=5, help="6DOF bodies (the actor's first limbs)")
    qtm.add_argument("--axis-up", default="+Z", help="QTM's up axis (The_3D/AxisUpwards)")
    qtm.add_argument("--loss", type=float, default=0.0, help="fraction of frames QTM skips")
    qtm.add_argument("--bad-every", type=int, default=0, help="a malformed data packet every Nth frame")
    qtm.add_argument("--occlude-every", type=int, default=0, help="one marker and one body unseen every Nth frame")
    qtm.add_argument("--restart-every", type=float, default=0.0, help="QTM restarts every S seconds (0 = never)")
    qtm.add_argument("--restart-down", type=float, default=1.0, help="seconds the port stays closed on a restart")
    qtm.add_argument("--start-frame", type=int, default=0, help="first frame of the actor's session")
    qtm.add_argument("--delay-ms", default="0,0", help="each frame held back a random LO,HI milliseconds")
    qtm.add_argument("--drift-ppm", type=float, default=0.0, help="QTM's clock runs this many ppm fast")
    qtm.add_argument("--file", default="", help="stream this C3D, TRC or bag's markers instead of the synthetic actor")
    qtm.add_argument("--topic", default="", help="the bag's MarkerFrame topic ('' = its only one)")
    qtm.add_argument("--layout", default="plug_in_gait", help="marker layout worn by the performer")
    qtm.add_argument("--rate", type=float, default=120.0, help="frames per second")
    qtm.add_argument("--seed", type=int, default=0)
    qtm.add_argument("--noise-mm", type=float, default=0.0, help="marker noise, mm")
    qtm.add_argument("--count", type=int, default=0, help="frames in the measurement, then 'no more data' (0 = endless)")
    qtm.set_defaults(func=cmd_qtm)
    nat = ss.add_parser("natnet", help="an OptiTrack Motive NatNet server (command + data channels)")
    nat.add_argument("--natnet", default="4.1", choices=["3.0", "4.0", "4.1", "4.2"], help="NatNet bitstream version")
    nat.add_argument("--host", default="127.0.0.1", help="address to serve on")
    nat.add_argument("--port", type=int, default=1510, help="command port (0 = any free one)")
    nat.add_argument("--multicast-group", default="", help="send frames to this group too (e.g. 239.255.42.99)")
    nat.add_argument("--data-port", type=int, default=1511, help="multicast data port")
    nat.add_argument("--bodies", type=int, default=5, help="limbs streamed as rigid bodies")
    nat.add_argument("--dropout-hz", type=float, default=0.0, help="marker occlusions per marker per second")
    nat.add_argument("--loss", type=float, default=0.0, help="fraction of frames never sent (seeded)")
    nat.add_argument("--restart-after", type=int, default=0, help="restart the server after N frames (0 = never)")
    nat.add_argument("--restart-gap", type=float, default=2.0, help="seconds the restarted server is gone")
    nat.add_argument("--file", default="", help="stream this C3D, TRC or bag's markers instead of the synthetic actor")
    nat.add_argument("--topic", default="", help="the bag's MarkerFrame topic ('' = its only one)")
    nat.add_argument("--bone-dropout-every", type=int, default=0, help="one skeleton bone untracked every Nth frame")
    nat.add_argument("--no-skeleton", action="store_true", help="the actor's skeleton asset without bones")
    nat.add_argument("--skeleton-local", action="store_true",
                     help="bones relative to their parent (Motive's 'Local' skeleton coordinates)")
    nat.add_argument("--wait", type=float, default=0.0,
                     help="wait up to this many seconds for a reader to connect before streaming (0 = stream at once)")
    common(nat, "")
    nat.set_defaults(func=cmd_natnet)
    rep = ds.add_parser("replay", help="replay a NatNet (UDP) or QTM RT (TCP) pcapng capture to a reader at its "
                                       "original timing")
    rep.add_argument("file", help="a .pcapng capture of a NatNet or QTM RT session")
    rep.add_argument("--host", default="127.0.0.1", help="address to serve the command channel on")
    rep.add_argument("--port", type=int, default=None,
                     help="port readers connect to: NatNet's command port (1510), QTM's (22223); 0 = any")
    rep.add_argument("--to", action="append", default=[], metavar="HOST:PORT",
                     help="also send every packet here, without waiting for a reader to connect")
    rep.add_argument("--speed", type=float, default=1.0, help="2 = twice as fast, 0 = as fast as possible")
    rep.add_argument("--wait", type=float, default=30.0, help="seconds to wait for a reader to connect")
    rep.set_defaults(func=cmd_replay)
