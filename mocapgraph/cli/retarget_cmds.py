"""``mocapgraph retarget``: a recorded trial onto a character, batch, with the live node's code.

Inputs: BVH (a skeleton with orientations), Kinect CSV (positions only), C3D/TRC markers (with
``--model``, solved by the frame solver first), bags (.mcap: SkeletonPose + SkeletonInfo, ActorPose +
SkeletonModel, or MarkerFrame with ``--model``). Outputs: BVH (the character's hierarchy, offsets,
ZXY channels, frame time; centimetres, Y up), a bag (latched ``character_info``, one
``character_pose`` per frame), CSV (frame, time, then per joint x/y/z in metres, world, the local
rotation w/x/y/z and the quality 0/1/2), or glTF (``.glb``/``.gltf``: the skeleton as a skin, the
animation keyed at the source's frame times; :mod:`mocapgraph.formats.gltf_export`; ``.vrm``: the
same GLB with a VRM 1.0 humanoid map). ``mocapgraph retarget mapping`` writes the automatic
mapping for a source and a character, to read and edit.
"""
from __future__ import annotations

import argparse
import csv
import time
from typing import TYPE_CHECKING
from pathlib import Path

import numpy as np

from . import UserError
from .progress import Progress

if TYPE_CHECKING:   # annotations only: the command loads its readers when it runs
    from ..bag.trial_frames import SourceFrames

OUTPUTS = (".bvh", ".mcap", ".csv", ".glb", ".gltf", ".vrm")


def read_source(path: str, model: str | None, topic: str | None) -> "SourceFrames":
    """Any supported trial as source frames (``bag.trial_frames``); UserError (one line) otherwise."""
    from ..bag.trial_frames import TrialError, read_trial_frames
    try:
        return read_trial_frames(path, model, topic)
    except TrialError as exc:
        raise UserError(str(exc)) from None


def _options(args):
    from ..retarget.retargeter import RetargetOptions
    return RetargetOptions(foot_planting=not args.no_foot_planting, spread=not args.no_spread, aim=not args.no_aim,
                           roll=not args.no_roll, root_scale=not args.no_root_scale, scale=args.scale,
                           follow_tolerance_deg=getattr(args, "follow_tolerance", 10.0))


def cmd_retarget(args: argparse.Namespace) -> int:
    from ..formats.character_file import CharacterFileError
    from ..formats.retarget_setup import build
    from ..retarget.mapping import MappingError
    out = Path(args.output)
    if out.suffix.lower() not in OUTPUTS:
        raise UserError(f"{out}: unknown output type {out.suffix or '(none)'!r} (expected .bvh, .mcap, .csv, .glb, .gltf or .vrm)")
    bar = Progress("retargeting", unit="step", total=3)  # read, retarget, write
    frames = read_source(args.trial, args.model, args.topic)
    bar.advance()
    try:
        rig = build(args.character, args.mapping, frames.source, _options(args), height_m=args.height,
                    write_derived=args.mapping_out)
    except (MappingError, CharacterFileError) as exc:
        raise UserError(str(exc)) from None
    t0 = time.perf_counter()
    res = rig.retargeter.process(frames.points, frames.point_ok, frames.rotations, frames.rotation_ok, frames.times_s)
    dt = time.perf_counter() - t0
    bar.advance()
    ch = rig.character
    q = res.joint_quality
    print(f"{frames.label} onto {ch.name}: {len(q)} frames, {ch.n_joints} joints in {dt:.2f} s "
          f"({len(q) / max(dt, 1e-9):.0f} frames/s); {100 * (q == 2).mean():.1f} % good, {100 * (q == 1).mean():.1f} % "
          f"estimated, {100 * (q == 0).mean():.1f} % missing; root ratio {rig.retargeter.ratio:.3f}"
          + (f"; contact {100 * res.contact.mean():.0f} % of foot-frames" if not args.no_foot_planting else ""))
    if args.mapping_out and rig.derived:
        print(f"wrote the derived mapping to {args.mapping_out}")
    kind = out.suffix.lower()
    try:
        if kind == ".bvh":
            write_character_bvh(out, ch, res, 1.0 / frames.rate_hz)
        elif kind == ".mcap":
            _write_bag(out, ch, res, frames, args.character_name or ch.name)
        elif kind in (".glb", ".gltf", ".vrm"):
            from .gltf_out import write_retarget_gltf
            write_retarget_gltf(out, ch, res, frames.times_s, frames.rate_hz, args.character, not args.no_mesh)
        else:
            _write_csv(out, ch, res, frames)
    except OSError as exc:
        raise UserError(f"{out}: cannot write ({exc.strerror or exc})") from None
    bar.close()
    print(f"wrote {out}")
    return 0


def write_character_bvh(path: Path, ch, res, frame_time_s: float) -> None:
    """The character's animation as BVH (through bag.convert's skeleton_to_bvh: cm, Y up, ZXY)."""
    from ..bag.convert import SkeletonFrames, skeleton_to_bvh
    from ..formats.bvh_file import write_bvh
    pos, world = ch.forward_kinematics(res.local_rotations, res.root_positions)
    names = [n + ("_End" if ch.end_sites[j] and not n.endswith("_End") else "") for j, n in enumerate(ch.joint_names)]
    sk = SkeletonFrames(names, ch.parents, ch.rest_offsets, pos, world,
                        np.round(np.arange(len(pos)) * frame_time_s * 1e9).astype(np.int64), "CharacterPose")
    write_bvh(path, skeleton_to_bvh(sk, frame_time_s))


def _write_bag(out: Path, ch, res, frames: SourceFrames, name: str) -> None:
    from ..bag.writer import BagWriter, base_metadata
    from ..messages import CharacterInfo, CharacterPose
    stamps = np.round(frames.times_s * 1e9).astype(np.int64)
    with BagWriter(out, metadata=base_metadata("mocapgraph retarget", source=frames.label)) as w:
        w.write("character_info", CharacterInfo(character=name, joint_names=list(ch.joint_names),
                                                joint_parent=ch.parents.astype(np.int32), rest_offsets=ch.rest_offsets,
                                                rest_rotations=ch.rest_rotations), seq=1, capture_ns=int(stamps[0]),
                sender="retarget")
        for t in range(len(stamps)):
            w.write("character_pose", CharacterPose(character=name, frame_number=int(frames.frame_numbers[t]),
                                                    root_position=res.root_positions[t],
                                                    local_rotations=res.local_rotations[t],
                                                    joint_positions=res.joint_positions[t],
                                                    joint_quality=res.joint_quality[t]),
                    seq=t + 1, capture_ns=int(stamps[t]), sender="retarget")


def _write_csv(out: Path, ch, res, frames: SourceFrames) -> None:
    cols = ["frame", "time_s"]
    for n in ch.joint_names:
        cols += [f"{n}_x_m", f"{n}_y_m", f"{n}_z_m", f"{n}_qw", f"{n}_qx", f"{n}_qy", f"{n}_qz", f"{n}_quality"]
    F, J = res.joint_quality.shape
    table = np.concatenate([res.joint_positions, res.local_rotations, res.joint_quality[..., None]], axis=-1)
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for t in range(F):
            row = table[t]
            cells = []
            for j in range(J):
                cells += [f"{v:.6f}" for v in row[j, :7]] + [f"{int(row[j, 7])}"]
            w.writerow([int(frames.frame_numbers[t]), f"{frames.times_s[t]:.6f}", *cells])


def cmd_mapping(args: argparse.Namespace) -> int:
    from ..formats.character_file import CharacterFileError, load_character
    from ..formats.mapping_file import write_mapping
    from ..retarget.mapping import derive_mapping
    frames = read_source(args.trial, args.model, args.topic)
    try:
        ch = load_character(args.character, height_m=args.height)
    except CharacterFileError as exc:
        raise UserError(str(exc)) from None
    m = derive_mapping(ch, frames.source)
    write_mapping(m, args.output, comment=f"derived automatically from {frames.label} ({frames.source.kinect_like}) "
                                          f"onto {ch.name}; edit freely")
    print(f"{len(m.joints)} of {ch.n_joints} joints mapped; wrote {args.output}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("retarget", help="retarget a trial onto a character (BVH, Kinect CSV, C3D/TRC, bags)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("trial", metavar="TRIAL", help="BVH, Kinect CSV, C3D/TRC (with --model) or .mcap; "
                                                  "or `mapping` to write a mapping file")
    p.add_argument("extra", nargs="?", help=argparse.SUPPRESS)
    p.add_argument("--character", default="standard_20", help="character file (YAML/BVH) or shipped name")
    p.add_argument("--height", type=float, default=None, help="height of a generated character (standard_20), m")
    p.add_argument("--model", help="actor model JSON for marker trials")
    p.add_argument("--mapping", help="mapping file or shipped name (default: derived from the two rest poses)")
    p.add_argument("--mapping-out", help="write the derived mapping here")
    p.add_argument("--topic", help="topic of a bag input (when it has several)")
    p.add_argument("--scale", type=float, default=None, help="root translation ratio (default: leg-length ratio)")
    p.add_argument("--character-name", help="name in bag output")
    p.add_argument("--follow-tolerance", type=float, default=10.0, metavar="DEG",
                   help="a joint whose bone turns from the source bone by more than this (beyond the rest-shape "
                        "difference) is flagged estimated on that frame (default 10; 180: never)")
    for flag, what in (("foot-planting", "foot planting"), ("spread", "spine spread"), ("aim", "clavicle aiming"),
                       ("roll", "roll joints"), ("root-scale", "root scaling")):
        p.add_argument(f"--no-{flag}", action="store_true", help=f"turn {what} off")
    p.add_argument("--no-mesh", action="store_true", help="glTF output: the skeleton only (default: the character "
                                                           "file's own skinned mesh, else a generated mannequin)")
    p.add_argument("-o", "--output", required=True, help="out.bvh, out.mcap, out.csv, out.glb, out.gltf or out.vrm "
                                                           "(mapping: out.yaml)")
    p.set_defaults(func=_dispatch)


def _dispatch(args: argparse.Namespace) -> int:
    if args.trial == "mapping":
        if not args.extra:
            raise UserError("retarget mapping TRIAL --character C -o mapping.yaml: which trial?")
        args.trial = args.extra
        return cmd_mapping(args)
    return cmd_retarget(args)
