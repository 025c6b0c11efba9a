"""Marker columns of a recorded input put in a calibrated model's marker order, for solving a file.

The batch commands (``mocapgraph solve``, ``mocapgraph retarget`` on markers) read a C3D, TRC or
bag, then need float[T, M, 3] in the model's marker order (NaN where a marker is absent). Positions
in metres, world frame (Z up), as :class:`mocapgraph.bag.sources.MarkerInput` holds them.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..kinematics.labels import missing_labels, place_labels
from ..kinematics.model import ModelFileError
from .model_messages import marker_index

if TYPE_CHECKING:   # annotations only
    from ..bag.sources import MarkerInput
    from ..kinematics.model import ActorModel


def place_markers(model: "ActorModel", inp: "MarkerInput", allow_missing: bool) -> tuple[np.ndarray, list[str]]:
    """Model marker -> input column (-1 absent) and the labels absent from the input.

    ModelFileError (one line) for another layout or absent markers unless ``allow_missing`` (and at
    least one marker present): then the absent ones are listed and stay missing in every frame.
    """
    try:
        return marker_index(model, inp.layout_name, inp.labels, source=inp.path.name), []
    except ModelFileError:
        where, _ = place_labels(model.marker_labels, inp.labels)
        if not allow_missing or not (where >= 0).any():
            raise
        return where, missing_labels(model.marker_labels, where)


def model_order(inp: "MarkerInput", where: np.ndarray) -> np.ndarray:
    """float[T, M, 3] m: the input's columns in the model's marker order (``where`` from
    :func:`place_markers`), NaN for a marker the input lacks."""
    x = np.concatenate([inp.positions, np.full(inp.positions.shape[:1] + (1, 3), np.nan)], axis=1)
    return x[:, np.where(where >= 0, where, inp.positions.shape[1])]
