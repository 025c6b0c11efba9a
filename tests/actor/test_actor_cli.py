"""``mocapgraph calibrate`` / ``mocapgraph solve`` on files written from the synthetic actor
(TRC, C3D, bag) against its ground truth, bad input as one-line errors, and the real pyCGM files."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import yaml

from actor_support import quick_model
from mocapgraph.bag.convert import file_to_bag
from mocapgraph.bag.reader import BagReader
from mocapgraph.cli import main
from mocapgraph.formats import MarkerTrial, read_trc, write_c3d, write_trc
from mocapgraph.kinematics.layout import layout_path
from mocapgraph.kinematics.model import load_model, save_model
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from mocapgraph.kinematics.synthetic.motion import MotionScript

pytestmark = pytest.mark.slow  # the calibrate/solve commands as processes, on real captures

RATE = 120.0


def _trial(cap, sl, drop=()) -> MarkerTrial:
    labels = list(cap.skeleton.marker_labels)
    keep = [i for i, l in enumerate(labels) if l not in drop]
    return MarkerTrial(labels=[labels[i] for i in keep], positions=cap.markers[sl][:, keep], residuals=None,
                       rate_hz=RATE)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("actor_cli")
    cap = SyntheticActor("kiip_full_body", rate=RATE, seed=5, script=MotionScript(gym_block_s=2.0),
                         options=CaptureOptions(noise_mm=1.0)).capture()
    gym_end = cap.phases["gym"][1]
    perf = cap.phase_slice("performance")
    write_trc(d / "rom.trc", _trial(cap, slice(0, gym_end)))
    write_c3d(d / "static.c3d", _trial(cap, slice(0, 60)))
    write_c3d(d / "trial.c3d", _trial(cap, perf))
    write_trc(d / "no_lkne.trc", _trial(cap, slice(0, gym_end), drop=("LKNE",)))
    still = SyntheticActor("kiip_full_body", rate=RATE, seed=5, script=MotionScript(gym_block_s=2.0, gym_scale=0.02),
                           options=CaptureOptions(noise_mm=1.0)).capture(0, gym_end)
    write_trc(d / "still.trc", _trial(still, slice(None)))
    nan = _trial(cap, slice(0, 50))
    nan.positions[:] = np.nan
    write_trc(d / "all_nan.trc", nan)
    file_to_bag(d / "rom.trc", d / "rom.mcap")
    return d, cap.joint_centres[perf]


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def _csv_joints(path, J):
    d = np.genfromtxt(path, delimiter=",", skip_header=1)
    return d[:, 2:].reshape(len(d), J, 4)


def test_calibrate_then_solve_to_csv_trc_and_bag(files, capsys, tmp_path):
    d, truth = files
    code, out, _ = run(capsys, "calibrate", d / "rom.trc", "--layout", "kiip_full_body", "-o", tmp_path / "m.json")
    assert code == 0
    table = out[out.index("joint "):].splitlines()
    assert len([l for l in table if l.rstrip().endswith("yes")]) == 16, out
    model = load_model(tmp_path / "m.json", "kiip_full_body", load_model(tmp_path / "m.json").marker_labels)
    J = len(model.joint_names)
    for ext in ("csv", "trc", "mcap"):
        code, out, _ = run(capsys, "solve", d / "trial.c3d", "--model", tmp_path / "m.json", "-o", tmp_path / f"o.{ext}")
        assert code == 0 and "100.0 % good" in out, out
    csv = _csv_joints(tmp_path / "o.csv", J)
    assert (csv[..., 3] == 2).all()
    err = np.linalg.norm(csv[..., :3] - truth, axis=-1)
    print(f"\nbatch TRC gym -> C3D trial: joint error mean {1000 * err.mean():.2f} mm, max {1000 * err.max():.2f} mm")
    assert err.mean() < 0.005 and err.max() < 0.02
    # The markers low-passed first (cutoff by cross-validation): closer to the truth, and the
    # uncertainty in the bag scaled down with the noise, still covering the error.
    code, out, _ = run(capsys, "solve", d / "trial.c3d", "--model", tmp_path / "m.json", "--lowpass", "auto",
                       "-o", tmp_path / "lp.mcap")
    assert code == 0 and "low-pass: zero-lag Butterworth at" in out, out
    with BagReader(tmp_path / "lp.mcap") as bag:
        lp = [m for _, m in bag.decoded("actor_pose")]
    lp_err = np.linalg.norm(np.array([p.joint_positions for p in lp]) - truth, axis=-1)
    unc = np.array([p.joint_uncertainty for p in lp])
    with capsys.disabled():
        print(f"\n{next(l for l in out.splitlines() if l.startswith('low-pass'))} -> joint error mean {1000 * lp_err.mean():.2f} mm, max {1000 * lp_err.max():.2f} mm "
              f"(raw {1000 * err.mean():.2f} / {1000 * err.max():.2f}); within 3 reported uncertainties: "
              f"{100 * (lp_err <= 3 * unc).mean():.1f} % of joint-frames")
    assert lp_err.mean() < 0.9 * err.mean() and lp_err.max() <= err.max()
    assert (lp_err <= 3 * unc).mean() >= 0.95
    code, out, err_text = run(capsys, "solve", d / "trial.c3d", "--model", tmp_path / "m.json", "--lowpass", "70",
                              "-o", tmp_path / "bad.csv")
    assert code != 0 and "--lowpass 70: low-pass cutoff 70 Hz must be between 0 and half the rate" in out + err_text
    trc = read_trc(tmp_path / "o.trc")
    assert trc.labels == list(model.joint_names)
    np.testing.assert_allclose(trc.positions, csv[..., :3], atol=2e-6)
    with BagReader(tmp_path / "o.mcap") as bag:
        bag_poses = [m for _, m in bag.decoded("actor_pose")]
        (bag_model,) = [m for _, m in bag.decoded("skeleton_model")]
    assert bag_model.joint_names == list(model.joint_names)
    np.testing.assert_allclose(np.array([p.joint_positions for p in bag_poses]), csv[..., :3], atol=1e-6)


def test_static_plus_rom_files_and_a_bag_give_the_same_kind_of_model(files, capsys, tmp_path):
    d, truth = files
    code, out, _ = run(capsys, "calibrate", d / "static.c3d", d / "rom.trc", "--layout", "kiip_full_body",
                       "--frames", ":", "--frames", "60:", "-o", tmp_path / "two.json")
    assert code == 0 and "static.c3d: 60 frames" in out and "rom.trc: 1020 frames" in out, out
    code, _, _ = run(capsys, "solve", d / "trial.c3d", "--model", tmp_path / "two.json", "-o", tmp_path / "two.csv")
    err = np.linalg.norm(_csv_joints(tmp_path / "two.csv", truth.shape[1])[..., :3] - truth, axis=-1)
    assert code == 0 and err.mean() < 0.005
    # A bag of the same capture calibrates to the very same model file as the TRC.
    assert run(capsys, "calibrate", d / "rom.mcap", "--layout", "kiip_full_body", "-o", tmp_path / "bag.json")[0] == 0
    assert run(capsys, "calibrate", d / "rom.trc", "--layout", "kiip_full_body", "-o", tmp_path / "trc.json")[0] == 0
    assert (tmp_path / "bag.json").read_text() == (tmp_path / "trc.json").read_text()


def test_bad_input_is_one_clear_line(files, capsys, tmp_path):
    d, _ = files
    arm = tmp_path / "arm.json"
    save_model(quick_model("one_arm"), arm)
    kiip = tmp_path / "kiip.json"
    assert run(capsys, "calibrate", d / "rom.trc", "--layout", "kiip_full_body", "-o", kiip)[0] == 0
    lay = yaml.safe_load(layout_path("one_arm").read_text())
    lay["limbs"][2]["markers"] = lay["limbs"][2]["markers"][:2]
    few = tmp_path / "few.yaml"
    few.write_text(yaml.safe_dump(lay))
    (tmp_path / "broken.json").write_text("{not json")
    cases = [
        (["calibrate", d / "no_lkne.trc", "--layout", "kiip_full_body", "-o", tmp_path / "x.json"],
         "no_lkne.trc: layout 'kiip_full_body' names markers the capture lacks: LKNE"),
        (["calibrate", d / "rom.trc", "--layout", few, "-o", tmp_path / "x.json"],
         "limb `forearm_r` has 2 marker(s)"),
        (["calibrate", d / "still.trc", "--layout", "kiip_full_body", "-o", tmp_path / "x.json"],
         "still.trc: gym capture has almost no motion (every joint below 25 deg)"),
        (["calibrate", d / "all_nan.trc", "--layout", "kiip_full_body", "-o", tmp_path / "x.json"],
         "all_nan.trc: no layout marker is visible in any selected frame"),
        (["solve", d / "all_nan.trc", "--model", kiip, "-o", tmp_path / "x.csv"],
         "all_nan.trc: no model marker is visible in any frame"),
        (["solve", d / "trial.c3d", "--model", arm, "-o", tmp_path / "x.csv"],
         "trial.c3d: lacks 1 of the 12 markers of model 'one_arm': CLAV; --allow-missing solves without them"),
        (["solve", d / "rom.mcap", "--model", arm, "-o", tmp_path / "x.csv"],
         "rom.mcap: model was calibrated for layout 'one_arm', but the markers come in layout 'rom'"),  # bag convert names the layout after the file
        (["solve", d / "no_lkne.trc", "--model", kiip, "-o", tmp_path / "x.csv"],
         "lacks 1 of the 62 markers of model 'kiip_full_body': LKNE"),
        (["calibrate", d / "rom.trc", "--layout", "kiip_ful_body", "-o", tmp_path / "x.json"],
         "unknown layout 'kiip_ful_body'"),
        (["calibrate", tmp_path / "absent.c3d", "--layout", "kiip_full_body", "-o", tmp_path / "x.json"],
         "absent.c3d: no such file"),
        (["solve", d / "trial.c3d", "--model", tmp_path / "broken.json", "-o", tmp_path / "x.csv"],
         "broken.json: cannot read skeleton model"),
        (["solve", d / "trial.c3d", "--model", kiip, "-o", tmp_path / "x.bvh"],
         "unknown output type '.bvh'"),
        (["solve", d / "trial.c3d", "--model", kiip, "-o", tmp_path / "x.csv", "--frames", "5"],
         "--frames '5': expected a:b"),
        (["calibrate", d / "rom.trc", d / "static.c3d", "--frames", "1:2", "--frames", "1:3", "--frames", ":",
          "--layout", "kiip_full_body", "-o", tmp_path / "x.json"], "--frames given 3 times for 2 files"),
    ]
    for argv, want in cases:
        code, out, err = run(capsys, *argv)
        assert code == 2, (argv, out, err)
        assert want in err and err.count("\n") == 1 and "Traceback" not in err, (want, err)
    # solving without the absent marker when asked: the knee still solves from its other markers
    code, out, _ = run(capsys, "solve", d / "no_lkne.trc", "--model", kiip, "-o", tmp_path / "y.csv",
                       "--allow-missing")
    assert code == 0 and "note: 1 model markers absent from no_lkne.trc (always missing): LKNE" in out
    q = _csv_joints(tmp_path / "y.csv", 16)[..., 3]
    assert (q > 0).all()


def test_the_command_itself_exits_2_without_traceback(files, tmp_path):
    d, _ = files
    r = subprocess.run([sys.executable, "-m", "mocapgraph", "calibrate", str(d / "no_lkne.trc"), "--layout",
                        "kiip_full_body", "-o", str(tmp_path / "x.json")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip() == "mocapgraph: no_lkne.trc: layout 'kiip_full_body' names markers the capture lacks: LKNE"


def test_real_plug_in_gait_static_and_walk(shared_data, capsys, tmp_path):
    folder = shared_data / "c3d" / "pycgm"
    code, out, _ = run(capsys, "calibrate", folder / "Static_trial.c3d", folder / "Movement_trial.c3d",
                       "--layout", "plug_in_gait", "--frames", ":", "--frames", ":200", "-o", tmp_path / "pig.json")
    assert code == 0, out
    with capsys.disabled():
        print("\n" + out)
    code, out, _ = run(capsys, "solve", folder / "Movement_trial.c3d", "--model", tmp_path / "pig.json",
                       "-o", tmp_path / "walk.csv")
    assert code == 0 and "323 frames" in out and "0.0 % missing" in out, out
    model = load_model(tmp_path / "pig.json")
    walk = _csv_joints(tmp_path / "walk.csv", len(model.joint_names))
    # joints calibration called unreliable (centre from the prior) are never flagged good
    rel = model.quality.reliable
    assert (~rel).any() and (walk[:, ~rel, 3] == 1).all() and (walk[:, rel, 3] == 2).all()
    idx = {n: i for i, n in enumerate(model.joint_names)}
    for s in "lr":  # bone lengths held (enforce_lengths) and plausible for an adult
        thigh = np.linalg.norm(walk[:, idx[f"hip_{s}"], :3] - walk[:, idx[f"knee_{s}"], :3], axis=1)
        assert 0.3 < thigh.mean() < 0.55 and thigh.std() < 1e-4


def test_static_plus_walk_with_other_markers_and_plug_in_gait_regressions(shared_data, capsys, tmp_path):
    # OpenSim: the static has medial/lateral knee and ankle markers, the walk has none of them.
    folder = shared_data / "trc" / "opensim-gait2392"
    code, out, _ = run(capsys, "calibrate", folder / "subject01_static.trc", folder / "subject01_walk1.trc",
                       "--layout", "opensim_gait2392", "--centres", "anatomical,functional", "-o", tmp_path / "os.json")
    assert code == 0, out
    assert "subject01_walk1.trc: lacks 8 landmarks of subject01_static.trc: static-only" in out and "R.Knee.Med" in out
    assert "knee_r: midpoint of R.Knee.Lat and R.Knee.Med" in out
    code, out, _ = run(capsys, "solve", folder / "subject01_walk1.trc", "--model", tmp_path / "os.json",
                       "-o", tmp_path / "walk.csv")
    assert code == 0 and "0.0 % missing" in out, out  # no --allow-missing: the absent ones are static-only
    # Plug-in Gait from the static alone with the VSK: regressions, inputs printed.
    pig = shared_data / "c3d" / "pycgm"
    code, out, _ = run(capsys, "calibrate", pig / "Static_trial.c3d", "--layout", "plug_in_gait", "--vsk",
                       pig / "Test.vsk", "--subject", "LeftKneeWidth=150", "--centres", "regression,functional",
                       "-o", tmp_path / "pig.json")
    assert code == 0, out
    with capsys.disabled():
        print("\n" + out)
    assert "knee_l: Plug-in Gait chord (knee) (knee_width 150.0 mm" in out  # --subject overrides the VSK
    assert "regression:pig_hip" in out
    code, out, err = run(capsys, "calibrate", pig / "Static_trial.c3d", "--layout", "plug_in_gait",
                         "--subject", "LeftKneeWidth", "-o", tmp_path / "x.json")
    assert code == 2 and "--subject 'LeftKneeWidth': expected key=value" in err
    code, out, err = run(capsys, "calibrate", pig / "Static_trial.c3d", "--layout", "plug_in_gait",
                         "--centres", "magic", "-o", tmp_path / "x.json")
    assert code == 2 and "--centres 'magic'" in err
