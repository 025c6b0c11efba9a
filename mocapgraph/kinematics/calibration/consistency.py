"""Cluster consistency between captures: inter-marker distances of each limb, file against file.

A cluster re-taped between the static and the dynamic trial (a marker moved on the skin) breaks
every offset calibrated in the static's cluster frame, silently. Per limb and marker pair the
median distance in each capture is compared with the first (static) capture; changes over the
tolerance are reported naming the markers, the change and the files.
"""
from __future__ import annotations

import warnings
from typing import Any, Sequence

import numpy as np

TOLERANCE_M = 0.003


def cluster_changes(definition: Any, markers: np.ndarray, parts: Sequence[tuple[str, int]],
                    tol: float = TOLERANCE_M) -> list[str]:
    """One message per limb marker pair whose median distance (m) in a later part of ``markers``
    float[T,M,3] (the parts concatenated in order) differs from the first part by more than tol."""
    # Own markers only: a shared marker rides the next limb and is rigid with this one only on
    # a hinge axis, so its distances change with the joint angle.
    owner = np.asarray(definition.marker_limb)
    rows = [np.flatnonzero(owner == l) for l in range(len(definition.limb_names))]
    labels = definition.marker_labels
    bounds = np.cumsum([0] + [int(n) for _, n in parts])
    out: list[str] = []
    for limb, ks in enumerate(rows):
        if ks.size < 2:
            continue
        i, j = np.triu_indices(ks.size, 1)
        d = np.linalg.norm(markers[:, ks[i]] - markers[:, ks[j]], axis=-1)  # [T,P]
        with warnings.catch_warnings():  # a pair never seen in a part (static-only) is NaN there
            warnings.simplefilter("ignore", RuntimeWarning)
            med = [np.nanmedian(d[a:b], axis=0) if b > a else None for a, b in zip(bounds[:-1], bounds[1:])]
        ref = med[0]
        for part, m in zip(parts[1:], med[1:]):
            if m is None:
                continue
            delta = m - ref
            for p in np.flatnonzero(np.abs(np.nan_to_num(delta)) > tol):
                out.append(f"cluster {definition.limb_names[limb]} changed between {parts[0][0]} and {part[0]}: "
                           f"{labels[ks[i[p]]]}-{labels[ks[j[p]]]} {1000 * ref[p]:.1f} -> {1000 * m[p]:.1f} mm "
                           f"({1000 * delta[p]:+.1f} mm; re-taped or moved marker?)")
    return out
