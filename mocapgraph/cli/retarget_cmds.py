"""``mocapgraph retarget``: a recorded trial onto a character, batch, with the live node's code.

Inputs: BVH (a skeleton with orientations), Kinect CSV (positions only), C3D/TRC markers (with
``--model``, solved by the frame solver first), bags (.mcap: SkeletonPose + SkeletonInfo, ActorPose +
SkeletonModel, or MarkerFrame with ``--model``). Outputs: BVH (the character's hierarchy, offsets,
ZXY channels, frame time; centimetres, Y up), a bag (latched ``character_info``, one
``character_pose`` per frame), or CSV (frame, time, then per joint x/y/z in metres, world, the local
rotation w/x/y/z and the quality 0/1/2). ``mocapgraph retarget mapping`` writes the automatic
mapping for a source and a character, to read and edit.
"""
from __future__ import annotations

import argparse
import csv
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import UserError
from .progress import Progress

OUTPUTS = (".bvh", ".mcap", ".csv")


@dataclass
class SourceFrames:
    """A trial as the retargeter reads it: points [F, P, 3], ok [F, P], rotations [F, R, 4] or None."""

    source: object
    points: np.ndarray
    point_ok: np.ndarray
    rotations: np.ndarray | None
    rotation_ok: np.ndarray | None
    times_s: np.ndarray
    frame_numbers: np.ndarray
    rate_hz: float
    label: str


def _skeleton_frames(names, parents, rest_offsets, positions, orientations, state, times, rate, label):
    from ..formats.retarget_setup import source_from_skeleton_info
    has_q = orientations is not None and bool(np.isfinite(orientations).any())
    src = source_from_skeleton_info(names, parents, rest_offsets, has_orientations=has_q)
    ok = np.isfinite(positions).all(-1) & (state >= 1 if state is not None else True)
    return SourceFrames(src, positions, ok, orientations if has_q else None, None, times,
                        np.arange(len(times)), rate, label)


def _actor_frames(model_msg_like, joints, jq, limbs, lq, times, rate, label):
    from ..formats.retarget_setup import source_from_model
    from ..retarget.source import optical_points
    m = model_msg_like
    src = source_from_model(m.joint_names, m.joint_parent, m.joint_limbs, m.limb_names, m.joint_base, m.layout)
    pts = optical_points(joints, m.joint_names)
    hips = [i for i, n in enumerate(m.joint_names) if n.startswith("hip")]
    pok = np.concatenate([jq >= 1, (jq[:, hips] >= 1).all(1, keepdims=True)], axis=1)
    return SourceFrames(src, pts, pok, limbs, lq >= 1, times, np.arange(len(times)), rate, label)


def read_source(path: str, model: str | None, topic: str | None) -> SourceFrames:
    """Any supported trial as source frames; UserError (one line) otherwise."""
    from ..bag.errors import BagError
    from ..formats import FormatError
    from ..formats.sources import SKELETON_KINDS, read_skeleton_file, skeleton_rest_offsets
    p = Path(path)
    if not p.exists():
        raise UserError(f"{path}: no such file")
    kind = p.suffix.lower()
    try:
        if kind in SKELETON_KINDS:
            # BVH: its rest pose; Kinect: bone lengths of tracked samples (only lengths matter, see retarget_setup)
            tr = read_skeleton_file(p, ground="feet")
            offs = skeleton_rest_offsets(tr, tracked_only=True)
            t = tr.timestamps_ns * 1e-9 if kind != ".bvh" else np.arange(tr.n_frames) / tr.rate_hz
            state = tr.tracking_state if kind != ".bvh" else None
            return _skeleton_frames(tr.names, tr.parents, offs, tr.positions, tr.orientations, state, t,
                                    tr.rate_hz, p.name)
        if kind in (".c3d", ".trc"):
            return _solve_markers(p, model, topic)
        if kind == ".mcap":
            return _bag_source(p, model, topic)
    except (FormatError, BagError) as exc:
        raise UserError(str(exc)) from None
    raise UserError(f"{p.name}: unknown trial type {p.suffix or '(none)'!r} (expected .bvh, .csv or .txt (Kinect), "
                    ".c3d, .trc or .mcap)")


def _solve_markers(p: Path, model_path: str | None, topic: str | None) -> SourceFrames:
    from ..kinematics.model import ModelFileError, load_model
    from ..kinematics.solving.solver import FrameSolver
    from .actor_cmds import _place, read_marker_input
    if not model_path:
        raise UserError(f"{p.name}: markers need an actor model: --model model.json (mocapgraph calibrate)")
    try:
        model = load_model(model_path)
    except ModelFileError as exc:
        raise UserError(str(exc)) from None
    inp = read_marker_input(str(p), topic)
    where, _ = _place(model, inp, False)
    x = np.concatenate([inp.positions, np.full(inp.positions.shape[:1] + (1, 3), np.nan)], axis=1)
    x = x[:, np.where(where >= 0, where, inp.positions.shape[1])]
    times = (inp.frame_numbers - inp.frame_numbers[0]) / inp.rate_hz
    res = FrameSolver(model, rate_hz=inp.rate_hz).solve(x, times)
    m = _ModelView(model.joint_names, model.joint_parent, model.joint_limbs, model.limb_names, model.joint_base,
                   model.layout)
    return _actor_frames(m, res.joints, res.joint_quality, res.limb_rotation, res.limb_quality, times, inp.rate_hz, p.name)


@dataclass
class _ModelView:
    joint_names: tuple
    joint_parent: np.ndarray
    joint_limbs: np.ndarray
    limb_names: tuple
    joint_base: np.ndarray
    layout: str


def _bag_source(p: Path, model_path: str | None, topic: str | None) -> SourceFrames:
    from ..bag.reader import BagReader
    with BagReader(p) as r:
        infos = r.topic_infos()
        by_type = {}
        for t, i in infos.items():
            by_type.setdefault(i.type_name, []).append(t)
        if "SkeletonPose" in by_type or "ActorPose" in by_type:
            kind = "SkeletonPose" if "SkeletonPose" in by_type else "ActorPose"
            tp = topic or by_type[kind][0]
            comp = "SkeletonInfo" if kind == "SkeletonPose" else "SkeletonModel"
            if comp not in by_type:
                raise UserError(f"{p.name}: topic {tp!r} [{kind}] needs its latched {comp}, which the bag lacks")
            info = None
            for _, m in r.decoded(by_type[comp][0]):
                info = m
            frames = [(env.capture_ns, m) for env, m in r.decoded(tp)]
        elif "MarkerFrame" in by_type:
            return _solve_markers(p, model_path, topic)
        else:
            raise UserError(f"{p.name}: no SkeletonPose, ActorPose or MarkerFrame topic to retarget")
    if not frames:
        raise UserError(f"{p.name}: topic {tp!r} holds no frames")
    ns = np.array([f[0] for f in frames], dtype=np.int64)
    t = (ns - ns[0]) * 1e-9
    rate = float(1.0 / np.median(np.diff(t))) if len(t) > 1 else 30.0
    msgs = [f[1] for f in frames]
    if kind == "SkeletonPose":
        J = len(info.joint_names)
        good = [m for m in msgs if m.joint_positions.shape[0] == J]
        if len(good) < len(msgs):
            print(f"note: {len(msgs) - len(good)} frames of {tp} do not have the {J} joints of skeleton_info: skipped")
        return _skeleton_frames(info.joint_names, info.joint_parent, info.rest_offsets,
                                np.stack([m.joint_positions for m in good]), np.stack([m.joint_orientations for m in good]),
                                np.stack([m.tracking_state for m in good]), t[:len(good)], rate, p.name)
    m = info
    view = _ModelView(m.joint_names, m.joint_parent, m.joint_limbs, m.limb_names, m.base_joints, m.layout_name)
    return _actor_frames(view, np.stack([x.joint_positions for x in msgs]), np.stack([x.joint_quality for x in msgs]),
                         np.stack([x.limb_orientations for x in msgs]), np.stack([x.limb_quality for x in msgs]),
                         t, rate, p.name)


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
        raise UserError(f"{out}: unknown output type {out.suffix or '(none)'!r} (expected .bvh, .mcap or .csv)")
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
    p.add_argument("-o", "--output", required=True, help="out.bvh, out.mcap or out.csv (mapping: out.yaml)")
    p.set_defaults(func=_dispatch)


def _dispatch(args: argparse.Namespace) -> int:
    if args.trial == "mapping":
        if not args.extra:
            raise UserError("retarget mapping TRIAL --character C -o mapping.yaml: which trial?")
        args.trial = args.extra
        return cmd_mapping(args)
    return cmd_retarget(args)
