"""``mocapgraph physics mjcf`` and ``mocapgraph posture-db build``: the physics part on files.

``physics mjcf CHARACTER -o body.xml`` writes the MuJoCo model of a character (a shipped name such
as ``standard_20``, a character YAML or a BVH), optionally on a stage, that MuJoCo's own viewer
opens (``python -m mujoco.viewer --mjcf body.xml``).

``posture-db build CLIPS... -o db.npz`` builds Shum & Ho's posture database for a character from:

* ``synthetic:NAME[,NAME...]`` clips of the synthetic actor (``gym``, ``walk``, ``reach``, ``turn``,
  ``walk_back``, ``kick``, ``turn_back``, or ``START-STOP`` seconds), retargeted onto ``standard_20``
  (by its segment rotations), optionally ``@SEED`` for another performer;
* bags (``.mcap``) holding ``CharacterPose`` messages of the character (what the retargeter
  publishes), read in place;
* BVH files, retargeted onto the character by the retargeter library (mapping derived from the two
  rest poses).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from . import UserError
from .progress import Progress

def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("physics", help="the physical character: write its MuJoCo model")
    ps = p.add_subparsers(dest="physics_command", required=True, metavar="SUBCOMMAND")
    m = ps.add_parser("mjcf", help="write a character's MuJoCo body (MJCF) for MuJoCo's own viewer")
    m.add_argument("character", help="shipped character name (standard_20), character YAML or BVH")
    m.add_argument("-o", "--output", required=True, help="MJCF file to write")
    m.add_argument("--body-mass", type=float, default=70.0, help="body mass, kg (default 70)")
    m.add_argument("--height", type=float, default=None, help="standing height, m (generated characters)")
    m.add_argument("--stage", default=None, help="stage YAML to put the character on")
    m.set_defaults(func=cmd_mjcf)

    d = sub.add_parser("posture-db", help="Shum & Ho's PCA posture database")
    ds = d.add_subparsers(dest="db_command", required=True, metavar="SUBCOMMAND")
    b = ds.add_parser("build", help="build a posture database from clips")
    b.add_argument("clips", nargs="+", help="synthetic:walk,reach[@SEED], bags (.mcap) or BVH files")
    b.add_argument("-o", "--output", required=True, help="database file (.npz)")
    b.add_argument("--character", default="standard_20", help="character the postures are of")
    b.add_argument("-k", type=int, default=7, help="PCA dimensions kept (default 7)")
    b.add_argument("--min-ssd", type=float, default=0.005,
                   help="drop a posture closer than this sum of squared differences to a kept one, m^2")
    b.add_argument("--topic", default=None, help="CharacterPose topic in bags (default: the only one)")
    b.set_defaults(func=cmd_db_build)


def _character(name: str, height: float | None = None):
    from ..formats.character_file import CharacterFileError, load_character
    from ..retarget.character import standard_20
    if name == "standard_20" and height:
        return standard_20(height)
    try:
        return load_character(name, height_m=height)
    except (CharacterFileError, OSError, ValueError) as exc:
        raise UserError(str(exc)) from None


def cmd_mjcf(args: argparse.Namespace) -> int:
    from ..physics.stage import EMPTY_STAGE, StageError, load_stage
    from ..physics.world import PhysicsWorld, TrackerParams
    ch = _character(args.character, args.height)
    try:
        stage = load_stage(args.stage) if args.stage else EMPTY_STAGE
        world = PhysicsWorld([ch], stage, TrackerParams(body_mass=args.body_mass))
    except (StageError, ValueError) as exc:
        raise UserError(str(exc)) from None
    Path(args.output).write_text(world.xml)
    m = world.model
    print(f"{args.output}: {ch.name}, {len(world.index.b_body)} bodies, {len(world.bodies[0].bone_child)} capsules, "
          f"{m.nv} DOF, {m.body_mass[world.index.b_body].sum():.1f} kg; open with: python -m mujoco.viewer --mjcf {args.output}")
    return 0


def synthetic_clip(spec: str, character):
    """Positions and local rotations of ``synthetic:walk,reach@SEED`` for ``standard_20``-named joints."""
    from ..physics.synthetic_targets import synthetic_postures
    try:
        return synthetic_postures(spec, character)
    except ValueError as exc:
        raise UserError(str(exc)) from None


def bag_clip(path: str, character, topic: str | None):
    """Postures of the ``CharacterPose`` topic of a bag (the character's own retargeted frames)."""
    from ..bag.errors import BagError
    from ..bag.reader import BagReader
    pos, rot = [], []
    try:
        with BagReader(path) as bag:
            topics = sorted(t for t, i in bag.topic_infos().items() if i.type_name == "CharacterPose")
            want = topic or (topics[0] if len(topics) == 1 else None)
            if want is None:
                raise UserError(f"{path}: {len(topics)} CharacterPose topics ({', '.join(topics) or 'none'}); "
                                "pass --topic")
            for _, m in bag.decoded(want):
                if m.joint_positions.shape[0] != character.n_joints:
                    raise UserError(f"{path}: {want} has {m.joint_positions.shape[0]} joints, the character "
                                    f"{character.name} {character.n_joints}")
                pos.append(m.joint_positions)
                rot.append(m.local_rotations)
    except BagError as exc:
        raise UserError(str(exc)) from None
    if not pos:
        raise UserError(f"{path}: no CharacterPose messages on {want}")
    return np.array(pos), np.array(rot)


def bvh_clip(path: str, character):
    """A BVH performance retargeted onto ``character`` (mapping derived from the two rest poses)."""
    from ..formats.bvh_file import bvh_to_skeleton, read_bvh
    from ..kinematics.rest_offsets import offsets_from_rest
    from ..retarget.retargeter import RetargetOptions, Retargeter
    from ..retarget.mapping import derive_mapping
    from ..retarget.source import skeleton_source
    try:
        motion = read_bvh(path)
        trial = bvh_to_skeleton(motion)
        par = trial.parents
        offs = offsets_from_rest(motion.rest_positions(), par)
        src = skeleton_source(trial.names, par, offs, has_orientations=True, kind_hint="bvh")
        res = Retargeter(character, derive_mapping(character, src), src, RetargetOptions()).process(
            trial.positions, None, trial.orientations)
    except (OSError, ValueError, KeyError) as exc:
        raise UserError(f"{path}: cannot retarget onto {character.name}: {exc}") from None
    return res.joint_positions, res.local_rotations


def cmd_db_build(args: argparse.Namespace) -> int:
    from ..physics.posture_db import PostureDB, PostureDBError
    ch = _character(args.character)
    pos, rot, sources = [], [], []
    bar = Progress("building", unit="step", total=len(args.clips) + 2)  # each clip, the PCA, the search
    for spec in args.clips:
        if spec.startswith("synthetic:"):
            p, r = synthetic_clip(spec, ch)
        elif spec.lower().endswith(".mcap"):
            p, r = bag_clip(spec, ch, args.topic)
        elif spec.lower().endswith(".bvh"):
            p, r = bvh_clip(spec, ch)
        else:
            raise UserError(f"{spec}: not a clip (synthetic:NAMES, .mcap bag or .bvh file)")
        print(f"{spec}: {len(p)} postures")
        bar.advance()
        pos.append(p)
        rot.append(r)
        sources.append(spec)
    try:
        db = PostureDB.build(ch.joint_names, ch.parents, np.concatenate(pos), np.concatenate(rot), k=args.k,
                             min_ssd=args.min_ssd, sources=tuple(sources))
    except PostureDBError as exc:
        raise UserError(str(exc)) from None
    bar.advance()
    times = db.choose_search()
    db.save(args.output)
    bar.close()
    total = sum(len(p) for p in pos)
    print(f"{args.output}: {len(db)} of {total} postures kept (SSD >= {args.min_ssd} m^2), k = {db.k}; "
          f"search {db.search} ({times['brute'] * 1e3:.1f} us brute force, {times['kdtree'] * 1e3:.1f} us k-d tree)")
    return 0
