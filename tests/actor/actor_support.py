"""Helpers of the actor tests: JSON-lines logs, waiting on conditions, small models."""
from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import numpy as np

from mocapgraph.kinematics.calibration.calibrate import CalibrationWarning, calibrate
from mocapgraph.kinematics.model import ActorModel
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from mocapgraph.kinematics.synthetic.motion import MotionScript

from graph_helpers import read_jsonl, wait_until  # noqa: F401  (re-exported to the actor tests)

#: the test source node, by the file that holds it (the graph check loads only files a graph names)
ACTOR_SOURCE = f"{Path(__file__).resolve().parent / 'actor_source.py'}:ActorSource"
PIPELINE = Path(__file__).resolve().parents[2] / "graph_configs" / "actor_pipeline.yaml"


def statuses(path: Path, node: str | None = None) -> list[dict]:
    return [r["msg"] for r in read_jsonl(path, "calibration_status") if node is None or r["msg"]["node"] == node]


def states(path: Path, node: str | None = None) -> list[str]:
    """The sequence of distinct consecutive states a calibration node reported."""
    out: list[str] = []
    for m in statuses(path, node):
        if not out or out[-1] != m["state"]:
            out.append(m["state"])
    return out


def poses(path: Path, topic: str = "actor_pose") -> dict[int, dict]:
    return {r["msg"]["frame_number"]: r["msg"] for r in read_jsonl(path, topic)}


def joints(recs: dict[int, dict], frames) -> np.ndarray:
    """float[T,J,3] joint positions (None -> NaN) of the given frames."""
    return np.array([[[np.nan if v is None else v for v in p] for p in recs[f]["joint_positions"]]
                     for f in frames], dtype=float)


def quick_model(layout: str, seed: int = 0) -> ActorModel:
    """A model calibrated (kinematics only) from a short synthetic gym of ``layout``."""
    cap = SyntheticActor(layout, rate=60.0, seed=seed, script=MotionScript(gym_block_s=1.0),
                         options=CaptureOptions(noise_mm=1.0)).capture(0, 300)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        return calibrate(cap.skeleton, cap.markers, rate_hz=60.0)
