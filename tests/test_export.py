"""gltrack export: glTF binary (checked by an independent GLB reader), OpenSim TRC, JSON, CLI."""
import json
import struct

import numpy as np
import pytest

from gltrack.body.gltf import read_gltf_skin
from gltrack.body.model import BodyModel
from gltrack.cli import main
from gltrack.data.results import ResultsWriter, load_results
from gltrack.export import body_for_result, build_glb, format_trc, read_trc, write_glb
from trackdata import make_depth_dataset

N = 6


def _write_results(out, body, P, markers=True, frames=None):
    frames = range(len(P)) if frames is None else frames
    J = body.joints(P)
    M = body.marker_positions(P) if markers else [None] * len(P)
    with ResultsWriter(out, "test", body.skeleton.names,
                       body.markers.names if markers else None) as w:
        for k, f in enumerate(frames):
            w.append(f, P[k], J[k], M[k], score=0.5 + k)
        w.finish()
    return load_results(out)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    body, P = make_depth_dataset(root / "ds", N)
    rng = np.random.default_rng(7)
    Q = body.dofs.validate(P + rng.normal(size=P.shape) * 0.05)
    result = _write_results(root / "res", body, Q)
    return {"root": root, "ds": root / "ds", "res": root / "res", "body": body, "Q": Q,
            "result": result}


# --------------------------------------------------------------------------------------------
# an independent GLB reader (plain struct + numpy), so the checks do not trust gltrack's parser

_DT = {5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_NC = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def _read_glb(path):
    raw = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", raw, 0)
    assert magic == b"glTF" and version == 2 and length == len(raw)
    jlen, jtype = struct.unpack_from("<I4s", raw, 12)
    assert jtype == b"JSON" and jlen % 4 == 0
    doc = json.loads(raw[20:20 + jlen])
    blen, btype = struct.unpack_from("<I4s", raw, 20 + jlen)
    assert btype == b"BIN\0" and blen % 4 == 0
    binary = raw[28 + jlen:28 + jlen + blen]
    assert doc["buffers"][0]["byteLength"] <= len(binary)

    def acc(i):
        a = doc["accessors"][i]
        v = doc["bufferViews"][a["bufferView"]]
        assert v["byteOffset"] % 4 == 0
        n = _NC[a["type"]]
        arr = np.frombuffer(binary, _DT[a["componentType"]], a["count"] * n,
                            v["byteOffset"] + a.get("byteOffset", 0))
        return arr.reshape(a["count"], n) if n > 1 else arr

    return doc, acc


def _quat_matrix(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _animated_worlds(doc, acc, key):
    """(nodes, 4, 4) world matrices with every animated channel set to its keyframe ``key``."""
    nodes = doc["nodes"]
    trs = [{"t": np.array(n.get("translation", [0, 0, 0]), float),
            "r": np.array(n.get("rotation", [0, 0, 0, 1]), float)} for n in nodes]
    anim = doc["animations"][0]
    for ch in anim["channels"]:
        out = acc(anim["samplers"][ch["sampler"]]["output"]).astype(float)
        slot = "r" if ch["target"]["path"] == "rotation" else "t"
        trs[ch["target"]["node"]][slot] = out[key]
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}
    world = {}

    def solve(i):
        if i not in world:
            L = np.eye(4)
            L[:3, :3] = _quat_matrix(trs[i]["r"])
            L[:3, 3] = trs[i]["t"]
            world[i] = solve(parent[i]) @ L if i in parent else L
        return world[i]

    return np.stack([solve(i) for i in range(len(nodes))])


def test_glb_reads_back_with_gltrack_loader(data, tmp_path):
    body = data["body"]
    path = write_glb(tmp_path / "m.glb", body, data["Q"], 30.0)
    skin = read_gltf_skin(path)
    mesh, sk = body.mesh, body.skeleton
    np.testing.assert_allclose(skin["vertices"], mesh.vertices, atol=1e-6)
    np.testing.assert_array_equal(skin["faces"], mesh.faces)
    np.testing.assert_array_equal(skin["joints"], np.where(mesh.weights > 0, mesh.joints, 0))
    np.testing.assert_allclose(skin["weights"], mesh.weights, atol=1e-7)
    assert skin["joint_names"] == tuple(sk.names)
    np.testing.assert_array_equal(skin["joint_parents"], sk.parents)
    np.testing.assert_allclose(skin["bind_positions"], sk.rest_positions(), atol=1e-6)


@pytest.mark.parametrize("key", [0, N - 1])
def test_glb_animation_reproduces_fk(data, tmp_path, key):
    body, Q, result = data["body"], data["Q"], data["result"]
    path = write_glb(tmp_path / "m.glb", body, Q, 25.0)
    doc, acc = _read_glb(path)
    B = body.skeleton.n_joints
    world = _animated_worlds(doc, acc, key)[:B]
    # joint positions of the animated hierarchy == the tracked (FK) joints of the results
    np.testing.assert_allclose(world[:, :3, 3], result["joints"][key], atol=2e-5)
    # glTF skinning (world_j @ inverseBind_j, JOINTS_0/WEIGHTS_0) == gltrack's posed mesh
    prim = doc["meshes"][0]["primitives"][0]
    skin = doc["skins"][0]
    ibm = acc(skin["inverseBindMatrices"]).reshape(B, 4, 4).transpose(0, 2, 1)
    jm = world[skin["joints"]] @ ibm
    pos = acc(prim["attributes"]["POSITION"]).astype(float)
    jt = acc(prim["attributes"]["JOINTS_0"]).astype(int)
    wt = acc(prim["attributes"]["WEIGHTS_0"]).astype(float)
    vh = np.concatenate([pos, np.ones((len(pos), 1))], 1)
    posed = np.einsum("vk,vkij,vj->vi", wt, jm[jt], vh)[:, :3]
    expect = body.mesh.skin(body.skinning(Q[key:key + 1]))[0]
    np.testing.assert_allclose(posed, expect, atol=5e-5)
    times = acc(doc["animations"][0]["samplers"][0]["input"])
    np.testing.assert_allclose(times, np.arange(N) / 25.0, atol=1e-7)


def test_glb_structure_and_normals(data, tmp_path):
    body = data["body"]
    doc, acc = _read_glb(write_glb(tmp_path / "m.glb", body, data["Q"], 30.0))
    prim = doc["meshes"][0]["primitives"][0]
    assert set(prim["attributes"]) == {"POSITION", "NORMAL", "JOINTS_0", "WEIGHTS_0"}
    nrm = acc(prim["attributes"]["NORMAL"]).astype(float)
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-5)
    # outward normals: away from the centre of the vertex's body part, and +Z on the chest
    pos = acc(prim["attributes"]["POSITION"])
    part = body.mesh.part
    centre = np.stack([pos[part == p].mean(0) for p in range(part.max() + 1)])[part]
    assert np.mean(np.einsum("vi,vi->v", nrm, pos - centre) > 0) > 0.9
    chest = (np.abs(pos[:, 0]) < 0.05) & (pos[:, 1] > 1.25) & (pos[:, 1] < 1.35) & (pos[:, 2] > 0)
    assert chest.any() and np.all(nrm[chest, 2] > 0.2)
    pa = doc["accessors"][prim["attributes"]["POSITION"]]
    np.testing.assert_allclose(pa["min"], pos.min(0))
    np.testing.assert_allclose(pa["max"], pos.max(0))
    # sign-continuous quaternions: LINEAR interpolation takes the short way
    for s in doc["animations"][0]["samplers"][1:]:
        q = acc(s["output"]).astype(float)
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)
        assert np.all(np.einsum("ti,ti->t", q[1:], q[:-1]) >= 0)
    assert len(doc["animations"][0]["channels"]) == body.skeleton.n_joints + 1


def test_glb_opens_in_trimesh(data, tmp_path):
    import trimesh

    path = write_glb(tmp_path / "m.glb", data["body"], data["Q"], 30.0)
    scene = trimesh.load(path, process=False)
    geoms = list(scene.geometry.values())
    assert len(geoms) == 1
    assert len(geoms[0].faces) == data["body"].mesh.n_faces


def test_glb_times_follow_frame_numbers_and_reject_bad_input(data):
    body, Q = data["body"], data["Q"]
    raw = build_glb(body, Q[:3], 30.0, frames=[10, 12, 15])
    jlen = struct.unpack_from("<I", raw, 12)[0]
    doc = json.loads(raw[20:20 + jlen])
    t_acc = doc["accessors"][doc["animations"][0]["samplers"][0]["input"]]
    assert t_acc["min"] == pytest.approx([10 / 30]) and t_acc["max"] == pytest.approx([0.5])
    with pytest.raises(ValueError, match="strictly increasing"):
        build_glb(body, Q[:3], 30.0, frames=[3, 2, 4])
    with pytest.raises(ValueError, match="params must be"):
        build_glb(body, Q[:, :10], 30.0)


def _parse_trc_plain(path):
    """Independent minimal TRC parse: header dict, names, (T, 2 + 3M) numbers."""
    lines = path.read_text().split("\n")
    header = dict(zip(lines[1].split("\t"), lines[2].split("\t")))
    names = [s for s in lines[3].split("\t")[2:] if s]
    rows = [[float(c) if c else np.nan for c in ln.split("\t")] for ln in lines[5:] if ln.strip()]
    return lines, header, names, np.array(rows)


def test_trc_via_cli_matches_markers(data, tmp_path):
    out = tmp_path / "m.trc"
    assert main(["export", str(data["res"]), "--format", "trc", "--dataset", str(data["ds"]),
                 "--out", str(out)]) == 0
    lines, header, names, rows = _parse_trc_plain(out)
    result = data["result"]
    assert lines[0].split("\t")[:3] == ["PathFileType", "4", "(X/Y/Z)"]
    assert header["Units"] == "mm" and float(header["DataRate"]) == 30.0
    assert int(header["NumFrames"]) == N and int(header["NumMarkers"]) == len(names)
    assert names == result["marker_names"]
    assert lines[4].split("\t")[2:5] == ["X1", "Y1", "Z1"]
    np.testing.assert_array_equal(rows[:, 0], np.arange(1, N + 1))
    np.testing.assert_allclose(rows[:, 1], np.arange(N) / 30.0, atol=1e-5)
    np.testing.assert_allclose(rows[:, 2:].reshape(N, -1, 3) / 1000.0, result["markers"],
                               atol=1e-6)
    back = read_trc(out)
    np.testing.assert_allclose(back["points"] / 1000.0, result["markers"], atol=1e-6)


def test_trc_joints_gaps_and_missing_values(data, tmp_path):
    names = ["a", "b"]
    pts = np.array([[[0.1, 0.2, 0.3], [np.nan, np.nan, np.nan]],
                    [[1.0, 2.0, 3.0], [4.0, -5.0, 6.0]]])
    text = format_trc(names, pts, 50.0, frames=[4, 9])
    path = tmp_path / "x.trc"
    path.write_text(text)
    back = read_trc(path)
    assert back["names"] == names
    np.testing.assert_array_equal(back["frame"], [5, 10])
    np.testing.assert_allclose(back["time"], [0.08, 0.18])
    np.testing.assert_allclose(back["points"], pts * 1000.0)  # NaN stays NaN
    assert back["header"]["OrigDataStartFrame"] == "5"
    with pytest.raises(ValueError, match="tab"):
        format_trc(["a\tb"], pts[:, :1], 30.0)
    out = tmp_path / "j.trc"
    assert main(["export", str(data["res"]), "--out", str(out), "--points", "joints"]) == 0
    j = read_trc(out)
    assert j["names"] == data["result"]["joint_names"]
    np.testing.assert_allclose(j["points"] / 1000.0, data["result"]["joints"], atol=1e-6)


def test_json_schema_and_values(data, tmp_path):
    out = tmp_path / "m.json"
    assert main(["export", str(data["res"]), "--dataset", str(data["ds"]), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    result, body = data["result"], data["body"]
    assert doc["format"] == "gltrack-motion" and doc["version"] == 1
    assert doc["fps"] == 30.0 and doc["method"] == "test" and doc["dof_preset"] == "full"
    assert doc["dof_names"] == list(body.dofs.names)
    assert doc["joint_names"] == result["joint_names"]
    assert doc["joint_parents"] == body.skeleton.parents.tolist()
    assert doc["marker_names"] == result["marker_names"]
    assert [f["frame"] for f in doc["frames"]] == list(range(N))
    np.testing.assert_allclose([f["time"] for f in doc["frames"]], np.arange(N) / 30.0)
    np.testing.assert_allclose([f["params"] for f in doc["frames"]], result["params"])
    np.testing.assert_allclose([f["joints"] for f in doc["frames"]], result["joints"])
    np.testing.assert_allclose([f["markers"] for f in doc["frames"]], result["markers"])
    np.testing.assert_allclose([f["score"] for f in doc["frames"]], result["score"])


def test_json_nonfinite_becomes_null(data, tmp_path):
    from gltrack.export import write_json

    result = dict(data["result"])
    result["markers"] = result["markers"].copy()
    result["markers"][2, 3] = np.nan
    out = write_json(tmp_path / "n.json", result, 30.0)
    doc = json.loads(out.read_text())  # strict JSON: no NaN tokens
    assert "NaN" not in out.read_text()
    assert doc["frames"][2]["markers"][3] == [None, None, None]
    assert doc["dof_names"] is None and doc["joint_parents"] is None


def test_cli_bvh_default_out_and_format_inference(data, tmp_path):
    from gltrack.motion.bvh import read_bvh

    assert main(["export", str(data["res"]), "--format", "bvh"]) == 0
    bvh = read_bvh(data["res"] / "poses.bvh")
    assert bvh.motion.shape[0] == N
    out = tmp_path / "a.glb"
    assert main(["export", str(data["res"]), "--out", str(out), "--fps", "60"]) == 0
    doc, acc = _read_glb(out)
    np.testing.assert_allclose(acc(doc["animations"][0]["samplers"][0]["input"]),
                               np.arange(N) / 60.0, atol=1e-7)
    assert main(["export", str(data["res"]), "--out", str(tmp_path / "a.xyz")]) == 2
    assert main(["export", str(data["res"])]) == 2
    assert main(["export", str(tmp_path / "nothing"), "--format", "json"]) == 1


def test_dof_preset_must_match(data, tmp_path, capsys):
    body38 = BodyModel.build(preset="38")
    P = np.repeat(body38.dofs.zero(body38.skeleton)[None], 3, axis=0)
    P[:, body38.dofs.index("l_knee_rx")] = [0.1, 0.5, 0.9]
    res = tmp_path / "res38"
    result = _write_results(res, body38, P)
    with pytest.raises(ValueError, match="'38'"):
        body_for_result(result)
    out = tmp_path / "k.glb"
    assert main(["export", str(res), "--out", str(out), "--dataset", str(data["ds"])]) == 1
    assert "'38'" in capsys.readouterr().err and not out.exists()
    assert main(["export", str(res), "--out", str(out), "--dof", "38"]) == 0
    doc, acc = _read_glb(out)
    world = _animated_worlds(doc, acc, 2)[:body38.skeleton.n_joints]
    np.testing.assert_allclose(world[:, :3, 3], result["joints"][2], atol=2e-5)


def test_glb_quaternions_stay_on_one_hemisphere_through_a_full_turn(data):
    body = data["body"]
    P = np.repeat(body.dofs.zero(body.skeleton)[None], 9, axis=0)
    P[:, body.dofs.index("pelvis_ry")] = np.linspace(0.0, 2 * np.pi, 9)  # passes through pi
    raw = build_glb(body, P, 30.0)
    jlen = struct.unpack_from("<I", raw, 12)[0]
    doc = json.loads(raw[20:20 + jlen])
    a = doc["accessors"][doc["animations"][0]["samplers"][1]["output"]]  # pelvis rotation
    v = doc["bufferViews"][a["bufferView"]]
    q = np.frombuffer(raw, np.float32, 36, 28 + jlen + v["byteOffset"]).reshape(9, 4)
    assert np.all(np.einsum("ti,ti->t", q[1:], q[:-1]) > 0.9)  # 45 degree steps: cos 22.5
    for k, ang in enumerate(np.linspace(0.0, 2 * np.pi, 9)):
        R = _quat_matrix(q[k].astype(float))
        np.testing.assert_allclose(R[[0, 0, 2], [0, 2, 0]],
                                   [np.cos(ang), np.sin(ang), -np.sin(ang)], atol=1e-6)
