"""Skeleton, DOF presets and batched forward kinematics."""
import numpy as np
import pytest

from gltrack.body.dofs import PRESETS, make_dofs
from gltrack.body.kinematics import Kinematics, euler_to_matrix, matrix_to_euler
from gltrack.body.skeleton import JOINT_NAMES, Skeleton, default_skeleton


@pytest.fixture(scope="module")
def skel():
    return default_skeleton(1.75)


def test_default_skeleton_proportions(skel):
    assert skel.names == JOINT_NAMES
    assert skel.height() == pytest.approx(1.75, rel=0.01)
    pos = skel.rest_positions()
    # T-pose: wrists out along +-X at shoulder height, subject's left is +X.
    lw, rw = pos[skel.index("l_wrist")], pos[skel.index("r_wrist")]
    assert lw[0] > 0.5 and rw[0] < -0.5 and abs(lw[1] - pos[skel.index("l_shoulder")][1]) < 1e-9
    assert default_skeleton(1.5).height() == pytest.approx(1.5, rel=0.01)


def test_skeleton_validation():
    with pytest.raises(ValueError, match="topologically"):
        Skeleton(("a", "b"), np.array([-1, 1]), np.zeros((2, 3)), np.zeros((2, 3)), ("XYZ", "XYZ"))
    with pytest.raises(ValueError, match="finite"):
        Skeleton(("a",), np.array([-1]), np.full((1, 3), np.nan), np.zeros((1, 3)), ("XYZ",))
    with pytest.raises(KeyError, match="unknown joint"):
        default_skeleton().index("elbow")
    with pytest.raises(ValueError, match="height"):
        default_skeleton(5.0)


def test_presets_sizes(skel):
    sizes = {p: make_dofs(skel, p).size for p in PRESETS}
    assert sizes == {"full": 48, "38": 37, "25": 25, "upper": 36}
    with pytest.raises(ValueError, match="unknown DOF preset"):
        make_dofs(skel, "99")
    d = make_dofs(skel, "25")
    # Caillette's model: at most 2 DOF per non-root joint.
    for j in range(1, skel.n_joints):
        assert len(d.joint_dofs(j)) <= 2


def test_euler_roundtrip(rng):
    for order in ("ZXY", "YXZ", "ZYX"):
        a = rng.uniform(-1.2, 1.2, size=(50, 3))
        R = euler_to_matrix(a, order)
        assert np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=1e-12)
        assert np.allclose(matrix_to_euler(R, order), a, atol=1e-9)


def test_elementary_rotation_directions():
    # +z about Z takes +X to +Y: a left arm (along +X) with shoulder_rz = -pi/2 points down.
    R = euler_to_matrix(np.array([0, 0, np.pi / 2]), "XYZ")
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_fk_rest_pose_and_known_motion(skel):
    d = make_dofs(skel, "full")
    kin = Kinematics(skel, d)
    pose = kin.forward(d.zero(skel))
    assert np.allclose(pose.positions[0], skel.rest_positions(), atol=1e-12)
    assert np.allclose(pose.rotations[0], np.eye(3), atol=1e-12)
    # Left arm down: shoulder_rz = -pi/2 puts the wrist straight below the shoulder.
    p = d.zero(skel)
    p[d.index("l_shoulder_rz")] = -np.pi / 2
    pos = kin.forward(p).positions[0]
    sh, el, wr = (pos[skel.index(n)] for n in ("l_shoulder", "l_elbow", "l_wrist"))
    upper = np.linalg.norm(skel.offsets[skel.index("l_elbow")])
    assert np.allclose(el, sh + [0, -upper, 0], atol=1e-9)
    assert wr[1] < el[1] and abs(wr[0] - sh[0]) < 1e-9
    # Knee flexion moves the ankle backwards (-Z), never the hip.
    p = d.zero(skel)
    p[d.index("l_knee_rx")] = 1.0
    pos2 = kin.forward(p).positions[0]
    rest = skel.rest_positions()
    assert pos2[skel.index("l_ankle")][2] < -0.2
    assert np.allclose(pos2[skel.index("l_hip")], rest[skel.index("l_hip")])
    # Root translation and yaw move everything rigidly.
    p = d.zero(skel)
    p[:3] += [1.0, 0.0, 2.0]
    p[d.index("pelvis_ry")] = np.pi
    pos3 = kin.forward(p).positions[0]
    assert np.allclose(pos3[skel.index("l_wrist")][0], 1.0 - rest[skel.index("l_wrist")][0])


def test_fk_batch_matches_single_and_preserves_bone_lengths(skel, rng):
    d = make_dofs(skel, "full")
    kin = Kinematics(skel, d)
    P = d.zero(skel) + rng.normal(size=(64, d.size)) * 0.4
    batch = kin.forward(P)
    for i in (0, 17, 63):
        one = kin.forward(P[i])
        assert np.allclose(one.positions[0], batch.positions[i])
    lengths = np.linalg.norm(batch.positions[:, 1:] - batch.positions[:, skel.parents[1:]], axis=-1)
    assert np.allclose(lengths, np.linalg.norm(skel.offsets[1:], axis=-1), atol=1e-12)
    R = batch.rotations
    assert np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=1e-10)


def test_skinning_matrices_map_rest_joints(skel, rng):
    d = make_dofs(skel, "full")
    kin = Kinematics(skel, d)
    P = d.zero(skel) + rng.normal(size=(8, d.size)) * 0.3
    pose = kin.forward(P)
    S = kin.skinning_matrices(pose=pose, dtype=np.float64)
    rest = skel.rest_positions()
    mapped = np.einsum("nbij,bj->nbi", S[..., :3], rest) + S[..., 3]
    assert np.allclose(mapped, pose.positions, atol=1e-12)


def test_validate_clamps_and_rejects(skel):
    d = make_dofs(skel, "full")
    p = d.zero(skel)
    p[d.index("l_knee_rx")] = 10.0
    out = d.validate(p)
    assert out[0, d.index("l_knee_rx")] == d.upper[d.index("l_knee_rx")]
    with pytest.raises(ValueError, match="non-finite.*l_elbow_ry"):
        bad = d.zero(skel)
        bad[d.index("l_elbow_ry")] = np.nan
        d.validate(bad)
    with pytest.raises(ValueError, match="shape"):
        d.validate(np.zeros((2, 5)))
    assert d.validate(np.zeros((0, d.size))).shape == (0, d.size)
    assert np.allclose(d.sigma_at(60), d.sigma30 / 2)


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_local_rotations_match_per_joint_euler(skel, rng, preset):
    """The one-pass composition against its CPU twin, euler_to_matrix joint by joint, with
    orders that differ between joints (the Euler orders are shuffled per joint)."""
    orders = tuple(rng.choice(["ZXY", "YXZ", "ZYX", "XYZ", "XZY", "YZX"]) for _ in skel.orders)
    sk = Skeleton(skel.names, skel.parents, skel.offsets, skel.ends, orders)
    d = make_dofs(sk, preset)
    kin = Kinematics(sk, d)
    P = d.validate(d.zero(sk) + rng.normal(size=(7, d.size)) * 0.8)
    angles = kin.angles(P)
    want = np.stack([euler_to_matrix(angles[:, j], o) for j, o in enumerate(orders)], axis=1)
    assert np.allclose(kin.local_rotations(P), want, atol=1e-12)
    sub = [5, 0, 11]
    assert np.allclose(kin.local_rotations(P, joints=sub), want[:, sub], atol=1e-12)
    # the output follows the input: one DOF changed moves its joint's rotation alone
    Q = P.copy()
    k = d.size - 1
    Q[:, k] += 0.3
    moved = np.abs(kin.local_rotations(Q) - kin.local_rotations(P)).max(axis=(0, 2, 3)) > 1e-6
    assert moved.tolist() == [j == d.joint[k] for j in range(sk.n_joints)]


def test_chain_points_match_full_forward_kinematics(skel, rng):
    d = make_dofs(skel, "full")
    kin = Kinematics(skel, d)
    P = d.zero(skel) + rng.normal(size=(9, d.size)) * 0.5
    pose = kin.forward(P)
    local = rng.normal(size=(4, 3)) * 0.1
    for name in ("pelvis", "head", "l_wrist", "r_ankle"):
        b = skel.index(name)
        want = kin.transform_points(pose, np.full(4, b), local)
        assert np.allclose(kin.chain_points(P, b, local), want, atol=1e-12)
    # one pose as a (D,) vector, and clamping as forward does
    wild = d.zero(skel)
    wild[d.index("l_elbow_rx")] = 50.0
    b = skel.index("l_wrist")
    want = kin.transform_points(kin.forward(wild), np.array([b]), local[:1])
    assert np.allclose(kin.chain_points(wild, b, local[:1]), want, atol=1e-12)
