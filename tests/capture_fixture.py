"""Files the ecosystem tests share: a synthetic capture (gym + performance) with ground truth,
written as TRC and as a bag, and the model calibrated from it by the real command."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from mocapgraph.bag.convert import file_to_bag
from mocapgraph.cli import main
from mocapgraph.formats import MarkerTrial, write_trc
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from mocapgraph.kinematics.synthetic.motion import MotionScript

RATE = 60.0


@dataclass
class Capture:
    folder: Path
    rom: Path           # gym TRC
    trial: Path         # performance TRC
    rom_bag: Path       # the gym as a bag (markers + latched layout)
    model: Path         # model JSON from `mocapgraph calibrate`
    labels: list[str]
    markers: np.ndarray  # float[T,M,3] of the gym, m


@pytest.fixture(scope="session")
def capture(tmp_path_factory) -> Capture:
    d = tmp_path_factory.mktemp("eco")
    cap = SyntheticActor("kiip_full_body", rate=RATE, seed=3, script=MotionScript(gym_block_s=1.0),
                         options=CaptureOptions(noise_mm=1.0)).capture(0, 600)
    labels = list(cap.skeleton.marker_labels)
    gym_end = cap.phases["gym"][1]
    write_trc(d / "rom.trc", MarkerTrial(labels=labels, positions=cap.markers[:gym_end], residuals=None, rate_hz=RATE))
    write_trc(d / "trial.trc", MarkerTrial(labels=labels, positions=cap.markers[gym_end:], residuals=None,
                                           rate_hz=RATE))
    file_to_bag(d / "rom.trc", d / "rom.mcap")
    assert main(["calibrate", str(d / "rom.trc"), "--layout", "kiip_full_body", "-o", str(d / "model.json")]) == 0
    return Capture(d, d / "rom.trc", d / "trial.trc", d / "rom.mcap", d / "model.json", labels,
                   cap.markers[:gym_end])
