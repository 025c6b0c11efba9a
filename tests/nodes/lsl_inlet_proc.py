"""A plain pylsl inlet in its own process, as LabRecorder would open one: resolves a stream by
name, reads its description and pulls samples; writes what it got to an .npz file.

usage: python lsl_inlet_proc.py NAME N_SAMPLES OUT.npz READY_FILE
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import pylsl


def main() -> int:
    name, n, out, ready = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3]), Path(sys.argv[4])
    found = pylsl.resolve_byprop("name", name, 1, 30.0)
    if not found:
        print(f"no stream {name}", file=sys.stderr)
        return 1
    inlet = pylsl.StreamInlet(found[0], max_buflen=60)
    info = inlet.info(timeout=10.0)
    chans, ch = [], info.desc().child("channels").child("channel")
    while not ch.empty():
        chans.append({k: ch.child_value(k) for k in ("label", "type", "unit", "marker", "joint")})
        ch = ch.next_sibling()
    inlet.open_stream(timeout=10.0)
    ready.write_text("ready")
    samples, stamps = [], []
    t_end = time.monotonic() + 60
    while len(samples) < n and time.monotonic() < t_end:
        chunk, ts = inlet.pull_chunk(timeout=0.5, max_samples=1024)
        samples += chunk
        stamps += ts
    meta = {"name": info.name(), "type": info.type(), "rate": info.nominal_srate(), "channels": chans,
            "format": info.channel_format(),
            "frame": info.desc().child("reference").child_value("frame"), "clock_now": pylsl.local_clock()}
    np.savez(out, samples=np.array(samples[:n], float), stamps=np.array(stamps[:n]), meta=json.dumps(meta))
    return 0


if __name__ == "__main__":
    sys.exit(main())
