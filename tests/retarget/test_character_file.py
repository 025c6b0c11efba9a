"""Character files: shipped characters load; a wrong file is one `file:line: key: message` line."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.formats.character_file import CharacterFileError, load_character, write_character_yaml
from mocapgraph.retarget.character import standard_20


def test_shipped_characters_load():
    s20 = load_character("standard_20")
    assert s20.n_joints == 20
    np.testing.assert_allclose(s20.rest_offsets, standard_20(1.75).rest_offsets)
    np.testing.assert_allclose(load_character("standard_20", height_m=1.5).rest_offsets, standard_20(1.5).rest_offsets)
    cmu, mix = load_character("cmu"), load_character("mixamo")
    assert cmu.n_joints == 38 and "LeftCollar" in cmu.joint_names
    assert mix.n_joints == 70 and "LeftHandPinky3" in mix.joint_names
    # CMU: arms down at rest; Mixamo: T-pose (hands out to the sides)
    cp, mp = cmu.rest_pose()[0], mix.rest_pose()[0]
    assert cp[cmu.index("LeftWrist"), 2] < cp[cmu.index("LeftShoulder"), 2] - 0.3
    assert abs(mp[mix.index("LeftHand"), 2] - mp[mix.index("LeftArm"), 2]) < 0.05
    assert mp[mix.index("LeftHand"), 1] > 0.5  # Y is left


def test_yaml_round_trip_with_rest_rotations(tmp_path):
    ch = standard_20(1.8)
    path = tmp_path / "c.yaml"
    write_character_yaml(ch, path)
    back = load_character(path)
    assert back.joint_names == ch.joint_names
    np.testing.assert_allclose(back.rest_offsets, ch.rest_offsets, atol=1e-9)
    path.write_text("name: t\nunits: cm\naxes: y_up\njoints:\n"
                    "  - {name: a, offset: [0, 100, 0]}\n"
                    "  - {name: b, parent: a, offset: [0, 0, 10], rest: [0.7071068, 0.7071068, 0, 0]}\n")
    c = load_character(path)
    np.testing.assert_allclose(c.rest_offsets, [[0, 0, 1.0], [0.1, 0, 0]], atol=1e-12)  # Y up -> Z up, +Z -> +X
    # a rotation about the file's X axis is a rotation about the world's Y axis
    np.testing.assert_allclose(c.rest_rotations[1], [0.7071068, 0, 0.7071068, 0], atol=1e-6)


@pytest.mark.parametrize("body,line,needle", [
    ("joints:\n  - {name: a, offset: [0, 0, 1]}\n  - {name: b, parent: c, offset: [0, 0, 1]}\n"
     "  - {name: c, parent: b, offset: [0, 0, 1]}\n", 4, "joints[1] (b).parent: parent 'c' is defined later: a cycle"),
    ("joints:\n  - {name: a, offset: [0, 0, 1]}\n  - {name: b, parent: b, offset: [0, 0, 1]}\n", 4, "own parent"),
    ("joints:\n  - {name: a, offset: [0, 0, 1]}\n  - {name: b, parent: x, offset: [0, 0, 1]}\n", 4,
     "parent 'x' is not a joint of this character"),
    ("joints:\n  - {name: a, offset: [0, 0, 1]}\n  - {name: b, parent: a, offset: [0, 0, 0]}\n", 4,
     "zero-length bone to 'a'"),
    ("joints:\n  - {name: a, offset: [0, 0, 1]}\n  - {name: b, parent: a, offset: [0, 0, 1], rest: [1, 1, 0, 0]}\n", 4,
     "not a unit quaternion"),
    ("joints:\n  - {name: a, offset: [0, 0, 1]}\n  - {name: b, offset: [0, 0, 1]}\n", 2, "exactly one root"),
    ("joints:\n  - {name: a, offset: [0, zero, 1]}\n", 3, "wants 3 finite numbers"),
    ("joints:\n  - {name: a, ofset: [0, 0, 1]}\n", 3, "unknown key"),
    ("joints:\n  - {name: a, offset: [0, 0, 1]\n", 4, "YAML syntax error"),
])
def test_wrong_character_files_are_one_line_errors(tmp_path, body, line, needle):
    path = tmp_path / "bad.yaml"
    path.write_text("name: bad\n" + body)
    with pytest.raises(CharacterFileError) as err:
        load_character(path)
    msg = str(err.value)
    assert "\n" not in msg and needle in msg, msg
    assert msg.startswith(f"{path}:{line}:"), msg


def test_unknown_character_name_lists_the_shipped_ones():
    with pytest.raises(CharacterFileError, match="shipped: cmu, mixamo, standard_20"):
        load_character("mixamoo")


def test_every_shipped_mapping_fits_its_character_and_source(shared_data):
    """graph_configs/mappings: each file loads and checks against the character and source it names."""
    from mocapgraph.formats.kinect_csv import KINECT_V1_JOINTS, KINECT_V1_PARENTS, KINECT_V2_JOINTS, KINECT_V2_PARENTS
    from mocapgraph.formats.mapping_file import MAPPINGS_DIR, load_mapping
    from mocapgraph.retarget.mapping import check_mapping
    from mocapgraph.retarget.source import kinect_source, optical_source
    from mocapgraph.kinematics.skeleton import SkeletonDefinition
    from retarget_support import bvh_source

    files = sorted(MAPPINGS_DIR.glob("*.yaml"))
    assert len(files) >= 6
    for f in files:
        m = load_mapping(f)
        if m.source == "kinect_v2":
            src = kinect_source(KINECT_V2_JOINTS, KINECT_V2_PARENTS)
        elif m.source == "kinect_v1":
            src = kinect_source(KINECT_V1_JOINTS, KINECT_V1_PARENTS)
        elif m.source == "bvh":
            src = bvh_source(shared_data / "bvh/cmu/131_01.bvh")[2]
        else:
            sk = SkeletonDefinition.from_layout_file(m.source.split(":", 1)[1])
            src = optical_source(sk.joint_names, sk.joint_parent, sk.joint_limbs, sk.limb_names,
                                 np.zeros((len(sk.joint_names), 3)))
        check_mapping(m, load_character(m.character), src)
