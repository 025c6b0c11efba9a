"""The stage's skinned avatars: a character's mannequin as GLB, and the three.js files the page may load.

The page asks ``/avatar.glb?key=<CharacterInfo stream key>``; :func:`avatar_glb` builds the
character from that latched message (names, parents, rest offsets and rotations), wraps it in our
generated mannequin (:mod:`mocapgraph.formats.mannequin`) and writes it with our glTF writer
(:mod:`mocapgraph.formats.gltf_export`), no animation: the page drives the skin's bones from each
``CharacterPose``. :func:`three_files` maps the fixed allow-list of three.js module files (from
npm, ``node_modules/three``, installed by ``scripts/setup.sh``) to the URL paths the page's import
map names; nothing else under ``node_modules`` is ever served.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..messages.types import CharacterInfo
from . import ASSET_DIR

#: node_modules/three of the repository (scripts/setup.sh runs npm ci); MOCAPGRAPH_THREE_DIR overrides
THREE_DIR = ASSET_DIR.parents[1] / "node_modules" / "three"
#: the only files under node_modules/three the viewer serves (URL /three/<file>)
THREE_FILES = ("build/three.module.js", "build/three.core.js",
               "examples/jsm/controls/OrbitControls.js", "examples/jsm/loaders/GLTFLoader.js",
               "examples/jsm/utils/BufferGeometryUtils.js", "examples/jsm/utils/SkeletonUtils.js")
MAX_AVATAR_JOINTS = 1024   # a larger rig stays bones (Mixamo's 70 joints: a 0.6 MB GLB in 0.1 s)
SETUP_HINT = "three.js is not installed: run scripts/setup.sh (it runs npm ci), then restart the graph"


class AvatarError(ValueError):
    """A character the mannequin cannot be built on (one line)."""


def three_dir() -> Path:
    """Where three.js is looked for (MOCAPGRAPH_THREE_DIR, else the repository's node_modules)."""
    env = os.environ.get("MOCAPGRAPH_THREE_DIR", "")
    return Path(env) if env else THREE_DIR


def three_files(root: Path | None = None) -> dict[str, Path]:
    """URL path -> file, for the allow-listed three.js files that exist ({} when three is missing)."""
    root = three_dir() if root is None else root
    files = {f"/three/{name}": root / name for name in THREE_FILES}
    return files if all(p.is_file() for p in files.values()) else {}


def avatar_glb(info: CharacterInfo) -> bytes:
    """A GLB of ``info``'s character at rest with its mannequin skinned to it (AvatarError if none)."""
    from ..formats.gltf_export import GltfExportError, character_gltf, gltf_file_bytes
    from ..formats.mannequin import mannequin
    from ..retarget.character import Character

    if len(info.joint_names) > MAX_AVATAR_JOINTS:
        raise AvatarError(f"no avatar for character {info.character!r}: {len(info.joint_names)} joints "
                          f"(at most {MAX_AVATAR_JOINTS}); drawn as bones")
    try:
        ch = Character(info.character or "character", tuple(info.joint_names), np.asarray(info.joint_parent),
                       np.asarray(info.rest_offsets), np.asarray(info.rest_rotations), allow_zero_bones=True)
        doc = character_gltf(ch, mesh=mannequin(ch, name=f"{ch.name}_mannequin"))
        return gltf_file_bytes(doc, ".glb")
    except (ValueError, GltfExportError) as exc:
        raise AvatarError(f"no avatar for character {info.character!r}: {exc}") from None
