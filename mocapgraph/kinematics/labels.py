"""Placing a capture's marker labels on a layout's or model's markers: the one matching rule."""
from __future__ import annotations

from typing import Sequence

import numpy as np


def place_labels(wanted: Sequence[str], labels: Sequence[str]) -> tuple[np.ndarray, list[str]]:
    """For each wanted marker its index in ``labels`` (-1 if absent), and the labels left unplaced.

    Case-insensitive; a label also matches after dropping a ``Subject:`` prefix (Vicon) and
    surrounding spaces. A label is unplaced when it is unknown or a second one for a marker
    already placed. Returns (int64[len(wanted)], list of labels).
    """
    want = {str(m).lower(): k for k, m in enumerate(wanted)}
    idx = np.full(len(wanted), -1, dtype=np.int64)
    unplaced: list[str] = []
    for i, lab in enumerate(labels):
        s = str(lab).strip()
        k = want.get(s.lower())
        if k is None and ":" in s:
            k = want.get(s.rsplit(":", 1)[1].strip().lower())
        if k is None or idx[k] >= 0:
            unplaced.append(lab)
        else:
            idx[k] = i
    return idx, unplaced


def missing_labels(wanted: Sequence[str], where: np.ndarray) -> list[str]:
    """The wanted markers that ``place_labels`` found no label for."""
    return [wanted[m] for m in np.flatnonzero(np.asarray(where) < 0)]
