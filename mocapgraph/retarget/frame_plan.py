"""The compiled live path's plan: one retargeter's folded constants and scratch as one numba struct with named fields.

The one-frame kernels (:mod:`kernels`) read everything that does not change per frame from a
:class:`FramePlan`: Eq 4.1's constant maps, the bone-follow, chain and aim tables, the character's
hierarchy and rest pose, the root's map, the legs for planting, the bone-follow checks, and the
frame's preallocated scratch. A numba structref passes as one pointer (about 0.7 us a call, where
seventy arrays in a tuple cost about 8 us to unbox), yet each field keeps its name, dtype and shape:
``plan.K`` is Eq 4.1's [n, 4, 4] maps, ``plan.parents`` the character's [J] parents.

:data:`FIELDS` is the one list of the fields (name, dtype, dims); :func:`build` coerces a dict of
arrays to it and fills a plan through the cached kernel :func:`_fill`, whose assignments follow
:data:`FIELDS` in order (a test reads them back by name). Units: metres, seconds, wxyz quaternions,
world frame (Z up).
"""
from __future__ import annotations

import numpy as np
from numba import types
from numba.experimental import structref

from ..jit import kernel

#: (name, dtype, dims) of every field; dims 0 is a scalar. The order is :func:`_fill`'s.
FIELDS: tuple[tuple[str, type, int], ...] = (
    # Eq 4.1: the source rotation of each rotate joint, its dependency levels, its [4, 4] map, its joint
    ("rot_src", np.int64, 1), ("dep_idx", np.int64, 2), ("K", np.float64, 3), ("rot_joint", np.int64, 1),
    # bones following the source bones: the joint, the source points a -> b, the rest bone, the axes map
    ("f_m", np.int64, 1), ("f_a", np.int64, 1), ("f_b", np.int64, 1), ("f_bone", np.float64, 2),
    ("f_A", np.float64, 3),
    # spread chains: ends, joints (CSR), fractions, end-point correction (iterations, points, path, offsets)
    ("c_start", np.int64, 1), ("c_end", np.int64, 1), ("c_jptr", np.int64, 1), ("c_joints", np.int64, 1),
    ("c_frac", np.float64, 1), ("c_iters", np.int64, 1), ("c_correct", np.int64, 1), ("c_end_src", np.int64, 1),
    ("c_pivot_src", np.int64, 1), ("c_A", np.float64, 3), ("c_pptr", np.int64, 1), ("c_path", np.int64, 1),
    ("c_off", np.float64, 2),
    # aimed joints: the joint, its parent-carried delta, the rest bone, source points from -> to, axes map
    ("a_joint", np.int64, 1), ("a_pre", np.int64, 1), ("a_bone", np.float64, 2), ("a_frm", np.int64, 1),
    ("a_to", np.int64, 1), ("a_A", np.float64, 3),
    # world orientations and the root: each joint's driving delta (J: none), rest world orientations
    ("src_ext", np.int64, 1), ("rw_q", np.float64, 2), ("root_src", np.int64, 0), ("root_M", np.float64, 2),
    ("root_c", np.float64, 1), ("root_joint", np.int64, 0), ("root_s", np.float64, 1),
    # the character: parents, an order with parents first, rest offsets (m), inverse rest locals
    ("parents", np.int64, 1), ("order", np.int64, 1), ("offsets", np.float64, 2), ("rl_inv", np.float64, 2),
    # holding: whether source rotations are checked for unit norm (a source with rotations)
    ("check_norm", np.bool_, 0),
    # foot planting: legs (l, r), two-bone lengths, rest ankle and toe heights, the joints a turn moves
    ("has_legs", np.bool_, 0), ("has_toe", np.bool_, 0), ("hip", np.int64, 1), ("knee", np.int64, 1),
    ("ankle", np.int64, 1), ("toe", np.int64, 1), ("l1", np.float64, 1), ("l2", np.float64, 1),
    ("rest_h", np.float64, 1), ("toe_h", np.float64, 1), ("aff", np.int64, 1), ("which", np.int64, 1),
    ("floor_z", np.float64, 0), ("height_m", np.float64, 0), ("speed_mps", np.float64, 0),
    ("release_s", np.float64, 0), ("window_s", np.float64, 0),
    # an optical actor's hips (the pelvis is their mean) and the bone-follow checks
    ("hips", np.int64, 1), ("b_joint", np.int64, 1), ("b_child", np.int64, 1), ("b_a", np.int64, 1),
    ("b_b", np.int64, 1), ("b_A", np.float64, 3), ("b_cos", np.float64, 1),
    # scratch, written every frame
    ("qn", np.float64, 2), ("qk", np.float64, 2), ("dq", np.float64, 2), ("ap", np.float64, 2),
    ("D", np.float64, 2), ("W", np.float64, 2), ("tmp", np.float64, 2), ("ank", np.float64, 2),
    ("toe_z", np.float64, 1), ("target", np.float64, 2), ("speed", np.float64, 1), ("turns", np.float64, 2),
    ("pin", np.float64, 2), ("pin_ok", np.bool_, 1), ("rot_ok", np.bool_, 1),
    # foot planting's source ankles (points, -1: none), the root ratio that scales them; their xy, scratch
    ("src_ankle", np.int64, 1), ("src_scale", np.float64, 0), ("src_xy", np.float64, 2),
)


@structref.register
class FramePlanType(types.StructRef):
    """numba's type of a :class:`FramePlan` (fields as :data:`FIELDS`)."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class FramePlan(structref.StructRefProxy):
    """A retargeter's compiled plan, as Python holds it: pass it to the kernels; built by :func:`build`."""


structref.define_boxing(FramePlanType, FramePlan)


def _numba_type(dtype: type, dims: int) -> types.Type:
    scalar = {np.int64: types.int64, np.float64: types.float64, np.bool_: types.boolean}[dtype]
    return scalar if dims == 0 else types.Array(scalar, dims, "C")


FRAME_PLAN = FramePlanType([(name, _numba_type(dtype, dims)) for name, dtype, dims in FIELDS])


def build(values: dict) -> FramePlan:
    """A plan from ``values`` (every name of :data:`FIELDS`: arrays of the right number of dims, or
    scalars), each copied into a C-contiguous writable array of its field's dtype."""
    missing = [name for name, _, _ in FIELDS if name not in values]
    if missing:
        raise ValueError(f"frame plan: no value for {', '.join(missing)}")
    out = []
    for name, dtype, dims in FIELDS:
        if dims == 0:
            out.append(dtype(values[name]))
            continue
        a = np.array(values[name], dtype=dtype, order="C", copy=True)
        if a.ndim != dims:
            raise ValueError(f"frame plan: {name} has {a.ndim} dims, {dims} wanted")
        out.append(a)
    return _fill(tuple(out))


@kernel
def _fill(x):
    """A new plan with the fields of :data:`FIELDS` from the tuple ``x`` (in that order)."""
    p = structref.new(FRAME_PLAN)
    p.rot_src = x[0]
    p.dep_idx = x[1]
    p.K = x[2]
    p.rot_joint = x[3]
    p.f_m = x[4]
    p.f_a = x[5]
    p.f_b = x[6]
    p.f_bone = x[7]
    p.f_A = x[8]
    p.c_start = x[9]
    p.c_end = x[10]
    p.c_jptr = x[11]
    p.c_joints = x[12]
    p.c_frac = x[13]
    p.c_iters = x[14]
    p.c_correct = x[15]
    p.c_end_src = x[16]
    p.c_pivot_src = x[17]
    p.c_A = x[18]
    p.c_pptr = x[19]
    p.c_path = x[20]
    p.c_off = x[21]
    p.a_joint = x[22]
    p.a_pre = x[23]
    p.a_bone = x[24]
    p.a_frm = x[25]
    p.a_to = x[26]
    p.a_A = x[27]
    p.src_ext = x[28]
    p.rw_q = x[29]
    p.root_src = x[30]
    p.root_M = x[31]
    p.root_c = x[32]
    p.root_joint = x[33]
    p.root_s = x[34]
    p.parents = x[35]
    p.order = x[36]
    p.offsets = x[37]
    p.rl_inv = x[38]
    p.check_norm = x[39]
    p.has_legs = x[40]
    p.has_toe = x[41]
    p.hip = x[42]
    p.knee = x[43]
    p.ankle = x[44]
    p.toe = x[45]
    p.l1 = x[46]
    p.l2 = x[47]
    p.rest_h = x[48]
    p.toe_h = x[49]
    p.aff = x[50]
    p.which = x[51]
    p.floor_z = x[52]
    p.height_m = x[53]
    p.speed_mps = x[54]
    p.release_s = x[55]
    p.window_s = x[56]
    p.hips = x[57]
    p.b_joint = x[58]
    p.b_child = x[59]
    p.b_a = x[60]
    p.b_b = x[61]
    p.b_A = x[62]
    p.b_cos = x[63]
    p.qn = x[64]
    p.qk = x[65]
    p.dq = x[66]
    p.ap = x[67]
    p.D = x[68]
    p.W = x[69]
    p.tmp = x[70]
    p.ank = x[71]
    p.toe_z = x[72]
    p.target = x[73]
    p.speed = x[74]
    p.turns = x[75]
    p.pin = x[76]
    p.pin_ok = x[77]
    p.rot_ok = x[78]
    p.src_ankle = x[79]
    p.src_scale = x[80]
    p.src_xy = x[81]
    return p
