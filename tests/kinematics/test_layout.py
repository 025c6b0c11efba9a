"""Marker layouts -> SkeletonDefinition: shipped layouts, real capture labels, malformed files."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from mocapgraph.kinematics.layout import LAYOUT_DIR, LayoutError, available_layouts
from mocapgraph.kinematics.skeleton import SkeletonDefinition

SHIPPED = ["kiip_full_body", "plug_in_gait", "qualisys", "opensim_gait2392", "lower_body", "one_arm"]

SMALL = {
    "name": "tiny",
    "limbs": [
        {"name": "pelvis", "markers": ["A", "B", "C"]},
        {"name": "thigh_l", "parent": "pelvis", "joint": {"name": "hip_l", "type": "ball"},
         "markers": ["D", "E", "K"]},
        {"name": "shank_l", "parent": "thigh_l", "joint": {"name": "knee_l", "type": "hinge"},
         "markers": ["F", "G"], "shared": ["K"]},
    ],
}


def test_shipped_layouts_are_listed_and_load():
    assert set(SHIPPED) <= set(available_layouts())
    for name in SHIPPED:
        sk = SkeletonDefinition.from_layout_file(name)
        assert sk.name == name
        assert (sk.limb_parent[0] == -1) and (sk.limb_parent[1:] >= 0).all()
        assert (sk.limb_parent[1:] < np.arange(1, sk.n_limbs)).all(), "parents precede children"
        assert len(set(m.lower() for m in sk.marker_labels)) == sk.n_markers
        lmi = sk.limb_marker_index()
        fit_points = (lmi >= 0).sum(axis=1) + np.array([len(p) for p in sk.limb_joint_points])
        assert (fit_points >= 3).all()


def test_kiip_layout_matches_table_1():
    sk = SkeletonDefinition.from_layout_file(LAYOUT_DIR / "kiip_full_body.yaml")
    counts = dict(zip(sk.limb_names, np.bincount(sk.marker_limb, minlength=sk.n_limbs)))
    three = {"clavicle_l", "clavicle_r", "hand_l", "hand_r", "foot_l", "foot_r"}
    assert sk.n_limbs == 17 and sk.n_joints == 16 and sk.n_markers == 62
    for limb, n in counts.items():
        assert n == (3 if limb in three else 4), limb
    assert sk.joint_hinge.sum() == 4
    assert {sk.joint_names[j] for j in np.flatnonzero(sk.joint_hinge)} == {"elbow_l", "elbow_r", "knee_l", "knee_r"}
    # joint_parent: joint at the proximal end of the proximal limb
    knee = sk.joint_index("knee_l")
    assert sk.joint_names[sk.joint_parent[knee]] == "hip_l"
    assert sk.joint_parent[sk.joint_index("hip_l")] == -1
    assert sk.joint_names[sk.joint_parent[sk.joint_index("shoulder_r")]] == "sternoclavicular_r"
    for j in range(sk.n_joints):
        p, c = sk.joint_limbs[j]
        assert sk.limb_parent[c] == p


def test_shared_markers_enter_fit_set_not_ownership():
    sk = SkeletonDefinition.from_layout_file("plug_in_gait")
    lknee = sk.marker_labels.index("LKNE")
    thigh, shank = sk.limb_index("thigh_l"), sk.limb_index("shank_l")
    assert sk.marker_limb[lknee] == thigh
    lmi = sk.limb_marker_index()
    assert lknee in lmi[shank] and lknee in lmi[thigh]
    assert list(lmi[shank][lmi[shank] >= 0]) == [sk.marker_labels.index(m) for m in ("LTIB", "LANK", "LKNE")]
    assert sk.limb_joint_points[thigh] == (sk.joint_index("hip_l"),)


def test_match_labels_case_insensitive_prefix_and_unplaced():
    sk = SkeletonDefinition.from_layout_dict(SMALL)
    idx, unplaced = sk.match_labels(["x", "a", "Subj:B", " c ", "A", "zz", "k"])
    assert list(idx) == [1, 2, 3, -1, -1, 6, -1, -1]
    assert unplaced == ["x", "A", "zz"]


def test_real_captures_carry_every_layout_marker(shared_data: Path):
    ezc3d = pytest.importorskip("ezc3d")
    for rel, layout in [("c3d/pycgm/Static_trial.c3d", "plug_in_gait"),
                        ("c3d/pycgm/Movement_trial.c3d", "plug_in_gait"),
                        ("c3d/ezc3d-testFiles/Qualisys.c3d", "qualisys")]:
        labels = ezc3d.c3d(str(shared_data / rel))["parameters"]["POINT"]["LABELS"]["value"]
        sk = SkeletonDefinition.from_layout_file(layout)
        idx, _ = sk.match_labels(labels)
        assert (idx >= 0).all(), (rel, [sk.marker_labels[k] for k in np.flatnonzero(idx < 0)])
    sk = SkeletonDefinition.from_layout_file("opensim_gait2392")
    for trc, missing in (("subject01_static.trc", 0), ("subject01_walk1.trc", 8)):
        header = (shared_data / "trc/opensim-gait2392" / trc).read_text().splitlines()[3]
        labels = [s.strip() for s in header.split("\t")[2:] if s.strip()]
        idx, unplaced = sk.match_labels(labels)
        assert unplaced == [] and (idx < 0).sum() == missing


# ---------------------------------------------------------------------- malformed layouts
def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "bad_layout.yaml"
    p.write_text(text)
    return p


GOOD_TEXT = """\
name: bad
limbs:
  - name: pelvis
    markers: [A, B, C]
  - name: thigh_l
    parent: pelvis
    joint: {name: hip_l, type: ball}
    markers: [D, E, F]
"""


@pytest.mark.parametrize(
    "text, key, words, line",
    [
        (GOOD_TEXT.replace("markers: [D, E, F]", "markers: [D, E, F"), None, "YAML syntax", None),
        (GOOD_TEXT.replace("[D, E, F]", "[D, E]"), "limbs.1.markers", "rigid fit needs >= 3", 8),
        (GOOD_TEXT.replace("parent: pelvis", "parent: pelvix"), "limbs.1.parent", "unknown parent limb `pelvix`", 6),
        (GOOD_TEXT.replace("type: ball", "type: saddle"), "limbs.1.joint.type", "type must be", 7),
        (GOOD_TEXT.replace("[D, E, F]", "[D, E, A]"), "limbs.1.markers", "listed twice", 8),
        (GOOD_TEXT + "    shared: [Q]\n", "limbs.1.shared", "not owned", 9),
        (GOOD_TEXT.replace("name: bad\n", ""), "name", "missing", None),
    ],
)
def test_malformed_layout_gives_one_line_error(tmp_path, text, key, words, line):
    p = _write(tmp_path, text)
    with pytest.raises(LayoutError) as ei:
        SkeletonDefinition.from_layout_file(p)
    msg = str(ei.value)
    assert "\n" not in msg
    assert str(p) in msg and words in msg
    if key:
        assert f"`{key}`" in msg
    if line:
        assert f"{p}:{line}:" in msg


def test_cycle_is_rejected(tmp_path):
    text = GOOD_TEXT + """\
  - name: shank_l
    parent: foot_l
    joint: {name: knee_l, type: hinge}
    markers: [G, H, I]
  - name: foot_l
    parent: shank_l
    joint: {name: ankle_l, type: ball}
    markers: [J, K, L]
"""
    p = _write(tmp_path, text)
    with pytest.raises(LayoutError, match=r"bad_layout\.yaml:\d+: key `limbs\.2\.parent`: .*cycle"):
        SkeletonDefinition.from_layout_file(p)


def test_dict_errors_name_source_and_key():
    bad = copy.deepcopy(SMALL)
    bad["limbs"][2]["shared"] = []
    with pytest.raises(LayoutError, match=r"^mine: key `limbs\.2\.markers`: limb `shank_l` has 2 marker"):
        SkeletonDefinition.from_layout_dict(bad, source="mine")
    bad = copy.deepcopy(SMALL)
    bad["limbs"][1]["parent"] = "thigh_l"
    with pytest.raises(LayoutError, match="own parent"):
        SkeletonDefinition.from_layout_dict(bad)
    bad = copy.deepcopy(SMALL)
    bad["limbs"][0]["markers"] = ["A", "B", "C"]
    bad["limbs"][1]["shared"] = ["F"]   # F is on shank_l: adjacent, allowed
    assert SkeletonDefinition.from_layout_dict(bad).limb_marker_index().shape == (3, 4)
    bad["limbs"][0]["shared"] = ["F"]   # pelvis and shank are not joined
    with pytest.raises(LayoutError, match="not joined"):
        SkeletonDefinition.from_layout_dict(bad)


def test_missing_file_is_a_layout_error(tmp_path):
    with pytest.raises(LayoutError, match="cannot read"):
        SkeletonDefinition.from_layout_file(tmp_path / "nope.yaml")
