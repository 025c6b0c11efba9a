"""`bag play --loop` of a bag whose latched message was published long before the recording."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapgraph.bag.player import Playback
from mocapgraph.bag.reader import BagReader
from mocapgraph.bag.writer import BagWriter
from mocapgraph.messages import MarkerFrame, MarkerLayout

T0 = 1_700_000_000_000_000_000


def test_a_latched_value_from_before_the_recording_neither_stretches_duration_nor_silences_a_pass(tmp_path: Path):
    bag = tmp_path / "late.mcap"
    with BagWriter(str(bag)) as w:
        # the layout was published 31 s before the recorder started (it got it as a latched resend)
        w.write("marker_layout", MarkerLayout(name="ring", labels=["a", "b"], limb_names=[],
                                              marker_limb=np.full(2, -1)),
                seq=1, capture_ns=T0 - 31_000_000_000, publish_ns=T0 - 31_000_000_000, log_ns=T0)
        for i in range(500):  # 5 s at 100 Hz
            t = T0 + 5_000_000 + i * 10_000_000
            w.write("markers", MarkerFrame(frame_number=i, rate_hz=100.0, positions=np.zeros((2, 3)),
                                           valid=np.ones(2, bool), residual=np.zeros(2, np.float32)),
                    seq=i + 1, capture_ns=t, publish_ns=t, log_ns=t + 1_000_000)
    with BagReader(bag) as r:
        pb = Playback(r, loop=True)
        assert abs(pb.duration_s - 5.0) < 0.3, pb.duration_s
        pb.begin()
        stamps = []
        while len(stamps) < 1200 and pb._read_one():  # two passes and a bit
            stamps.append(pb._buf.popleft()[0])
    steps = np.diff(np.asarray(stamps, np.float64)) / 1e9
    print(f"duration {pb.duration_s:.2f} s, longest step between scheduled messages {steps.max():.3f} s, "
          f"loops {pb.loops}")
    assert pb.loops >= 2 and steps.max() < 0.5  # was a 31 s silence per pass
