"""Conversion between capture files and bags.

Into a bag (so any file can be replayed through a graph):
- C3D / TRC -> latched ``MarkerLayout`` on ``marker_layout`` + ``MarkerFrame`` on ``markers``;
  a C3D's ROTATION group (segment poses) also -> ``skeleton_info`` + ``skeleton_pose``;
- BVH / Kinect CSV -> latched ``SkeletonInfo`` on ``skeleton_info`` + ``SkeletonPose`` on
  ``skeleton_pose``.
Capture, publish and log stamps are the file's frame times (``start_ns`` + time from the first
frame; the Kinect sensor's own clock for Kinect CSV); sequence numbers count frames from 1.

Out of a bag:
- markers -> TRC, C3D (via :class:`~mocapgraph.formats.MarkerTrial`), CSV;
- SkeletonPose (with orientations) or CharacterPose -> BVH, written in centimetres, Y up (the
  BVH convention; ``read_bvh`` converts back to metres, Z up);
- any topic -> CSV, one row per message, array columns named after the latched names
  (marker labels, joint names) where the bag has them.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from ..formats.errors import FormatError
from ..formats.marker_trial import MarkerTrial
from ..formats.skeleton_trial import SkeletonTrial, topological_order
from ..formats.sources import FILE_KINDS, read_marker_file, read_skeleton_file, skeleton_rest_offsets
from ..messages import (Array, CharacterInfo, CharacterPose, MarkerFrame, MarkerLayout, Message, Scalar,
                        SkeletonInfo, SkeletonPose, Strings)
from .errors import BagError
from .reader import BagReader
from .writer import BagWriter, base_metadata

Progress = Callable[[int, int], None]
SENDER = "bag_convert"
INPUT_KINDS = FILE_KINDS  # what converts into a bag: every capture file formats.sources reads
OUTPUT_KINDS = {".csv": "csv", ".trc": "trc", ".c3d": "c3d", ".bvh": "bvh"}
BVH_UNITS_M = 0.01  # BVH written in centimetres
# world = BVH_TO_WORLD @ bvh (Y-up BVH, character facing +Z; see formats.bvh_file)
from ..formats.bvh_file import BVH_TO_WORLD, BvhMotion, write_bvh  # noqa: E402
from ..formats.c3d_segments import read_c3d_segments  # noqa: E402


@dataclass
class ConvertReport:
    """What a conversion wrote."""

    source: Path
    output: Path
    kind: str
    topics: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def text(self) -> str:
        parts = ", ".join(f"{t} ({n})" for t, n in self.topics.items())
        lines = [f"wrote {self.output} from {self.kind} {self.source.name}" + (f": {parts}" if parts else "")]
        lines += [f"  {n}" for n in self.notes]
        return "\n".join(lines)


# ----- files -> bag ---------------------------------------------------------------------------------
def markers_to_bag(trial: MarkerTrial, writer: BagWriter, *, start_ns: int = 0, topic: str = "markers",
                   layout_topic: str = "marker_layout", times_ns: np.ndarray | None = None,
                   progress: Progress | None = None) -> int:
    """Write a MarkerTrial as a latched MarkerLayout + one MarkerFrame per frame. Returns frames written."""
    stamps = start_ns + (trial.timestamps_ns if times_ns is None else np.asarray(times_ns, np.int64))
    M = trial.n_markers
    note = "; ".join(trial.conversions) or "no conversion"
    layout = MarkerLayout(name=Path(trial.source).stem if trial.source else "markers", labels=trial.labels,
                          limb_names=[], marker_limb=np.full(M, -1, np.int32), units_note=note, unplaced=[],
                          source=str(trial.source))
    first = int(stamps[0]) if len(stamps) else start_ns
    writer.write(layout_topic, layout, seq=1, capture_ns=first, sender=SENDER)
    valid = trial.valid
    res = trial.residuals.astype(np.float32)
    T = trial.n_frames
    for i in range(T):
        writer.write(topic, MarkerFrame(frame_number=trial.first_frame + i, rate_hz=trial.rate_hz,
                                        positions=trial.positions[i], valid=valid[i], residual=res[i]),
                     seq=i + 1, capture_ns=int(stamps[i]), sender=SENDER)
        if progress is not None and i % 256 == 0:
            progress(i, T)
    return T


def skeleton_to_bag(trial: SkeletonTrial, writer: BagWriter, *, source: str, start_ns: int = 0,
                    topic: str = "skeleton_pose", info_topic: str = "skeleton_info",
                    progress: Progress | None = None) -> int:
    """Write a SkeletonTrial as a latched SkeletonInfo + one SkeletonPose per frame."""
    J, T = trial.n_joints, trial.n_frames
    stamps = start_ns + trial.timestamps_ns
    info = SkeletonInfo(source=source, joint_names=trial.names, joint_parent=trial.parents.astype(np.int32),
                        rest_offsets=skeleton_rest_offsets(trial),
                        units_note="; ".join(trial.conversions) or "no conversion")
    writer.write(info_topic, info, seq=1, capture_ns=int(stamps[0]) if T else start_ns, sender=SENDER)
    quat = trial.orientations if trial.orientations is not None else np.full((T, J, 4), np.nan)
    for i in range(T):
        writer.write(topic, SkeletonPose(source_id="0", frame_number=i, joint_positions=trial.positions[i],
                                         joint_orientations=quat[i], tracking_state=trial.tracking_state[i]),
                     seq=i + 1, capture_ns=int(stamps[i]), sender=SENDER)
        if progress is not None and i % 256 == 0:
            progress(i, T)
    return T


def file_to_bag(src: str | Path, dst: str | Path, *, compression: str = "lz4", start_ns: int = 0,
                progress: Progress | None = None, up_axis: str | None = None) -> ConvertReport:
    """Convert a C3D, TRC, BVH or Kinect CSV file into a bag (kind from the extension).

    up_axis: a marker file's up axis (None/"auto": what the file says; see read_c3d/read_trc).
    """
    from ..formats.c3d_segments import c3d_segment_count

    src, dst = Path(src), Path(dst)
    kind = INPUT_KINDS.get(src.suffix.lower())
    if kind is None:
        raise BagError(src, f"cannot convert a {src.suffix or 'extensionless'} file into a bag "
                            f"(known: {', '.join(sorted(INPUT_KINDS))})")
    if not src.is_file():
        raise BagError(src, "no such file")
    try:
        if kind == "c3d" and c3d_segment_count(src) > 0:
            return _c3d_with_segments_to_bag(src, dst, compression, start_ns, progress, up_axis)
        if kind in ("c3d", "trc"):
            trial = read_marker_file(src, up_axis=up_axis)
            times = None
            t_file = trial.extra.get("time_s") if kind == "trc" else None
            if t_file is not None and len(t_file) == trial.n_frames and np.all(np.isfinite(t_file)) \
                    and np.all(np.diff(t_file) > 0):
                times = np.round((np.asarray(t_file) - t_file[0]) * 1e9).astype(np.int64)
            notes = [trial.summary()] + list(trial.notes)
            with _writer(dst, compression, src, kind) as w:
                n = markers_to_bag(trial, w, start_ns=start_ns, times_ns=times, progress=progress)
            topics = {"marker_layout": 1, "markers": n}
        else:
            trial = read_skeleton_file(src)
            notes = [f"{trial.n_joints} joints x {trial.n_frames} frames @ {trial.rate_hz:.4g} Hz "
                     f"({'; '.join(trial.conversions) or 'no conversion'})"] + list(trial.notes)
            with _writer(dst, compression, src, kind) as w:
                n = skeleton_to_bag(trial, w, source=kind, start_ns=start_ns, progress=progress)
            topics = {"skeleton_info": 1, "skeleton_pose": n}
    except FormatError as exc:
        raise BagError(src, exc.fault) from None
    if progress is not None:
        progress(1, 1)
    return ConvertReport(src, dst, kind, topics, notes)


def _c3d_with_segments_to_bag(src: Path, dst: Path, compression: str, start_ns: int,
                              progress: Progress | None, up_axis: str | None) -> ConvertReport:
    """A C3D with a ROTATION group: its segment poses on skeleton_info + skeleton_pose, and its
    markers (when it has any) on marker_layout + markers, both from ``start_ns``."""
    from ..formats.c3d_file import inspect_c3d, read_c3d

    seg = read_c3d_segments(src, up_axis=up_axis)
    seg.timestamps_ns = seg.timestamps_ns - seg.timestamps_ns[0]
    trial = read_c3d(src, up_axis=up_axis) if inspect_c3d(src).n_points > 0 else None
    notes = [f"{seg.n_joints} segments x {seg.n_frames} frames @ {seg.rate_hz:.4g} Hz from the ROTATION "
             f"group ({'; '.join(seg.conversions)})"] + list(seg.notes)
    topics: dict[str, int] = {}
    with _writer(dst, compression, src, "c3d") as w:
        if trial is not None:
            notes = [trial.summary()] + list(trial.notes) + notes
            topics.update(marker_layout=1, markers=markers_to_bag(trial, w, start_ns=start_ns, progress=progress))
        topics.update(skeleton_info=1,
                      skeleton_pose=skeleton_to_bag(seg, w, source="c3d_segments", start_ns=start_ns))
    if progress is not None:
        progress(1, 1)
    return ConvertReport(src, dst, "c3d", topics, notes)


def _writer(dst: Path, compression: str, src: Path, kind: str) -> BagWriter:
    if dst.suffix.lower() != ".mcap":
        raise BagError(dst, "a bag file name ends in .mcap")
    meta = base_metadata("bag convert", source=str(src), source_kind=kind)
    return BagWriter(dst, compression=compression, metadata=meta)


# ----- bag -> files ---------------------------------------------------------------------------------
def _topic_of_type(reader: BagReader, type_names: tuple[str, ...], given: str | None) -> str:
    infos = reader.topic_infos()
    if given:
        if given not in infos:
            raise BagError(reader.path, f"has no topic {given!r} (topics: {', '.join(sorted(infos))})")
        if infos[given].type_name not in type_names:
            raise BagError(reader.path, f"topic {given!r} holds {infos[given].type_name}, not "
                                        f"{' or '.join(type_names)}")
        return given
    found = [t for t, i in infos.items() if i.type_name in type_names]
    if not found:
        raise BagError(reader.path, f"has no {' or '.join(type_names)} topic (topics: "
                                    f"{', '.join(f'{t} [{i.type_name}]' for t, i in sorted(infos.items()))})")
    if len(found) > 1:
        raise BagError(reader.path, f"has several {' or '.join(type_names)} topics ({', '.join(found)}); "
                                    "choose one with --topic")
    return found[0]


def _latest_of_type(reader: BagReader, type_name: str) -> Message | None:
    infos = reader.topic_infos()
    topic = next((t for t, i in infos.items() if i.type_name == type_name and i.known), None)
    if topic is None:
        return None
    msg = None
    for _env, m in reader.decoded(topic):
        msg = m
    return msg


def bag_to_marker_trial(reader: BagReader, topic: str | None = None,
                        progress: Progress | None = None) -> MarkerTrial:
    """Marker frames of a bag topic (and the bag's MarkerLayout labels) as a MarkerTrial."""
    topic = _topic_of_type(reader, ("MarkerFrame",), topic)
    layout = _latest_of_type(reader, "MarkerLayout")
    total = reader.topic_infos()[topic].count
    pos, res, numbers, stamps = [], [], [], []
    rate = 0.0
    for i, (env, m) in enumerate(reader.decoded(topic)):
        if pos and m.positions.shape != pos[0].shape:
            raise BagError(reader.path, f"topic {topic!r} changes marker count at frame {i} "
                                        f"({pos[0].shape[0]} -> {m.positions.shape[0]})")
        pos.append(m.positions)
        res.append(m.residual)
        numbers.append(m.frame_number)
        stamps.append(env.capture_ns)
        rate = rate or m.rate_hz
        if progress is not None and i % 256 == 0:
            progress(i, total)
    if not pos:
        raise BagError(reader.path, f"topic {topic!r} holds no frames")
    M = pos[0].shape[0]
    labels = list(layout.labels) if layout is not None and len(layout.labels) == M else [f"M{k}" for k in range(M)]
    if not rate > 0:
        d = np.diff(np.asarray(stamps, np.float64))
        rate = 1e9 / float(np.median(d)) if d.size else 1.0
    return MarkerTrial(labels=labels, positions=np.stack(pos), residuals=np.stack(res).astype(np.float64),
                       rate_hz=rate, first_frame=int(numbers[0]), source=f"{reader.path}:{topic}",
                       conversions=[], extra={"capture_ns": np.asarray(stamps, np.int64)})


@dataclass
class SkeletonFrames:
    """A skeleton stream pulled out of a bag: hierarchy, rest offsets and per-frame world pose."""

    names: list[str]
    parents: np.ndarray
    rest_offsets: np.ndarray  # [J, 3] m, world rest frame
    positions: np.ndarray  # [T, J, 3] m, world
    orientations: np.ndarray  # [T, J, 4] wxyz world (may hold NaN)
    capture_ns: np.ndarray
    kind: str  # SkeletonPose or CharacterPose
    topic: str = ""


def bag_to_skeleton_frames(reader: BagReader, topic: str | None = None,
                           progress: Progress | None = None) -> SkeletonFrames:
    """SkeletonPose (+ SkeletonInfo) or CharacterPose (+ CharacterInfo) frames of a bag."""
    topic = _topic_of_type(reader, ("SkeletonPose", "CharacterPose"), topic)
    tname = reader.topic_infos()[topic].type_name
    info = _latest_of_type(reader, "SkeletonInfo" if tname == "SkeletonPose" else "CharacterInfo")
    if info is None:
        raise BagError(reader.path, f"topic {topic!r} [{tname}] needs its latched "
                                    f"{'SkeletonInfo' if tname == 'SkeletonPose' else 'CharacterInfo'} "
                                    "(joint names, parents, rest offsets), which the bag lacks")
    parents = np.asarray(info.joint_parent, np.int64)
    rest = np.asarray(info.rest_offsets, np.float64)
    total = reader.topic_infos()[topic].count
    P, Q, stamps = [], [], []
    for i, (env, m) in enumerate(reader.decoded(topic)):
        if tname == "SkeletonPose":
            P.append(m.joint_positions)
            Q.append(m.joint_orientations)
        else:
            q, p = _character_world(m, parents, np.asarray(info.rest_rotations, np.float64))
            P.append(p)
            Q.append(q)
        stamps.append(env.capture_ns)
        if progress is not None and i % 256 == 0:
            progress(i, total)
    if not P:
        raise BagError(reader.path, f"topic {topic!r} holds no frames")
    J = len(info.joint_names)
    if P[0].shape[0] != J:
        raise BagError(reader.path, f"topic {topic!r} has {P[0].shape[0]} joints, its info names {J}")
    return SkeletonFrames(list(info.joint_names), parents, rest, np.stack(P), np.stack(Q),
                          np.asarray(stamps, np.int64), tname, topic)


def _character_world(m: CharacterPose, parents: np.ndarray, rest_rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World orientations from CharacterPose local rotations (child = parent * rest * local)."""
    J = len(parents)
    local = (Rotation.from_quat(rest_rot, scalar_first=True) * Rotation.from_quat(m.local_rotations, scalar_first=True)).as_matrix()
    world = np.empty((J, 3, 3))
    for j in topological_order(parents):
        p = parents[j]
        world[j] = local[j] if p < 0 else world[p] @ local[j]
    q = Rotation.from_matrix(world).as_quat(scalar_first=True)
    return q, np.asarray(m.joint_positions, np.float64)


def skeleton_to_bvh(sk: SkeletonFrames, frame_time_s: float) -> BvhMotion:
    """A BVH motion (centimetres, Y up, ZXY Euler channels) reproducing the world poses of ``sk``.

    Joint rotation in BVH axes = A^T (Q_parent^-1 Q_joint) A with A = BVH_TO_WORLD; offsets are the
    rest offsets in BVH axes; the root carries the world root position. Leaves named ``*_End``
    become End Sites.
    """
    J = len(sk.names)
    T = sk.positions.shape[0]
    bad = np.flatnonzero(~np.isfinite(sk.orientations).all(axis=(0, 2)))
    if bad.size:
        # BVH stores rotations; deriving them from positions alone is an IK step (kinematics), not a
        # file conversion
        raise BagError(None, f"joint orientations are missing ({sk.names[bad[0]]} and {len(bad) - 1} more "
                             "joints have NaN rotations; a positions-only source such as Kinect cannot "
                             "be written as BVH)")
    order = topological_order(sk.parents)
    new_index = np.empty(J, np.int64)
    new_index[order] = np.arange(J)
    parents = np.array([new_index[sk.parents[j]] if sk.parents[j] >= 0 else -1 for j in order])
    names = [sk.names[j] for j in order]
    children = np.zeros(J, bool)
    children[parents[parents >= 0]] = True
    is_end = np.array([(not children[k]) and names[k].endswith("_End") for k in range(J)])
    A = BVH_TO_WORLD
    offsets = (sk.rest_offsets[order] @ A) / BVH_UNITS_M  # rows: A^T v
    roots = np.flatnonzero(parents < 0)
    if len(roots) != 1:
        raise BagError(None, f"a BVH needs exactly one root joint, this skeleton has {len(roots)}")
    root = int(roots[0])
    offsets[root] = 0.0
    Rw = Rotation.from_quat(sk.orientations[:, order].reshape(-1, 4), scalar_first=True).as_matrix().reshape(T, J, 3, 3)
    par_R = np.where((parents >= 0)[None, :, None, None], Rw[:, np.maximum(parents, 0)], np.eye(3))
    local_w = np.einsum("tjki,tjkl->tjil", par_R, Rw)  # parent^T @ joint
    local_b = np.einsum("ki,tjkl,lm->tjim", A, local_w, A)  # A^T L A
    channels: list[list[str]] = []
    cols: list[np.ndarray] = []
    rot_names = ["Zrotation", "Xrotation", "Yrotation"]
    for k in range(J):
        if is_end[k]:
            channels.append([])
            continue
        if k == root:
            channels.append(["Xposition", "Yposition", "Zposition"] + rot_names)
            cols.append((sk.positions[:, order[k]] @ A) / BVH_UNITS_M)
        else:
            channels.append(list(rot_names))
        cols.append(Rotation.from_matrix(local_b[:, k]).as_euler("ZXY", degrees=True))
    values = np.concatenate(cols, axis=1) if cols else np.zeros((T, 0))
    return BvhMotion(names=names, parents=parents, offsets=offsets, channels=channels, is_end_site=is_end,
                     frame_time_s=frame_time_s, values=values, scale=BVH_UNITS_M)


# ----- CSV ---------------------------------------------------------------------------------------------
COMPANIONS: dict[str, tuple[str, dict[str, str]]] = {
    "MarkerFrame": ("MarkerLayout", {"N": "labels"}),
    "SkeletonPose": ("SkeletonInfo", {"J": "joint_names"}),
    "CharacterPose": ("CharacterInfo", {"J": "joint_names"}),
    "ActorPose": ("SkeletonModel", {"J": "joint_names", "L": "limb_names"}),
    "PhysicsState": ("PhysicsScene", {"B": "body_names"}),
    "Diagnostics": ("", {}),
}
_AXES = {3: "xyz", 4: "wxyz"}


def _column_names(cls: type[Message], msg: Message, names: dict[str, list[str]]) -> list[str]:
    cols = ["capture_s", "seq"]
    for fname, spec in cls.fields().items():
        if isinstance(spec, Scalar):
            cols.append(fname)
        elif isinstance(spec, Strings):
            cols.append(fname)
        elif isinstance(spec, Array):
            arr = getattr(msg, fname)
            first = names.get(spec.shape[0]) if spec.shape and isinstance(spec.shape[0], str) else None
            idx = np.ndindex(*arr.shape) if arr.ndim else [()]
            for ix in idx:
                parts = []
                for d, k in enumerate(ix):
                    if d == 0 and first is not None and k < len(first):
                        parts.append(first[k])
                    elif d == arr.ndim - 1 and arr.shape[d] in _AXES and d > 0:
                        parts.append(_AXES[arr.shape[d]][k])
                    else:
                        parts.append(str(k))
                cols.append(fname + ("_" + "_".join(parts) if parts else ""))
    return cols


def bag_to_csv(reader: BagReader, out: str | Path, topic: str, progress: Progress | None = None) -> int:
    """One row per message of ``topic``: capture time (s from the bag's first capture), seq, fields.
    Arrays are flattened, named after the latched labels when the bag has them. Returns rows."""
    infos = reader.topic_infos()
    if topic not in infos:
        raise BagError(reader.path, f"has no topic {topic!r} (topics: {', '.join(sorted(infos))})")
    info = infos[topic]
    comp_type, symbols = COMPANIONS.get(info.type_name, ("", {}))
    names: dict[str, list[str]] = {}
    if comp_type:
        comp = _latest_of_type(reader, comp_type)
        if comp is not None:
            names = {sym: list(getattr(comp, f)) for sym, f in symbols.items()}
    out = Path(out)
    n = 0
    t0 = None
    try:
        f = open(out, "w", newline="")
    except OSError as exc:
        raise BagError(out, f"cannot write ({exc.strerror or exc})") from None
    with f:
        w = csv.writer(f)
        cols: list[str] | None = None
        for env, msg in reader.decoded(topic):
            if cols is None:
                cols = _column_names(type(msg), msg, names)
                w.writerow(cols)
                t0 = env.capture_ns
            row: list = [f"{(env.capture_ns - t0) / 1e9:.9f}", env.seq]
            for fname, spec in msg.fields().items():
                v = getattr(msg, fname)
                if isinstance(spec, Array):
                    flat = v.ravel()
                    row.extend(flat.astype(np.int64).tolist() if v.dtype == bool else flat.tolist())
                elif isinstance(spec, Strings):
                    row.append("|".join(v))
                else:
                    row.append(v)
            if len(row) != len(cols):
                raise BagError(reader.path, f"topic {topic!r} changes its array sizes at message {n + 1}; "
                                            "CSV needs fixed columns")
            w.writerow(row)
            n += 1
            if progress is not None and n % 256 == 0:
                progress(n, info.count)
    return n


def bag_to_file(src: str | Path, dst: str | Path, *, topic: str | None = None, units: str = "mm",
                progress: Progress | None = None) -> ConvertReport:
    """Export a bag topic to CSV, TRC, C3D (markers) or BVH (skeleton/character poses)."""
    from ..formats.c3d_file import write_c3d
    from ..formats.trc_file import write_trc

    src, dst = Path(src), Path(dst)
    kind = OUTPUT_KINDS.get(dst.suffix.lower())
    if kind is None:
        raise BagError(dst, f"cannot write a {dst.suffix or 'extensionless'} file from a bag "
                            f"(known: {', '.join(sorted(OUTPUT_KINDS))})")
    with BagReader(src) as r:
        rep = ConvertReport(src, dst, "bag")
        try:
            if kind == "csv":
                if topic is None:
                    found = [t for t, i in r.topic_infos().items() if i.known and not i.latched and t != "diagnostics"]
                    if len(found) != 1:
                        raise BagError(src, f"choose the topic to write with --topic (topics: {', '.join(sorted(r.topic_infos()))})")
                    topic = found[0]
                rep.topics[topic] = bag_to_csv(r, dst, topic, progress)
            elif kind in ("trc", "c3d"):
                trial = bag_to_marker_trial(r, topic, progress)
                (write_trc if kind == "trc" else write_c3d)(dst, trial, units=units)
                rep.topics[trial.source.rsplit(":", 1)[-1]] = trial.n_frames
                rep.notes.append(f"{trial.n_markers} markers x {trial.n_frames} frames @ {trial.rate_hz:g} Hz, {units}")
            else:
                sk = bag_to_skeleton_frames(r, topic, progress)
                d = np.diff(sk.capture_ns.astype(np.float64))
                frame_time = float(np.median(d)) / 1e9 if d.size else 1 / 30
                try:
                    motion = skeleton_to_bvh(sk, frame_time)
                except BagError as exc:
                    raise BagError(src, exc.fault) from None
                write_bvh(dst, motion)
                rep.topics[sk.topic] = sk.positions.shape[0]
                rep.notes.append(f"{len(sk.names)} joints, frame time {frame_time * 1e3:.3f} ms, centimetres, Y up")
        except FormatError as exc:
            raise BagError(dst, exc.fault) from None
    if progress is not None:
        progress(1, 1)
    return rep
