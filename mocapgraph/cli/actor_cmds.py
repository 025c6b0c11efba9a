"""``mocapgraph calibrate`` and ``mocapgraph solve``: the actor pipeline on files, batch.

The same code as the live nodes: label matching (:mod:`mocapgraph.adapters.model_messages`),
:func:`~mocapgraph.kinematics.calibration.calibrate.calibrate`,
:class:`~mocapgraph.kinematics.solving.solver.FrameSolver`
(batch ``solve`` runs the very temporal stage ``step`` runs live) and the ActorPose conversion.

Inputs: C3D, TRC, or a bag (.mcap, its MarkerFrame topic + latched MarkerLayout).
Times: ``time_s`` columns keep the input's own clock (a TRC's Time column; C3D frame n at
(n - 1) / rate), so a trial starting 0.23 s into the capture starts at 0.23 there too.
Outputs of ``solve``: CSV (one row per frame: frame, time_s, then per joint x/y/z in metres, world
frame Z up, empty where missing, and quality 0 missing / 1 estimated / 2 good), TRC of the joint centres, or
a bag with the latched ``skeleton_model`` and one ``actor_pose`` per frame.
"""
from __future__ import annotations

import argparse
import csv
import math
import warnings
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from . import UserError
from .progress import Progress

if TYPE_CHECKING:   # annotations only: the command loads its readers when it runs
    from ..bag.sources import MarkerInput

OUTPUT_KINDS = (".csv", ".trc", ".mcap")


def read_marker_input(path: str, topic: str | None = None, up: str = "auto") -> MarkerInput:
    """A C3D, TRC or bag file as markers (``bag.sources.read_marker_input``); UserError (one line)
    when it cannot be read, a warning printed for each duplicate label.

    up: the file's up axis ("auto": what the file says, see ``--up``); bags are already in
    world axes, so anything but "auto" is refused for them.
    """
    from ..bag import sources
    from ..bag.errors import BagError
    from ..formats import FormatError

    p = Path(path)
    if not p.exists():
        raise UserError(f"{path}: no such file")
    if p.suffix.lower() == ".mcap" and up != "auto":
        raise UserError(f"{p.name}: --up {up} applies to C3D and TRC files; a bag is already "
                        "in world axes (Z up)")
    try:
        inp = sources.read_marker_input(p, topic, up)
    except (FormatError, BagError) as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror or exc})") from None
    for note in inp.notes:
        if note.startswith("duplicate label"):
            print(f"warning: {p.name}: {note}")
    return inp


def parse_frames(spec: str, n: int, source: str) -> slice:
    """``a:b`` (0-based, end exclusive, either side may be empty, negatives from the end)."""
    a, sep, b = spec.partition(":")
    try:
        if not sep:
            raise ValueError
        start = int(a) if a.strip() else None
        stop = int(b) if b.strip() else None
    except ValueError:
        raise UserError(f"--frames {spec!r}: expected a:b (0-based frame indices, end excluded)") from None
    sl = slice(start, stop)
    if len(range(*sl.indices(n))) == 0:
        raise UserError(f"{source}: --frames {spec} selects no frames of its {n}")
    return sl


def _definition(layout: str):
    from ..kinematics.layout import LayoutError, available_layouts, layout_path
    from ..kinematics.skeleton import SkeletonDefinition

    p = layout_path(layout)
    if not p.exists():
        raise UserError(f"unknown layout {layout!r}: no file {p} (shipped layouts: {', '.join(available_layouts())})")
    try:
        return SkeletonDefinition.from_layout_file(p)
    except LayoutError as exc:
        raise UserError(str(exc)) from None


# ----- calibrate ---------------------------------------------------------------------------------
def _print_centre_inputs(model: Any) -> None:
    """What each anatomical or regression centre was built from (landmarks; regression inputs, mm)."""
    for j, inp_j in enumerate(model.quality.inputs):
        if "landmarks" in inp_j:
            print(f"  {model.joint_names[j]}: midpoint of {' and '.join(inp_j['landmarks'])}")
        elif "regression" in inp_j:
            vals = ", ".join(f"{k[:-2]} {1000 * v:.1f} mm" for k, v in inp_j.items() if k.endswith("_m") and isinstance(v, float))
            print(f"  {model.joint_names[j]}: {inp_j['regression']} ({vals}; subject from {inp_j.get('subject', '?')})")


def cmd_calibrate(args: argparse.Namespace) -> int:
    from ..kinematics.calibration.calibrate import CalibrationError, CalibrationWarning, calibrate, layout_markers
    from ..kinematics.model import save_model
    from ..adapters.model_messages import quality_table

    definition = _definition(args.layout)
    frames = args.frames or []
    if len(frames) not in (0, 1, len(args.files)):
        raise UserError(f"--frames given {len(frames)} times for {len(args.files)} files "
                        "(give it once for all files, or once per file)")
    order = tuple(m.strip() for m in args.centres.split(",") if m.strip())
    from ..kinematics.calibration.centres import METHODS

    bad = [m for m in order if m not in METHODS]
    if bad or not order:
        raise UserError(f"--centres {args.centres!r}: expected a comma list of {', '.join(METHODS)}")
    # Landmarks the layout names (medial knee, malleoli) may be in the first file (the static) only.
    landmark = {definition.marker_labels[k] for pair in (getattr(definition, "joint_landmarks", ()) or ())
                for k in pair}
    parts, rate, names, inputs = [], None, [], []
    report = _report_path(args.report, args.output)
    bar = Progress("calibrating", unit="step", total=len(args.files) + 2 + (report is not None))
    absent_everywhere: set[str] | None = None
    for i, f in enumerate(args.files):
        inp = read_marker_input(f, args.topic, args.up)
        bar.advance()
        inputs.append(inp)
        where, _ = definition.match_labels(list(inp.labels))
        absent = [definition.marker_labels[m] for m in np.flatnonzero(where < 0)]
        static_only = [m for m in absent if i > 0 and m in landmark]
        others = [m for m in absent if m not in static_only]
        if others and args.allow_missing:
            print(f"note: {inp.path.name}: {len(others)} layout markers absent (always missing): "
                  f"{', '.join(others)}")
        if static_only:
            print(f"{inp.path.name}: lacks {len(static_only)} landmarks of {Path(args.files[0]).name}: "
                  f"static-only, not needed later: {', '.join(static_only)}")
        absent_everywhere = set(absent) if absent_everywhere is None else absent_everywhere & set(absent)
        if others and not args.allow_missing:  # --help tells of --allow-missing
            raise UserError(f"{inp.path.name}: layout '{definition.name}' names markers the capture lacks: "
                            f"{', '.join(others)}")
        try:
            x = layout_markers(definition, inp.labels, inp.positions, source=inp.path.name, allow_missing=True)
        except CalibrationError as exc:
            raise UserError(str(exc)) from None  # --help tells of --allow-missing
        if frames:
            x = x[parse_frames(frames[i] if len(frames) > 1 else frames[0], len(x), inp.path.name)]
        seen = np.isfinite(x).all(-1)
        if not seen.any():
            raise UserError(f"{inp.path.name}: no layout marker is visible in any selected frame")
        print(f"{inp.path.name}: {len(x)} frames at {inp.rate_hz:g} Hz, {definition.n_markers} layout markers "
              f"({100 * (1 - seen.mean()):.1f} % missing samples)")
        parts.append(x)
        names.append(inp.path.name)
        rate = rate or inp.rate_hz
    if absent_everywhere:
        gone = [m for m in definition.marker_labels if m in absent_everywhere]
        raise UserError(f"layout '{definition.name}' markers absent from every file: {', '.join(gone)} "
                        "(the base pose needs each layout marker in at least one file; use a layout "
                        "without them)")
    markers = np.concatenate(parts)
    subject = _subject(args, inputs[0])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationWarning)
        try:
            model = calibrate(definition, markers, base_frame=args.base_frame, rate_hz=rate,
                              max_base_search_s=args.base_search_s, min_rom_deg=args.min_rom_deg,
                              source=" + ".join(Path(f).name for f in args.files), centre_order=order,
                              max_residual_mm=args.max_residual_mm, subject=subject,
                              max_uncertainty_mm=args.max_uncertainty_mm,
                              parts=list(zip(names, [len(p) for p in parts])))
        except CalibrationError as exc:
            raise UserError(str(exc)) from None
        except IndexError:
            raise UserError(f"--base-frame {args.base_frame} is outside the {len(markers)} frames") from None
    bar.advance()
    print(f"layout {definition.name}: {len(model.joint_names)} joints from {len(markers)} frames")
    print(quality_table(model))
    _print_centre_inputs(model)
    for w in caught:
        if issubclass(w.category, CalibrationWarning):
            print(f"warning: {w.message}")
    try:
        save_model(model, args.output)
    except OSError as exc:
        raise UserError(f"{args.output}: cannot write ({exc.strerror or exc})") from None
    print(f"wrote {args.output}")
    if report is not None:
        from ..reports.calibration_report import write_report

        try:
            write_report(report, model, markers, source=" + ".join(Path(f).name for f in args.files),
                         model_path=str(args.output), min_rom_deg=args.min_rom_deg)
        except OSError as exc:
            raise UserError(f"{report}: cannot write ({exc.strerror or exc})") from None
        print(f"wrote {report}")
    bar.close()
    return 0


def _report_path(arg: str | None, model_path: str) -> Path | None:
    """Where ``--report`` goes: a bare file name lands next to the model file; '' picks the name."""
    if arg is None:
        return None
    model = Path(model_path)
    p = Path(arg) if arg else model.with_name(model.stem + "_report.html")
    if p.suffix.lower() not in (".html", ".png"):
        raise UserError(f"--report {arg}: give a .html or .png file")
    return model.parent / p if p.parent == Path(".") else p


def _subject(args: argparse.Namespace, first: MarkerInput):
    """Subject measurements: a C3D's PROCESSING parameters, then --vsk, then --subject (each
    overriding the one before); None when there are none."""
    from ..kinematics.subject import Subject, SubjectError, parse_subject_args, read_c3d_processing, read_vsk

    sub = Subject()
    try:
        if first.path.suffix.lower() == ".c3d":
            sub = sub.merged(read_c3d_processing(first.path))
        if args.vsk:
            sub = sub.merged(read_vsk(args.vsk))
        if args.subject:
            sub = sub.merged(parse_subject_args(args.subject))
    except SubjectError as exc:
        raise UserError(str(exc)) from None
    if not sub.empty:
        known = ", ".join(f"{k} {1000 * v:.1f} mm" for k, v in sub.as_dict().items() if isinstance(v, float))
        print(f"subject ({sub.source}): {known}")
    return None if sub.empty else sub


# ----- solve -------------------------------------------------------------------------------------
def cmd_solve(args: argparse.Namespace) -> int:
    from ..kinematics.model import ModelFileError, load_model
    from ..kinematics.solving.solver import FrameSolver
    from ..adapters.marker_columns import model_order

    out = Path(args.output)
    if out.suffix.lower() not in OUTPUT_KINDS:
        raise UserError(f"{out}: unknown output type {out.suffix or '(none)'!r} (expected .csv, .trc or .mcap)")
    try:
        model = load_model(args.model)
    except ModelFileError as exc:
        raise UserError(str(exc)) from None
    inp = read_marker_input(args.trial, args.topic, args.up)
    where, missing = _place(model, inp, args.allow_missing)
    x = model_order(inp, where)
    numbers, times = inp.frame_numbers, inp.times()
    if args.frames:
        sl = parse_frames(args.frames, len(x), inp.path.name)
        x, numbers, times = x[sl], numbers[sl], times[sl]
    if not np.isfinite(x).all(-1).any():
        raise UserError(f"{inp.path.name}: no model marker is visible in any frame (all NaN)")
    if missing:
        print(f"note: {len(missing)} model markers absent from {inp.path.name} (always missing): {', '.join(missing)}")
    noise_scale = 1.0
    if args.lowpass != "off":
        x, noise_scale = _lowpass(x, inp.rate_hz, args.lowpass)
    try:
        solver = FrameSolver(model, rate_hz=inp.rate_hz, max_gap_s=args.max_gap_s,
                             enforce_lengths=not args.no_enforce_lengths, filter=args.filter or None,
                             fit=args.fit, noise_scale=noise_scale)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    res = _solve_chunks(solver, x, times)
    q = res.joint_quality
    T, J = q.shape
    print(f"{inp.path.name}: {T} frames, {J} joints: {100 * (q == 2).mean():.1f} % good, "
          f"{100 * (q == 1).mean():.1f} % estimated, {100 * (q == 0).mean():.1f} % missing")
    bad = [model.joint_names[j] for j in range(J) if (q[:, j] == 0).all()]
    if bad:
        print(f"note: never solved (too few markers): {', '.join(bad)}")
    kind = out.suffix.lower()
    try:
        if kind == ".csv":
            _write_csv(out, model, res, numbers, times)
        elif kind == ".trc":
            from ..formats import FormatError, MarkerTrial, write_trc

            try:
                write_trc(out, MarkerTrial(labels=list(model.joint_names), positions=res.joints, residuals=None,
                                           rate_hz=inp.rate_hz, first_frame=int(numbers[0]),
                                           source=f"joint centres solved from {inp.path.name}",
                                           extra={"time_s": times}))
            except FormatError as exc:
                raise UserError(str(exc)) from None
        else:
            _write_bag(out, model, res, numbers, times, args.actor, inp)
    except OSError as exc:
        raise UserError(f"{out}: cannot write ({exc.strerror or exc})") from None
    print(f"wrote {out}")
    return 0


def _lowpass_spec(text: str) -> str:
    """argparse type of --lowpass: off, auto or a positive number (Hz)."""
    if text in ("off", "auto"):
        return text
    try:
        if float(text) > 0:
            return text
    except ValueError:
        pass
    raise argparse.ArgumentTypeError(f"expected off, auto or a cutoff in Hz, got {text!r}")


def _lowpass(x: np.ndarray, rate_hz: float, spec: str) -> tuple[np.ndarray, float]:
    """Markers low-passed before the solve (``kinematics.solving.lowpass``) and their noise gain."""
    from ..kinematics.solving.lowpass import lowpass_markers

    if not rate_hz or not math.isfinite(rate_hz) or rate_hz <= 0:
        raise UserError(f"--lowpass {spec}: the trial gives no capture rate to filter at")
    try:
        out, rep = lowpass_markers(x, rate_hz, spec if spec == "auto" else float(spec))
    except ValueError as exc:
        raise UserError(f"--lowpass {spec}: {exc}") from None
    if rep.cutoff_hz is None:
        print("note: --lowpass left the markers raw (no marker seen for 16 frames in a row)")
    else:
        how = "chosen by cross-validation" if spec == "auto" else "as given"
        print(f"low-pass: zero-lag Butterworth at {rep.cutoff_hz:g} Hz ({how}); marker noise x{rep.noise_gain:.2f}")
    return out, rep.noise_gain


SOLVE_CHUNK = 500  # frames per solver call: a bar that moves, same result as one call


def _solve_chunks(solver, x: np.ndarray, times: np.ndarray):
    """``solver.solve`` over float[T,M,3] in chunks (the solver carries its state across calls)."""
    from ..kinematics.solving.solver import SolverResult

    parts = []
    with Progress("solving", total=len(x)) as bar:
        for a in range(0, len(x), SOLVE_CHUNK):
            parts.append(solver.solve(x[a:a + SOLVE_CHUNK], times[a:a + SOLVE_CHUNK]))
            bar.advance(len(parts[-1].joints))
    if len(parts) == 1:
        return parts[0]
    return SolverResult(*(np.concatenate([getattr(r, f.name) for r in parts]) for f in fields(SolverResult)))


def _place(model, inp: MarkerInput, allow_missing: bool) -> tuple[np.ndarray, list[str]]:
    """Model marker -> input column (-1 absent) and the absent labels (``adapters.marker_columns``);
    UserError for another layout or absent markers."""
    from ..adapters.marker_columns import place_markers
    from ..kinematics.model import ModelFileError
    try:
        return place_markers(model, inp, allow_missing)
    except ModelFileError as exc:
        raise UserError(f"{exc}" + ("" if allow_missing else "; --allow-missing solves without them")) from None


def _write_csv(out: Path, model, res, numbers: np.ndarray, times: np.ndarray) -> None:
    cols = ["frame", "time_s"]
    for n in model.joint_names:
        cols += [f"{n}_x_m", f"{n}_y_m", f"{n}_z_m", f"{n}_quality"]
    T, J = res.joint_quality.shape
    table = np.concatenate([res.joints, res.joint_quality[..., None].astype(float)], axis=-1).reshape(T, 4 * J)
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for t in range(T):
            cells = ["" if math.isnan(v) else (f"{v:.0f}" if k % 4 == 3 else f"{v:.6f}")
                     for k, v in enumerate(table[t].tolist())]
            w.writerow([int(numbers[t]), f"{times[t]:.6f}", *cells])


def _write_bag(out: Path, model, res, numbers: np.ndarray, times: np.ndarray, actor: str, inp: MarkerInput) -> None:
    from ..bag.errors import BagError
    from ..bag.writer import BagWriter, base_metadata
    from ..adapters.model_messages import model_to_message, pose_message

    stamps = np.round(times * 1e9).astype(np.int64)
    try:
        with BagWriter(out, metadata=base_metadata("mocapgraph solve", source=str(inp.path))) as w:
            w.write("skeleton_model", model_to_message(model), seq=1, capture_ns=int(stamps[0]), sender="solve")
            for t in range(len(stamps)):
                w.write("actor_pose", pose_message(res[t], actor, int(numbers[t])), seq=t + 1,
                        capture_ns=int(stamps[t]), sender="solve")
    except BagError as exc:
        raise UserError(str(exc)) from None


# ----- registration ------------------------------------------------------------------------------
def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="calibrate an actor skeleton model from static/ROM files",
                       description="Calibrate from one or more marker files (C3D, TRC, bag), concatenated after "
                                   "matching them to the layout: e.g. a static trial then a range-of-motion trial. "
                                   "The base pose is the first frame with every marker visible.")
    p.add_argument("files", nargs="+", metavar="FILE", help="static and/or range-of-motion files")
    p.add_argument("--layout", required=True, help="marker layout name (graph_configs/marker_layouts) or YAML path")
    p.add_argument("-o", "--output", required=True, help="model JSON to write")
    p.add_argument("--frames", action="append", metavar="A:B",
                   help="frames to use (0-based, end excluded); once for all files or once per file")
    p.add_argument("--base-frame", type=int, default=None, help="base-pose frame index in the concatenated frames")
    p.add_argument("--base-search-s", type=float, default=10.0, help="seconds searched for a base pose")
    p.add_argument("--min-rom-deg", type=float, default=25.0, help="joints moving less are unreliable, deg")
    p.add_argument("--topic", help="marker topic of bag inputs (when a bag has several)")
    p.add_argument("--report", nargs="?", const="", metavar="REPORT.html|png",
                   help="also write a report (per-joint residual and ROM bars, marker residuals over time, "
                        "joint centres on the base pose); a bare name goes next to the model file, "
                        "no name gives <model>_report.html")
    p.add_argument("--centres", default="functional,anatomical,regression",
                   help="joint-centre methods in order of preference, per joint the first that applies "
                        "(functional: SCoRE/SARA; anatomical: layout landmarks; regression: Plug-in Gait / "
                        "Harrington with subject measurements); e.g. regression,anatomical for Plug-in Gait")
    p.add_argument("--max-residual-mm", type=float, default=None,
                   help="functional centres with a larger residual are not trusted (default: none when the "
                        "residuals are marker noise, 10 mm when they are skin motion)")
    p.add_argument("--max-uncertainty-mm", type=float, default=2.0,
                   help="functional centres with a larger standard error are not reliable (when the residuals are noise)")
    p.add_argument("--vsk", metavar="FILE", help="Vicon VSK subject file (leg lengths, knee/ankle widths, ...)")
    p.add_argument("--subject", action="append", metavar="KEY=MM",
                   help="subject measurement in mm, e.g. LeftLegLength=877,RightKneeWidth=139 (repeatable; "
                        "overrides --vsk and a C3D's PROCESSING parameters)")
    p.add_argument("--allow-missing", action="store_true",
                   help="a layout marker absent from a file is missing there (named per file) instead of "
                        "an error; each marker must still be in some file")
    _add_up(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("solve", help="solve a marker trial with a calibrated model",
                       description="Joint centres of every frame of a trial (C3D, TRC, bag) -> CSV, TRC or bag.")
    p.add_argument("trial", metavar="TRIAL")
    p.add_argument("--model", required=True, help="model JSON from `mocapgraph calibrate` or a calibration node")
    p.add_argument("-o", "--output", required=True, help="out.csv, out.trc (joint centres) or out.mcap")
    p.add_argument("--frames", metavar="A:B", help="frames to solve (0-based, end excluded)")
    p.add_argument("--max-gap-s", type=float, default=0.1, help="longest gap predicted over, s (0: none)")
    p.add_argument("--filter", default="", choices=("", "one_euro", "constant_velocity"), help="joint filter")
    p.add_argument("--lowpass", default="off", type=_lowpass_spec, metavar="off|auto|HZ",
                   help="zero-lag low-pass of the markers before solving: a cutoff in Hz, or auto "
                        "(chosen by cross-validation); off by default")
    p.add_argument("--no-enforce-lengths", action="store_true", help="do not keep calibrated bone lengths")
    p.add_argument("--fit", default="segment", choices=("segment", "global"),
                   help="limb poses one by one (segment) or all together under the joint constraints (global)")
    p.add_argument("--allow-missing", action="store_true", help="solve even if some model markers are absent")
    p.add_argument("--actor", default="actor", help="actor name in bag output")
    p.add_argument("--topic", help="marker topic of a bag input (when it has several)")
    _add_up(p)
    p.set_defaults(func=cmd_solve)


UP_HELP = ("the input files' up axis, made world Z: auto = what each file says (C3D POINT:Y_SCREEN, else Z; "
           "TRC: Y, the OpenSim convention)")


def _add_up(p: argparse.ArgumentParser) -> None:
    p.add_argument("--up", choices=("auto", "y", "z"), default="auto", type=str.lower, help=UP_HELP)
