"""Limb proposals from the keypoints (``keypoint_ik``, :mod:`gltrack.track.keypoint_ik`).

The IK itself runs on the CPU; its independent check is the forward kinematics of the solved
pose against the targets. The tracker-level test renders a dataset with the CPU reference
rasteriser, puts its keypoints on the true joints and scores on the real GL context.
"""
import numpy as np
import pytest

from gltrack.body.model import BodyModel
from gltrack.track.keypoint_ik import LIMBS, NEAR, limb_targets, propose_limbs

SITES = [n for limb in LIMBS.values() for n in limb[1:]]


@pytest.fixture(scope="module")
def body():
    return BodyModel.build()


def _limb_dofs(body, limb, with_middle=True):
    sk, d = body.skeleton, body.dofs
    joints = LIMBS[limb][:2] if with_middle else LIMBS[limb][:1]
    return np.concatenate([d.joint_dofs(sk.index(j)) for j in joints])


def _targets(body, x):
    P = body.kin.forward(x[None]).positions[0]
    return np.stack([P[body.skeleton.index(n)] for n in SITES])


@pytest.mark.parametrize("limb", list(LIMBS))
def test_a_limb_anywhere_is_solved_onto_its_keypoints(body, limb):
    d, rng = body.dofs, np.random.default_rng(list(LIMBS).index(limb))
    idx = _limb_dofs(body, limb)
    lt = limb_targets(SITES)
    solved = close = 0
    for _ in range(6):
        truth, x = (d.zero(body.skeleton) for _ in range(2))
        truth[idx] = rng.uniform(d.lower[idx], d.upper[idx])
        x[idx] = rng.uniform(d.lower[idx], d.upper[idx])
        y = _targets(body, truth)
        props = [p for p in propose_limbs(body.kin, x, y, lt) if p.limb == limb]
        if not props:  # the random start happened to be near the truth
            assert np.linalg.norm(_targets(body, x) - y, axis=1)[
                [SITES.index(n) for n in LIMBS[limb][1:]]].mean() < NEAR
            continue
        p = props[0]
        solved += 1
        # only the limb's DOFs moved, within their limits
        moved = np.nonzero(~np.isclose(p.pose, x))[0]
        assert set(moved) <= set(idx)
        assert (p.pose >= d.lower - 1e-9).all() and (p.pose <= d.upper + 1e-9).all()
        # independent check: the solved pose's joints, by forward kinematics, on the targets
        k = [SITES.index(n) for n in LIMBS[limb][1:]]
        err = np.linalg.norm(_targets(body, p.pose)[k] - y[k], axis=1).mean()
        assert err == pytest.approx(p.after, abs=1e-9)
        assert err < p.before and p.before > NEAR
        close += err < 0.05
    # from its three starts the IK misses a random limb now and then (1 of 360 cases stayed
    # over 5 cm off, 137 mm; median 11 mm)
    assert solved >= 4 and close >= solved - 1


def test_no_proposal_near_the_keypoints_or_without_them(body):
    d = body.dofs
    x = d.zero(body.skeleton)
    y = _targets(body, x)
    lt = limb_targets(SITES)
    assert propose_limbs(body.kin, x, y, lt) == []  # every limb on its keypoints
    y2 = y + 0.03  # 3 cm off everywhere: under NEAR
    assert propose_limbs(body.kin, x, y2, lt) == []
    far = y.copy()
    far[SITES.index("l_wrist")] += [0.0, 0.5, 0.0]
    far[SITES.index("l_elbow")] = np.nan
    assert [p.limb for p in propose_limbs(body.kin, x, far, lt)] == ["l_arm"]
    gone = np.full_like(y, np.nan)
    assert propose_limbs(body.kin, x, gone, lt) == []


def test_the_middle_keypoint_alone_turns_the_swing_joint_only(body):
    d = body.dofs
    truth = d.zero(body.skeleton)
    truth[d.index("r_shoulder_rz")] = 1.0
    truth[d.index("r_elbow_ry")] = d.upper[d.index("r_elbow_ry")] * 0.5
    y = _targets(body, truth)
    y[SITES.index("r_wrist")] = np.nan
    x = d.zero(body.skeleton)
    (p,) = propose_limbs(body.kin, x, y, limb_targets(SITES))
    moved = set(np.nonzero(~np.isclose(p.pose, x))[0])
    assert p.limb == "r_arm" and moved and moved <= set(_limb_dofs(body, "r_arm", False))
    assert p.after < 0.02


def test_limb_targets_need_both_sites_and_presets_without_leg_dofs_get_no_legs():
    assert set(limb_targets(SITES)) == set(LIMBS)
    assert set(limb_targets([n for n in SITES if "knee" not in n])) == {"l_arm", "r_arm"}
    upper = BodyModel.build(preset="upper")
    y = _targets(upper, upper.dofs.zero(upper.skeleton)) + np.array([0.0, 0.3, 0.0])
    props = propose_limbs(upper.kin, upper.dofs.zero(upper.skeleton), y, limb_targets(SITES))
    assert {p.limb for p in props} <= {"l_arm", "r_arm"} and props


def test_the_tracker_brings_a_lost_arm_back_to_its_keypoints(tmp_path, ctx):
    """A rendered dataset, keypoints on the true joints: from a start with the left arm raised
    where the person's hangs, ``keypoint_ik`` puts it back in the first step (and says so in
    the frame's info); without it the arm stays raised."""
    from gltrack.track.multiview import HpsOptions, HPSTracker
    from trackdata import keypoint_dataset

    body = BodyModel.build()
    d = body.dofs
    P = np.repeat(d.zero(body.skeleton)[None], 3, axis=0)
    P[:, 2] = [0.0, 0.02, 0.04]
    P[:, d.index("l_shoulder_rz")] = -1.3  # hanging
    P[:, d.index("r_shoulder_rz")] = 1.3
    P = d.validate(P)
    ds, J = keypoint_dataset(tmp_path / "ds", body, P)
    start = P[0].copy()
    start[d.index("l_shoulder_rz")] = 1.2  # raised over the head
    wrist = body.skeleton.names.index("l_wrist")
    out = {}
    for on in (True, False):
        tr = HPSTracker(ds, body, ctx, HpsOptions(particles=12, keypoint_ik=on),
                        np.random.default_rng(0))
        try:
            tr.start(0, start)
            est = tr.step(1)
            out[on] = np.linalg.norm(body.joints(est.params[None])[0, wrist] - J[1, wrist])
            assert ("keypoint_ik" in est.info) == on
            if on:  # (a limb the 12 particles moved off may be solved back too)
                assert "l_arm" in est.info["keypoint_ik"]
        finally:
            tr.close()
    assert out[True] < 0.1 < out[False]
