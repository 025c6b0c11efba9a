"""The compiled plan's builder: every field of frame_plan.FIELDS is filled from its own slot of the
tuple, and a plan missing a field or given the wrong number of dims is refused in one line."""
from __future__ import annotations

import ast
import inspect

import numpy as np
import pytest

from mocapgraph.retarget import frame_plan


def test_fill_assigns_each_field_from_its_own_position() -> None:
    """A swapped pair of lines in ``_fill`` (two fields of one type) would compile and run wrong."""
    tree = ast.parse(inspect.getsource(frame_plan))
    fill = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "_fill")
    assigned = [(s.targets[0].attr, s.value.slice.value) for s in fill.body
                if isinstance(s, ast.Assign) and isinstance(s.targets[0], ast.Attribute)]
    wanted = [(name, i) for i, (name, _, _) in enumerate(frame_plan.FIELDS)]
    assert assigned == wanted


def test_build_refuses_a_missing_field_and_wrong_dims() -> None:
    values = {name: (dtype(0) if dims == 0 else np.zeros((1,) * dims, dtype)) for name, dtype, dims in frame_plan.FIELDS}
    assert isinstance(frame_plan.build(values), frame_plan.FramePlan)
    with pytest.raises(ValueError, match="no value for K"):
        frame_plan.build({k: v for k, v in values.items() if k != "K"})
    with pytest.raises(ValueError, match="K has 2 dims, 3 wanted"):
        frame_plan.build({**values, "K": np.zeros((2, 4))})
