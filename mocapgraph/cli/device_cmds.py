"""``mocapgraph device simulate serial|udp|lsl``: a synthetic performer as a marker device."""
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


def register(sub: argparse._SubParsersAction) -> None:
    d = sub.add_parser("device", help="simulated marker devices for trying lab graphs without hardware")
    ds = d.add_subparsers(dest="device_command", required=True)
    sim = ds.add_parser("simulate", help="send a synthetic performer as a serial, UDP or LSL device")
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
