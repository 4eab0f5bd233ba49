"""glTF skin loading: a synthetic file built here, plus the shared MakeHuman and Khronos meshes."""
import base64
import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest

from gltrack.body.dofs import make_dofs
from gltrack.body.gltf import MAKEHUMAN_CMU_MAP, load_gltf_skin, read_gltf_skin
from gltrack.body.kinematics import Kinematics
from gltrack.body.markers import closest_points_on_mesh, default_markers
from gltrack.body.mesh import PARTS
from gltrack.body.skeleton import JOINT_NAMES, default_skeleton


def _shared_file(name: str) -> Path:
    env = os.environ.get("GLTRACK_SHARED")
    root = Path(env) if env else Path(__file__).resolve().parents[1].parent / "shared"
    path = root / "meshes" / name
    if not path.is_file():
        pytest.skip(f"shared reference mesh {path} not available (set GLTRACK_SHARED)")
    return path


# ----------------------------------------------------------------------------- synthetic file
# Two joints A -> B in a Z-up skin under a root matrix that turns Z-up into Y-up.
_POS = np.array([[0, 0, 1], [1, 0, 1], [0.5, 0.2, 1], [1.5, 0, 1]], np.float32)
_FACES = np.array([[0, 1, 2], [1, 3, 2]], np.uint16)
_JOINTS = np.array([[0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [1, 0, 0, 0]], np.uint16)
_WEIGHTS = np.array([[1, 0, 0, 0], [0.5, 0.5, 0, 0], [1, 0, 0, 0], [0.8, 0, 0, 0]], np.float32)
_ROOT = [1, 0, 0, 0, 0, 0, -1, 0, 0, 1, 0, 0, 0, 0, 0, 1]  # column-major rotation -90 deg about X


def _ibm(t):
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = -np.asarray(t)
    return m.T.reshape(-1)  # column-major


def _synthetic(skin: bool = True):
    blobs = [_POS.tobytes(), _JOINTS.tobytes(), _WEIGHTS.tobytes(), _FACES.tobytes(),
             np.concatenate([_ibm([0, 0, 1]), _ibm([1, 0, 1])]).tobytes()]
    views, offset = [], 0
    for b in blobs:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(b)})
        offset += len(b) + (-len(b) % 4)
    data = b"".join(b + b"\0" * (-len(b) % 4) for b in blobs)
    acc = [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
           {"bufferView": 1, "componentType": 5123, "count": 4, "type": "VEC4"},
           {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC4"},
           {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"},
           {"bufferView": 4, "componentType": 5126, "count": 2, "type": "MAT4"}]
    mesh_node = {"mesh": 0, "skin": 0} if skin else {"mesh": 0}
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 3]}],
           "nodes": [{"matrix": _ROOT, "children": [1]},
                     {"name": "A", "translation": [0, 0, 1], "children": [2]},
                     {"name": "B", "translation": [1, 0, 0]}, mesh_node],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "JOINTS_0": 1,
                                                      "WEIGHTS_0": 2}, "indices": 3}]}],
           "skins": [{"joints": [1, 2], "inverseBindMatrices": 4}],
           "accessors": acc, "bufferViews": views, "buffers": [{"byteLength": len(data)}]}
    return doc, data


def _write_glb(path, doc, data):
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    body = struct.pack("<I4s", len(js), b"JSON") + js + struct.pack("<I4s", len(data), b"BIN\0")
    body += data
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
    return path


def _write_gltf(path, doc, data):
    doc = json.loads(json.dumps(doc))
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + \
        base64.b64encode(data).decode()
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("fmt", ["glb", "gltf"])
def test_synthetic_skin_is_read_in_scene_coordinates(tmp_path, fmt):
    doc, data = _synthetic()
    write = _write_glb if fmt == "glb" else _write_gltf
    path = write(tmp_path / f"two.{fmt}", doc, data)
    raw = read_gltf_skin(path)
    # Z-up skin space -> Y-up scene: (x, y, z) -> (x, z, -y)
    expect = _POS[:, [0, 2, 1]] * [1, 1, -1]
    assert np.allclose(raw["vertices"], expect, atol=1e-6)
    assert np.array_equal(raw["faces"], _FACES.astype(np.int32))
    assert raw["joint_names"] == ("A", "B") and list(raw["joint_parents"]) == [-1, 0]
    assert np.allclose(raw["bind_positions"], [[0, 1, 0], [1, 1, 0]], atol=1e-6)
    mesh, info = load_gltf_skin(path, joint_map=False)
    assert np.allclose(mesh.weights.sum(1), 1.0)
    assert info["renormalised"] == 1  # the 0.8 row
    assert mesh.joints[3, 0] == 1 and mesh.weights[3, 0] == pytest.approx(1.0)
    assert mesh.weights[1, :2] == pytest.approx([0.5, 0.5])


def test_synthetic_errors(tmp_path):
    doc, data = _synthetic(skin=False)
    with pytest.raises(ValueError, match="skin"):
        read_gltf_skin(_write_glb(tmp_path / "noskin.glb", doc, data))
    doc, data = _synthetic()
    path = _write_glb(tmp_path / "two.glb", doc, data)
    with pytest.raises(ValueError, match=r"not in the joint map: B"):
        load_gltf_skin(path, joint_map={"A": "pelvis"})
    with pytest.raises(FileNotFoundError):
        load_gltf_skin(tmp_path / "missing.glb")
    (tmp_path / "short.glb").write_bytes(b"glTF\x02\0\0\0")
    with pytest.raises(ValueError, match="short.glb"):
        read_gltf_skin(tmp_path / "short.glb")
    doc["accessors"][0]["count"] = 400  # reads past its buffer view
    with pytest.raises(ValueError, match=r"accessors\[0\]"):
        read_gltf_skin(_write_glb(tmp_path / "bad.glb", doc, data))
    doc, data = _synthetic()
    doc["buffers"][0]["uri"] = "../../etc/passwd"
    (tmp_path / "escape.gltf").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="outside"):
        read_gltf_skin(tmp_path / "escape.gltf")


# ----------------------------------------------------------------------------- MakeHuman


@pytest.fixture(scope="module")
def makehuman():
    return load_gltf_skin(_shared_file("makehuman_cmu_male1591.glb"))


def test_makehuman_loads(makehuman):
    mesh, info = makehuman
    assert mesh.n_vertices == 1591 and mesh.n_faces == 3140
    assert mesh.vertices.dtype == np.float32
    assert np.allclose(mesh.weights.sum(1), 1.0, atol=1e-5)
    assert np.all((mesh.weights > 0).sum(1) <= 4)
    assert set(info["joint_names"]) <= set(MAKEHUMAN_CMU_MAP)
    sk = info["skeleton"]
    assert sk.names == JOINT_NAMES
    assert 1.55 < sk.height() < 1.8
    assert set(np.unique(mesh.part)) == set(range(len(PARTS)))


def test_makehuman_rest_is_a_t_pose(makehuman):
    mesh, info = makehuman
    sk = info["skeleton"]
    rest = sk.rest_positions()
    bind = info["bind_vertices"]
    for side, sign in (("l", 1), ("r", -1)):
        hand = mesh.part == PARTS.index(f"{side}_hand")
        sh = rest[sk.index(f"{side}_shoulder")]
        assert np.all(sign * mesh.vertices[hand, 0] > 0.55)  # far out along +-X
        assert abs(mesh.vertices[hand, 1].mean() - sh[1]) < 0.08  # at shoulder height
        assert bind[hand, 1].mean() < sh[1] - 0.3  # the file's A-pose hangs lower
        # the arm chain is straight along +-X in the skeleton
        for j in ("elbow", "wrist"):
            off = sk.offsets[sk.index(f"{side}_{j}")]
            assert sign * off[0] > 0 and np.allclose(off[1:], 0)
    # the legs and head are not re-posed
    legs = np.isin(mesh.part, [PARTS.index(p) for p in ("l_shin", "r_shin", "head")])
    assert np.abs(mesh.vertices[legs] - bind[legs]).max() < 1e-5


def test_makehuman_poses_with_fk(makehuman):
    mesh, info = makehuman
    sk = info["skeleton"]
    kin = Kinematics(sk, make_dofs(sk, "full"))
    d = kin.dofs
    p = np.tile(d.zero(sk), (2, 1))
    p[1, d.index("l_elbow_ry")] = -1.5
    rest, bent = mesh.skin(kin.skinning_matrices(p))
    assert np.allclose(rest, mesh.vertices, atol=1e-5)
    move = np.linalg.norm(bent - rest, axis=1)
    assert move[mesh.part == PARTS.index("l_hand")].min() > 0.15
    feet = np.isin(mesh.part, [PARTS.index("l_foot"), PARTS.index("r_foot")])
    assert move[feet].max() < 1e-6
    assert move[mesh.part == PARTS.index("r_hand")].max() < 1e-6


def test_makehuman_onto_a_given_skeleton(makehuman):
    target = default_skeleton(1.66)
    mesh, info = load_gltf_skin(_shared_file("makehuman_cmu_male1591.glb"), skeleton=target)
    assert info["skeleton"] is target
    rest = target.rest_positions()
    for side in "lr":
        hand = mesh.vertices[mesh.part == PARTS.index(f"{side}_hand")]
        w = target.index(f"{side}_wrist")
        mid = rest[w] + 0.5 * target.ends[w]
        assert np.linalg.norm(hand.mean(0) - mid) < 0.08
        foot = mesh.vertices[mesh.part == PARTS.index(f"{side}_foot")]
        assert np.linalg.norm(foot.mean(0) - rest[target.index(f"{side}_ankle")]) < 0.12
    # differs from the file-derived skeleton's rest mesh
    assert np.abs(mesh.vertices - makehuman[0].vertices).max() > 0.02


def test_markers_on_the_makehuman_mesh(makehuman):
    mesh, info = makehuman
    mk = default_markers(info["skeleton"], mesh)
    _, dist = closest_points_on_mesh(mk.rest_positions(info["skeleton"]), mesh.vertices,
                                     mesh.faces)
    assert dist.max() < 0.01


# ----------------------------------------------------------------------------- Khronos


def test_khronos_raw_skin_renormalised():
    path = _shared_file("khronos_riggedfigure.glb")
    raw = read_gltf_skin(path)
    sums = raw["weights"].sum(1)
    assert sums.min() < 0.5  # the file really has short rows
    mesh, info = load_gltf_skin(path, joint_map=False)
    assert mesh.n_vertices == 370 and mesh.n_faces == 256
    assert len(info["joint_names"]) == 19
    assert np.allclose(mesh.weights.sum(1), 1.0, atol=1e-5)
    assert info["renormalised"] == int(np.sum(np.abs(sums - 1) > 1e-3)) > 0
    # the dominant joint is unchanged by renormalisation
    assert np.array_equal(mesh.joints[:, 0],
                          np.take_along_axis(raw["joints"], raw["weights"].argmax(1)[:, None],
                                             1)[:, 0])
    # Z-up file under a root matrix comes out Y-up, standing on y = 0
    ext = mesh.vertices.max(0) - mesh.vertices.min(0)
    assert ext[1] > 1.3 and ext[1] > ext[2] * 3
    assert abs(mesh.vertices[:, 1].min()) < 0.01
    with pytest.raises(ValueError, match="joint0"):
        load_gltf_skin(path)
