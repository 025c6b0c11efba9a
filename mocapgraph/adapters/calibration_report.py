"""What the calibration node reports: its status message, a calibrated model's report, a failed search.

Pure text and JSON built from kinematics results (no bus): the node only publishes them. Units
in the report are those of :func:`~mocapgraph.adapters.model_messages.quality_report` (mm, deg).
"""
from __future__ import annotations

import json
import math
from typing import Any, Sequence

import numpy as np

from ..kinematics.calibration.capture_steps import BasePoseFinder
from ..kinematics.model import ActorModel
from ..messages import NodeStatus
from .model_messages import jsonable, quality_report


def status_message(node: str, state: str, detail: str, progress: float = math.nan,
                   data: dict[str, Any] | None = None) -> NodeStatus:
    """The ``calibration_status`` message: state, one-line detail, progress 0..1 (NaN: none) and
    ``data`` as strict JSON (NaN -> null)."""
    return NodeStatus(node=node, state=state, detail=detail, progress=progress,
                      data_json=json.dumps(jsonable(data or {})))


def model_report(model: ActorModel, min_rom_deg: float, origin: str, path: str,
                 base_frame: int) -> tuple[str, dict[str, Any]]:
    """(one-line detail, per-joint report) for a model just calibrated or loaded.

    ``origin`` is "calibration" or "loaded PATH"; ``path`` the model file ('' if none). The
    detail names the joints calibration calls unreliable (too little motion).
    """
    report = quality_report(model, min_rom_deg)
    report.update(origin=origin, model_file=path, base_frame=base_frame)
    weak = [j["joint"] for j in report["joints"] if not j["reliable"]]
    detail = f"{origin}: {len(model.joint_names)} joints"
    if path and origin == "calibration":
        detail += f", saved to {path}"
    if weak:
        detail += f"; unreliable (too little motion or too uncertain): {', '.join(weak)}"
    return detail, report


def base_pose_failure(finder: BasePoseFinder, labels: Sequence[str]) -> tuple[str, dict[str, Any]]:
    """(detail, data) of a base-pose search that timed out: the markers never visible, else those
    missing from the most complete frame. ``labels`` are the layout's markers, finder order."""
    never = [labels[m] for m in np.flatnonzero(finder.never_seen)]
    span = f"{finder.timeout_s:g} s of capture"
    if never:
        return (f"no base pose in {span}: markers never visible: {', '.join(never)}",
                {"never_visible": never})
    worst = [labels[m] for m in np.flatnonzero(finder.best_missing)]
    return (f"no base pose in {span}: no frame shows all markers at once "
            f"(the best lacks {', '.join(worst)})", {"best_frame_missing": worst})


def stalled_search(layout_seen: bool, timeout_s: float) -> str:
    """The error of a base-pose search that got no usable frame within ``timeout_s`` wall time."""
    why = "no marker frames received" if layout_seen else "no marker_layout received"
    return f"no base pose: {why} within {timeout_s:g} s"


def gym_detail(seconds: float, rate_hz: float) -> str:
    """The detail line of a gym capture under way."""
    if rate_hz:
        return f"capturing {seconds:g} s of gym at {rate_hz:g} frames/s"
    return f"capturing {seconds:g} s of gym"
