"""Runs OptiTrack's natnetsdk client (unicast) against a NatNet server and writes what it decoded as JSON.

Usage: python tests/natnet_sdk_client.py SERVER_PORT FRAMES OUT.json [TIMEOUT_S]. A process of its
own, left with os._exit: natnetsdk's receive threads are not daemons and its shutdown() blocks
while no packet arrives, so a test process that ran it in-process could hang at exit."""
from __future__ import annotations

import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from natnetsdk.NatNetClient import NatNetClient  # noqa: E402

from tests.natnet_sdk import sdk_values  # noqa: E402


def main() -> None:
    port, want, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    timeout = float(sys.argv[4]) if len(sys.argv) > 4 else 15.0
    frames: list[dict] = []
    unpack = NatNetClient._NatNetClient__unpack_mocap_data

    def recording(self, data, packet_size, major, minor):
        offset, m = unpack(self, data, packet_size, major, minor)
        frames.append(sdk_values(m))
        return offset, m

    NatNetClient._NatNetClient__unpack_mocap_data = recording
    c = NatNetClient()
    c.set_use_multicast(False)
    c.set_server_address("127.0.0.1")
    c.set_client_address("127.0.0.1")
    c.command_port = port
    real_stdout, sys.stdout = sys.stdout, open(os.devnull, "w")  # it prints every frame
    c.run()
    end = time.monotonic() + timeout
    while len(frames) < want and time.monotonic() < end:
        time.sleep(0.01)
    result = {"connected": c.connected(), "app": c.get_application_name(),
              "version": list(c.get_nat_net_version_server()), "frames": frames[:want]}
    with open(out, "w") as fh:
        json.dump(result, fh)
    real_stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    main()
