"""Compiles every retargeting kernel once, through the code that calls them (the jit warm-up).

The kernels' argument types are those the retargeter builds (packed constants, plant state, the
actor's arrays as decoded from a message), so the warm-up runs the real callers on a small
character rather than guessing signatures. It lives above both kernel modules and the retargeter
so that the kernels import nothing of the code that calls them. `mocapgraph.jit.KERNEL_MODULES`
names these functions as the warm-up of ``kernels`` and ``source_kernels``.
"""
from __future__ import annotations

import numpy as np

from . import kernels
from .character import standard_20
from .mapping import derive_mapping
from .retargeter import RetargetOptions, Retargeter
from .source import plan_point_rotations, rotations_from_points_frame, skeleton_source


def warm_frame_kernels() -> None:
    """Compile the one-frame kernels (a standard_20 frame, with and without foot planting) and cache them."""
    ch = standard_20(1.75)
    pos, _ = ch.forward_kinematics()
    src = skeleton_source(list(ch.joint_names), ch.parents, ch.rest_offsets, has_orientations=True)
    for planting in (False, True):
        rt = Retargeter(ch, derive_mapping(ch, src), src, RetargetOptions(foot_planting=planting))
        q = np.tile([1.0, 0.0, 0.0, 0.0], (1, ch.n_joints, 1))
        for f in range(3):
            rt.process(pos[None], None, q, None, f / 240.0)
    kernels.load()   # the actor frame (compiled by signature) and the bone-follow flag
    # the node's point layout, on arrays as decoded from a message (read-only views) and plain ones
    jp, jq = np.zeros((3, 3)), np.full(3, 2, np.int8)
    jp.flags.writeable = False
    jq.flags.writeable = False
    for p, q in ((jp, jq), (jp.copy(), jq.copy())):
        kernels.optical_frame(p, q, np.array([0, 1], np.int64), np.empty((4, 3)), np.empty(4, np.bool_))


def warm_source_kernels() -> None:
    """Compile (and cache) the rotations-from-points kernel on a seven-point source with every kind
    of joint, for writable points and for read-only ones (a live frame decoded from a message buffer)."""
    offs = np.array([[0.0, 0, 1], [0, 0, 0.5], [0, 0.2, 0], [0, -0.2, 0.05], [0, 0, 0.4], [0.1, 0, 0.2], [0, 0, -0.4]])
    src = skeleton_source(list("rabcdef"), [-1, 0, 0, 0, 1, 1, 2], offs, has_orientations=False)
    plan = plan_point_rotations(src)
    frozen = src.rest_points.copy()
    frozen.flags.writeable = False
    for p in (src.rest_points, frozen):
        rotations_from_points_frame(plan, p)
