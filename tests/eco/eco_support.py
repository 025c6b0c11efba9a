"""Helpers of the ecosystem tests: the procedural performer and the marker pattern, wherever
the house keeps them (``mocapgraph/testing/`` after the house refactor, ``nodes/`` before)."""
from __future__ import annotations

try:
    from mocapgraph.testing import marker_pattern as _pattern
    from mocapgraph.testing import viewer_nodes as _stage
except ImportError:
    from mocapgraph.nodes import test_pattern as _pattern
    from mocapgraph.nodes.viewer import testing_nodes as _stage

STAGE_PERFORMER = f"{_stage.__name__}:StagePerformer"
JOINT_NAMES = _stage.JOINT_NAMES
pattern_positions = _pattern.pattern_positions
