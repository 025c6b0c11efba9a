"""Virtual arm jig after Kiip section 7.1: clavicle, upper arm, forearm and hand, three markers each.

Pure forward kinematics with exact joint positions, for accuracy tests of calibration and
solving (metres, world Z up). The clavicle's proximal end is fixed in space (``origin``); only
the shoulder, elbow and wrist are joints of the layout.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

ARM_LAYOUT: dict = {
    "name": "arm_jig",
    "description": "Kiip 7.1 virtual arm jig: four limbs, three markers each",
    "limbs": [
        {"name": "clavicle", "markers": ["CL1", "CL2", "CL3"]},
        {"name": "upper_arm", "parent": "clavicle", "joint": {"name": "shoulder", "type": "ball"},
         "markers": ["UA1", "UA2", "UA3"]},
        {"name": "forearm", "parent": "upper_arm", "joint": {"name": "elbow", "type": "ball"},
         "markers": ["FA1", "FA2", "FA3"]},
        {"name": "hand", "parent": "forearm", "joint": {"name": "wrist", "type": "ball"},
         "markers": ["HA1", "HA2", "HA3"]},
    ],
}
BONES = np.array([0.17, 0.30, 0.26, 0.09])  # m, clavicle, upper arm, forearm, hand along local x
# Three locators per limb, rigid in the limb frame (origin at the limb's proximal joint), m.
LOCAL = np.array([
    [[0.04, 0.03, 0.02], [0.10, -0.03, 0.03], [0.14, 0.01, -0.035]],
    [[0.06, 0.045, 0.0], [0.15, -0.02, 0.045], [0.25, 0.0, -0.05]],
    [[0.05, 0.04, 0.01], [0.14, -0.035, 0.03], [0.22, 0.01, -0.045]],
    [[0.03, 0.03, 0.0], [0.07, -0.03, 0.015], [0.10, 0.0, -0.03]],
])
ORIGIN = np.array([0.0, 0.2, 1.4])


def chain(base: np.ndarray, local: np.ndarray) -> np.ndarray:
    """World limb rotations [T,4,3,3]: each limb keeps its base-pose offset from its parent,
    then rotates by ``local[:, l]`` (expressed in its own frame). base: [4,3,3]."""
    world = np.empty_like(local)
    world[:, 0] = base[0] @ local[:, 0]
    for l in range(1, 4):
        world[:, l] = world[:, l - 1] @ (base[l - 1].T @ base[l]) @ local[:, l]
    return world


def forward(world: np.ndarray, origin: np.ndarray = ORIGIN) -> tuple[np.ndarray, np.ndarray]:
    """Markers [T,12,3] and joints [T,3,3] (shoulder, elbow, wrist) from world rotations [T,4,3,3]."""
    T = world.shape[0]
    starts = np.zeros((T, 5, 3))
    starts[:, 0] = origin
    for l in range(4):
        starts[:, l + 1] = starts[:, l] + world[:, l] @ np.array([BONES[l], 0.0, 0.0])
    markers = starts[:, :4, None, :] + np.einsum("tlij,lkj->tlki", world, LOCAL)
    return markers.reshape(T, 12, 3), starts[:, 1:4].copy()


def gym(rng: np.random.Generator, base: np.ndarray, n: int, amp_deg: float = 35.0,
        axes: np.ndarray | None = None) -> np.ndarray:
    """World rotations [n,4,3,3] of a gym swinging every joint from the base pose.

    Each limb's local rotation vector is ``amp * (sin(2 pi f t + phase) - sin(phase))`` per axis
    (so frame 0 is the base pose); ``axes`` [4,3] of 0/1 restricts which local axes move.
    """
    t = np.linspace(0.0, 1.0, n)[:, None, None]
    freq = rng.uniform(1.0, 3.0, size=(4, 3))
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(4, 3))
    ang = np.radians(amp_deg) * (np.sin(2 * np.pi * freq * t + phase) - np.sin(phase))
    if axes is not None:
        ang = ang * axes
    local = Rotation.from_rotvec(ang.reshape(-1, 3)).as_matrix().reshape(n, 4, 3, 3)
    return chain(base, local)


def random_poses(rng: np.random.Generator, base: np.ndarray, n: int,
                 min_deg: float = 20.0, max_deg: float = 50.0) -> np.ndarray:
    """World rotations [n,4,3,3]: every limb rotated by min..max degrees about a random axis."""
    ang = np.radians(rng.uniform(min_deg, max_deg, size=(n, 4)))
    ax = rng.normal(size=(n, 4, 3))
    ax /= np.linalg.norm(ax, axis=-1, keepdims=True)
    local = Rotation.from_rotvec((ax * ang[..., None]).reshape(-1, 3)).as_matrix().reshape(n, 4, 3, 3)
    return chain(base, local)


BASE_A = Rotation.from_euler("xyz", [[0, 0, 0], [0, 0, -70], [0, -20, -80], [0, 0, -85]],
                             degrees=True).as_matrix()
BASE_B = Rotation.from_euler("xyz", [[0, 0, 10], [30, 0, 20], [10, 40, 30], [0, 20, 35]],
                             degrees=True).as_matrix()
