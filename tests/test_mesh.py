"""The procedural body mesh and the default surface markers."""
import numpy as np
import pytest
import trimesh

from gltrack.body.dofs import make_dofs
from gltrack.body.kinematics import Kinematics
from gltrack.body.markers import (JOINT_SET_EVAL, MARKER_NAMES, Markers, closest_points_on_mesh,
                                  default_markers)
from gltrack.body.mesh import GIRTH_RATIOS, PARTS, BodyMesh, make_body_mesh
from gltrack.body.skeleton import JOINT_NAMES, default_skeleton


@pytest.fixture(scope="module")
def skel():
    return default_skeleton(1.75)


@pytest.fixture(scope="module")
def mesh(skel):
    return make_body_mesh(skel, lod=1)


@pytest.fixture(scope="module")
def kin(skel):
    return Kinematics(skel, make_dofs(skel, "full"))


def _components(m: BodyMesh):
    tm = trimesh.Trimesh(m.vertices.astype(np.float64), m.faces, process=False)
    return tm.split(only_watertight=False)


def _bvh_like_skeleton(skel):
    """Same topology, non-canonical bone directions: A-pose arms, leaning spine, splayed legs."""
    off = skel.offsets.copy()
    ends = skel.ends.copy()

    def rot_z(v, a):
        c, s = np.cos(a), np.sin(a)
        return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])

    for side, sgn in (("l", 1), ("r", -1)):
        for j in ("elbow", "wrist"):
            i = skel.index(f"{side}_{j}")
            off[i] = rot_z(off[i], -sgn * 0.8)  # arms ~45 deg down
        i = skel.index(f"{side}_wrist")
        ends[i] = rot_z(ends[i], -sgn * 0.8)
        i = skel.index(f"{side}_knee")
        off[i] = rot_z(off[i], sgn * 0.15)
    for j in ("spine_upper", "neck"):
        i = skel.index(j)
        off[i] = off[i] + np.array([0.0, 0.0, -0.03])
    return skel.with_offsets(off, ends)


def test_triangle_budget_per_lod(skel):
    n = {lod: make_body_mesh(skel, lod=lod).n_faces for lod in (0, 1, 2)}
    assert n == {0: 1008, 1: 1968, 2: 7872}  # the documented counts
    assert n[1] <= 2000
    assert 0.4 <= n[0] / n[1] <= 0.6
    assert 3.5 <= n[2] / n[1] <= 4.5
    with pytest.raises(ValueError, match="lod"):
        make_body_mesh(skel, lod=3)


def test_dtypes_and_skin_weights(mesh, skel):
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int32
    assert np.allclose(mesh.weights.sum(1), 1.0, atol=1e-5)
    assert np.all(mesh.weights >= 0)
    assert np.all((mesh.weights > 0).sum(1) <= 4)
    assert mesh.joints.min() >= 0 and mesh.joints.max() < skel.n_joints
    assert set(np.unique(mesh.part)) == set(range(len(PARTS)))
    # joints blend: some vertices carry two or more influences, most carry mainly one
    assert np.mean((mesh.weights > 0.01).sum(1) >= 2) > 0.1


@pytest.mark.parametrize("lod", [0, 1, 2])
def test_components_are_closed_and_outward(skel, lod):
    comps = _components(make_body_mesh(skel, lod=lod))
    assert len(comps) == 19
    for c in comps:
        assert c.is_watertight
        assert c.is_winding_consistent
        assert c.volume > 0  # signed volume > 0: faces wind CCW seen from outside


def test_total_volume_is_human(mesh):
    # a 1.75 m adult male displaces ~0.07 m^3; overlapping caps add a little
    vol = sum(c.volume for c in _components(mesh))
    assert 0.05 < vol < 0.11


@pytest.mark.parametrize("height", [1.5, 1.75, 1.95])
def test_size_follows_height(height):
    sk = default_skeleton(height)
    m = make_body_mesh(sk)
    ext = m.vertices.max(0) - m.vertices.min(0)
    assert abs(ext[1] - sk.height()) < 0.05 * sk.height()
    tips = sk.rest_positions() + sk.ends
    span = tips[:, 0].max() - tips[:, 0].min()  # finger tip to finger tip
    assert abs(ext[0] - span) < 0.05 * span


def test_girths_change_the_body(skel, mesh):
    vol = sum(c.volume for c in _components(mesh))
    fat = make_body_mesh(skel, girth_scale=1.3)
    assert sum(c.volume for c in _components(fat)) > 1.5 * vol
    thick = make_body_mesh(skel, girths={"thigh": 0.8})
    thigh = mesh.part == PARTS.index("l_thigh")
    r0 = np.abs(mesh.vertices[thigh, 0] - skel.rest_positions()[skel.index("l_hip"), 0]).max()
    r1 = np.abs(thick.vertices[thigh, 0] - skel.rest_positions()[skel.index("l_hip"), 0]).max()
    assert r1 > r0 * 1.2
    with pytest.raises(ValueError, match="unknown girths"):
        make_body_mesh(skel, girths={"belly": 1.0})
    with pytest.raises(ValueError, match="positive"):
        make_body_mesh(skel, girths={"head": -1.0})
    assert set(GIRTH_RATIOS) >= {"head", "neck", "chest", "waist", "pelvis", "upper_arm",
                                 "forearm", "hand", "thigh", "shin", "foot"}


def _segment_distance(p, a, b):
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0, 1)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


@pytest.mark.parametrize("which", ["default", "bvh_like"])
def test_vertices_follow_actual_bone_vectors(skel, which):
    sk = skel if which == "default" else _bvh_like_skeleton(skel)
    m = make_body_mesh(sk)
    P = sk.rest_positions()
    dominant = m.joints[np.arange(m.n_vertices), m.weights.argmax(1)]
    for joint, child in (("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"), ("r_hip", "r_knee"),
                         ("r_knee", "r_ankle"), ("spine_upper", "neck")):
        j, c = sk.index(joint), sk.index(child)
        own = dominant == j
        assert own.sum() > 10
        dist = _segment_distance(m.vertices[own].astype(np.float64), P[j], P[c])
        assert dist.max() < 0.2, f"{joint}: vertices {dist.max():.3f} m from the bone"
    for c in _components(m):
        assert c.is_watertight and c.volume > 0
    # hands are near the (rotated) finger tips
    tip = P[sk.index("l_wrist")] + sk.ends[sk.index("l_wrist")]
    hand = m.vertices[m.part == PARTS.index("l_hand")]
    assert np.linalg.norm(hand - tip, axis=1).min() < 0.01


def test_vertices_are_mostly_weighted_to_their_bone(mesh, skel):
    own_bone = {"l_upper_arm": "l_shoulder", "l_forearm": "l_elbow", "l_hand": "l_wrist",
                "l_thigh": "l_hip", "l_shin": "l_knee", "l_foot": "l_ankle", "head": "head",
                "r_forearm": "r_elbow", "r_shin": "r_knee", "pelvis": "pelvis"}
    for part, bone in own_bone.items():
        sel = mesh.part == PARTS.index(part)
        w_own = np.where(mesh.joints[sel] == skel.index(bone), mesh.weights[sel], 0).sum(1)
        assert w_own.min() >= 0.5 - 1e-6, part  # never outweighed by a neighbour
        assert np.mean(w_own) > 0.55, part


def _edges(faces):
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def test_posing_moves_the_right_vertices_without_tearing(mesh, skel, kin):
    d = kin.dofs
    p = np.tile(d.zero(skel), (2, 1))
    p[1, d.index("l_knee_rx")] = 1.6
    p[1, d.index("r_elbow_ry")] = 2.0
    rest, posed = mesh.skin(kin.skinning_matrices(p))
    assert np.allclose(rest, mesh.vertices, atol=1e-5)  # zero pose == rest mesh
    move = np.linalg.norm(posed - rest, axis=1)
    shin = mesh.part == PARTS.index("l_shin")
    foot = mesh.part == PARTS.index("l_foot")
    head = mesh.part == PARTS.index("head")
    r_hand = mesh.part == PARTS.index("r_hand")
    assert np.median(move[shin]) > 0.1 and move[foot].min() > 0.2
    assert move[head].max() < 1e-6
    assert move[mesh.part == PARTS.index("r_thigh")].max() < 1e-6
    assert move[r_hand].min() > 0.2
    # the posed shin hangs behind the knee: the ankle region goes back (-Z)
    assert posed[foot, 2].mean() < rest[foot, 2].mean() - 0.3
    # no tearing: edges stretch smoothly, none jumps
    e = _edges(mesh.faces)
    l0 = np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)
    l1 = np.linalg.norm(posed[e[:, 0]] - posed[e[:, 1]], axis=1)
    assert np.all(l1 < 2.0 * l0 + 0.01)
    assert np.abs(l1 - l0).max() < 0.06


# ----------------------------------------------------------------------------- markers


@pytest.fixture(scope="module")
def markers(skel, mesh):
    return default_markers(skel, mesh)


def test_marker_set(markers, skel):
    assert markers.names == MARKER_NAMES and 20 <= len(markers) <= 26
    assert markers.local.shape == (len(markers), 3) and markers.local.dtype == np.float64
    rest = markers.rest_positions(skel)
    x = dict(zip(markers.names, rest))
    for n in markers.names:
        if n.startswith("l_"):
            assert x[n][0] > 0.05 and np.allclose(x["r_" + n[2:]], x[n] * [-1, 1, 1], atol=0.01)
    assert rest[:, 1].argmax() == markers.index("head_top")
    assert x["sternum"][2] > 0.05 and x["sacrum"][2] < -0.05 and x["neck_back"][2] < -0.03
    assert x["l_toe"][2] > x["l_ankle"][2] > x["l_heel"][2]
    assert set(JOINT_SET_EVAL) <= set(JOINT_NAMES) and len(JOINT_SET_EVAL) == 15
    with pytest.raises(KeyError):
        markers.index("nose")


@pytest.mark.parametrize("lod", [0, 1, 2])
def test_markers_lie_on_the_surface(skel, lod):
    m = make_body_mesh(skel, lod=lod)
    mk = default_markers(skel, m)
    _, dist = closest_points_on_mesh(mk.rest_positions(skel), m.vertices, m.faces)
    assert dist.max() < 0.01


def test_markers_on_a_bvh_like_skeleton(skel):
    sk = _bvh_like_skeleton(skel)
    m = make_body_mesh(sk)
    mk = default_markers(sk, m)
    _, dist = closest_points_on_mesh(mk.rest_positions(sk), m.vertices, m.faces)
    assert dist.max() < 0.01
    # the wrist marker sits at the (lowered) wrist, not where a T-pose wrist would be
    wrist = sk.rest_positions()[sk.index("l_wrist")]
    assert np.linalg.norm(mk.rest_positions(sk)[mk.index("l_wrist")] - wrist) < 0.06


def test_markers_move_with_their_bones(markers, skel, kin, mesh):
    d = kin.dofs
    rng = np.random.default_rng(3)
    p = np.tile(d.zero(skel), (3, 1))
    p[1, d.index("l_elbow_ry")] = -1.5
    p[2, 6:] = rng.uniform(d.lower[6:], d.upper[6:]) * 0.5
    p[2, 3:6] = [0.3, 1.0, -0.2]
    p[2, :3] += [0.3, -0.1, 0.5]
    pose = kin.forward(p)
    pos = markers.positions(kin, pose)
    assert pos.shape == (3, len(markers), 3)
    assert np.allclose(pos[0], markers.rest_positions(skel))
    # independent: rigid transform of the rest offset by each bone's world frame
    for n in range(3):
        for k, b in enumerate(markers.bone):
            ref = pose.positions[n, b] + pose.rotations[n, b] @ markers.local[k]
            assert np.allclose(pos[n, k], ref)
    moved = np.linalg.norm(pos[1] - pos[0], axis=1)
    assert moved[markers.index("l_wrist")] > 0.1 and moved[markers.index("l_hand")] > 0.1
    assert moved[markers.index("l_elbow")] < 1e-9 and moved[markers.index("r_wrist")] < 1e-9
    # markers on rigid parts stay on the posed skin
    posed = mesh.skin(kin.skinning_matrices(pose=pose))[2]
    rigid = [markers.index(n) for n in ("head_top", "head_front", "l_toe", "r_heel", "sternum")]
    _, dist = closest_points_on_mesh(pos[2, rigid], posed, mesh.faces)
    assert dist.max() < 0.02


def test_closest_points_agree_with_trimesh():
    rng = np.random.default_rng(0)
    tm = trimesh.creation.icosphere(subdivisions=1, radius=0.3)
    pts = rng.normal(size=(40, 3)) * 0.4
    mine, dist = closest_points_on_mesh(pts, tm.vertices, tm.faces)
    tri = tm.triangles
    best = np.full(len(pts), np.inf)
    for k, p in enumerate(pts):  # trimesh's per-pair closest point, over every triangle
        c = trimesh.triangles.closest_point(tri, np.repeat(p[None], len(tri), 0))
        best[k] = np.linalg.norm(c - p, axis=1).min()
    assert np.allclose(dist, best, atol=1e-9)
    assert np.allclose(np.linalg.norm(mine - pts, axis=1), dist)


def test_markers_validate_shapes():
    with pytest.raises(ValueError):
        Markers(("a", "b"), np.array([0]), np.zeros((2, 3)))


def test_nearest_faces_carry_face_data_between_levels_of_detail(skel, mesh):
    np.testing.assert_array_equal(mesh.nearest_faces(mesh), np.arange(mesh.n_faces))
    coarse = make_body_mesh(skel, lod=0)
    idx = mesh.nearest_faces(coarse)
    assert idx.shape == (coarse.n_faces,) and idx.min() >= 0 and idx.max() < mesh.n_faces
    # every coarse face takes a face of its own body part, nearby on the surface
    np.testing.assert_array_equal(mesh.part[mesh.faces[idx, 0]], coarse.part[coarse.faces[:, 0]])
    gap = np.linalg.norm(mesh.vertices[mesh.faces[idx]].mean(axis=1)
                         - coarse.vertices[coarse.faces].mean(axis=1), axis=1)
    assert np.median(gap) < 0.03 and gap.max() < 0.1
