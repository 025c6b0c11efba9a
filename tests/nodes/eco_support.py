"""Helpers of the outlet tests: the procedural performer and the marker pattern (``mocapgraph/testing/``)."""
from __future__ import annotations

from mocapgraph.testing import marker_pattern as _pattern
from mocapgraph.testing import viewer_nodes as _stage

STAGE_PERFORMER = f"{_stage.__name__}:StagePerformer"
JOINT_NAMES = _stage.JOINT_NAMES
pattern_positions = _pattern.pattern_positions
