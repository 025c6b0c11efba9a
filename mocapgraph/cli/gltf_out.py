"""glTF output of the retarget command: frame times made usable as glTF keys, errors as one line."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..formats.gltf_export import GltfExportError, write_gltf
from . import UserError


def key_times(times_s: np.ndarray, rate_hz: float) -> tuple[np.ndarray, str]:
    """The source's frame times from 0 s when they are strictly increasing (as float32, glTF's keys),
    else frame index / rate; and a note saying which was used."""
    t = np.asarray(times_s, dtype=np.float64) - float(times_s[0])
    if np.isfinite(t).all() and (len(t) < 2 or (np.diff(t.astype(np.float32)) > 0).all()):
        return t, "the source's frame times"
    return np.arange(len(t)) / rate_hz, f"frame index / {rate_hz:g} Hz (the source's times repeat or go back)"


def character_mesh(ch, character: str, want: bool):
    """(the mesh to export, what it is): a glTF/VRM character file's own skinned mesh, else the
    generated mannequin; (None, "no mesh") when not wanted."""
    from ..formats.gltf_character import GLTF_SUFFIXES, load_gltf_character
    from ..formats.mannequin import mannequin
    if not want:
        return None, "no mesh"
    if Path(str(character)).suffix.lower() in GLTF_SUFFIXES:
        own = load_gltf_character(character).mesh
        if own is not None and own.joints.max(initial=0) < ch.n_joints:
            return own, f"the character file's mesh ({len(own.positions)} vertices)"
    m = mannequin(ch)
    return m, f"a generated mannequin ({len(m.positions)} vertices)"


def humanoid_of(ch, character: str) -> dict[str, str]:
    """Unity bone -> joint of the character: a VRM character file's own map, else the shipped table
    that fits its joint names (:func:`mocapgraph.formats.vmc.humanoid_bones`)."""
    from ..formats.gltf_character import GLTF_SUFFIXES, load_gltf_character
    from ..formats.vmc import UNITY_BONES, humanoid_bones
    if Path(str(character)).suffix.lower() in GLTF_SUFFIXES:
        own = load_gltf_character(character).humanoid
        if own:
            return {b: j for b, j in own.items() if b in UNITY_BONES}
    return humanoid_bones(ch)


def write_retarget_gltf(out: Path, ch, res, times_s: np.ndarray, rate_hz: float, character: str = "",
                        with_mesh: bool = True) -> None:
    """The retargeted animation as .glb/.gltf (written whole or not at all); UserError on a fault."""
    t, how = key_times(times_s, rate_hz)
    try:
        mesh, what = character_mesh(ch, character, with_mesh)
        humanoid = humanoid_of(ch, character) if Path(out).suffix.lower() == ".vrm" else None
        n = write_gltf(out, ch, res.local_rotations, res.root_positions, t, mesh=mesh, vrm_humanoid=humanoid)
    except (GltfExportError, ValueError) as exc:
        raise UserError(str(exc)) from None
    print(f"glTF: {ch.n_joints} joints, {len(t)} keys at {how}, {what}, {n / 1e6:.2f} MB")
