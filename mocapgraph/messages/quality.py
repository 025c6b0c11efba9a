"""The quality codes carried as int8 next to NaN-able values (joints, limbs, markers): defined once.

This module imports nothing, so the math (kinematics/) uses the same codes without the bus.
"""
from __future__ import annotations

from enum import IntEnum


class Quality(IntEnum):
    """Per joint / limb / marker quality code."""

    MISSING = 0    # no value (NaN)
    ESTIMATED = 1  # from fewer limbs than usual, a poor fit, or predicted over a short gap
    GOOD = 2       # measured from every attached limb


QUALITY_MISSING = int(Quality.MISSING)
QUALITY_ESTIMATED = int(Quality.ESTIMATED)
QUALITY_GOOD = int(Quality.GOOD)
