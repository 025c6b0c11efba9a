"""The exact skeleton model of a synthetic session: what a perfect calibration would give."""
from __future__ import annotations

import numpy as np

from ..calibration.calibrate import _joint_points
from ..model import JointQuality, ActorModel
from ..solving.rigid import gather_limb_markers
from .actor import SyntheticCapture


def exact_model(cap: SyntheticCapture, layout_name: str) -> ActorModel:
    """The session's true skeleton as a model the frame solver takes (metres, base-pose frame).

    Base markers, joint offsets and base joint centres are the capture's own; bone lengths are
    joint to parent joint in the base pose; quality says "exact" (no residual, every joint reliable).
    """
    sk = cap.skeleton
    J, L = sk.n_joints, sk.n_limbs
    idx = np.asarray(sk.limb_marker_index(), dtype=np.int64)
    parent = np.asarray(sk.joint_parent, dtype=np.int64)
    base = cap.base_joint_centres
    bone = np.full(J, np.nan)
    has = parent >= 0
    bone[has] = np.linalg.norm(base[has] - base[parent[has]], axis=1)
    hinge = np.asarray(sk.joint_hinge, dtype=bool)
    axes = np.where(hinge[:, None], cap.joint_dof_axes[:, 0, :], np.nan) if J else np.zeros((0, 3))
    return ActorModel(
        layout=layout_name, marker_labels=tuple(sk.marker_labels), limb_names=tuple(sk.limb_names),
        limb_parent=np.asarray(sk.limb_parent, dtype=np.int64), limb_markers=idx,
        joint_names=tuple(sk.joint_names), joint_limbs=np.asarray(sk.joint_limbs, dtype=np.int64).reshape(J, 2),
        joint_parent=parent, joint_hinge=hinge, base_markers=cap.base_markers.copy(),
        limb_centroid=np.nanmean(gather_limb_markers(cap.base_markers, idx), axis=1),
        offsets=cap.joint_offsets.copy(), joint_base=base.copy(), bone_length=bone, hinge_axis=axes,
        limb_rms=np.zeros(L),
        quality=JointQuality(residual_rms=np.zeros(J), range_of_motion=np.full(J, np.nan),
                             n_frames=np.zeros(J, np.int64), outlier_fraction=np.zeros(J),
                             reliable=np.ones(J, bool), method=("exact",) * J),
        warnings=("exact synthetic skeleton, not a calibration",), rate_hz=cap.rate,
        limb_joint_points=_joint_points(sk),
    )
