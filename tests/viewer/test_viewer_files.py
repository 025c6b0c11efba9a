"""What the viewer serves besides the page, without a browser: byte ranges of a source video, the
avatar GLB of a CharacterInfo (and one line for a skeleton it cannot be built on), the three.js allow-list."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.messages import CharacterInfo
from mocapgraph.viewer.avatar import THREE_FILES, AvatarError, avatar_glb, three_files
from mocapgraph.viewer.media import CHUNK, ranged


def test_byte_ranges_of_a_file(tmp_path):
    data = np.random.default_rng(0).integers(0, 256, CHUNK + 5000, dtype=np.uint8).tobytes()
    f = tmp_path / "clip.mp4"
    f.write_bytes(data)
    n = len(data)
    status, head, body = ranged(f, "bytes=10-19")
    assert (status, head["Content-Range"], body) == (206, f"bytes 10-19/{n}", data[10:20])
    assert head["Content-Type"] == "video/mp4" and head["Accept-Ranges"] == "bytes"
    status, head, body = ranged(f, "bytes=-100")                 # the last 100 bytes
    assert (status, body) == (206, data[-100:]) and head["Content-Range"] == f"bytes {n - 100}-{n - 1}/{n}"
    status, head, body = ranged(f, "bytes=0-")                   # open-ended: at most CHUNK a response
    assert status == 206 and body == data[:CHUNK] and head["Content-Range"] == f"bytes 0-{CHUNK - 1}/{n}"
    assert ranged(f, f"bytes={n}-")[0] == 416 and ranged(f, "bytes=50-10")[0] == 416
    assert ranged(f, "bytes=oops")[2] == data[:CHUNK]            # a header it cannot read: from the start
    small = tmp_path / "small.webm"
    small.write_bytes(b"x" * 100)
    assert ranged(small, None)[:2] == (200, {"Content-Type": "video/webm", "Accept-Ranges": "bytes"})


def _info(parents, offsets) -> CharacterInfo:
    J = len(parents)
    return CharacterInfo(character="probe", joint_names=[f"j{i}" for i in range(J)],
                         joint_parent=np.asarray(parents, np.int32), rest_offsets=np.asarray(offsets, float),
                         rest_rotations=np.tile([1.0, 0, 0, 0], (J, 1)))


def test_avatar_glb_of_a_character_and_one_line_for_a_bad_one():
    pygltflib = pytest.importorskip("pygltflib")
    glb = avatar_glb(_info([-1, 0, 1, 0], [[0, 0, 1.0], [0, 0, 0.4], [0, 0, 0.3], [0, 0.2, -0.5]]))
    doc = pygltflib.GLTF2.load_from_bytes(glb)
    assert [doc.nodes[j].name for j in doc.skins[0].joints] == ["j0", "j1", "j2", "j3"]
    assert len(doc.meshes) == 1 and not doc.animations
    for parents in ([-1, 2, 1], [-1, 0, 5]):                    # a cycle; a parent that is not a joint
        with pytest.raises(AvatarError) as err:
            avatar_glb(_info(parents, np.ones((3, 3))))
        assert "probe" in str(err.value) and "\n" not in str(err.value)
    n = 2000                                                     # a rig too large for an avatar: one line
    with pytest.raises(AvatarError, match="2000 joints"):
        avatar_glb(_info(np.arange(n) - 1, np.tile([0, 0, 0.1], (n, 1))))


def test_three_js_allow_list(tmp_path):
    assert three_files(tmp_path) == {}                         # not installed: nothing served
    for name in THREE_FILES:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("export {};")
    (tmp_path / "package.json").write_text("{}")
    files = three_files(tmp_path)
    assert sorted(files) == sorted(f"/three/{n}" for n in THREE_FILES)
    assert all(p.is_file() and tmp_path in p.parents for p in files.values())
