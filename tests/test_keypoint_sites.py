"""The body points the trackers fit to keypoints: joint centres and the head and foot sites."""
import numpy as np
import pytest

from gltrack.body.mesh import PARTS
from gltrack.body.model import BodyModel
from gltrack.body.skeleton import default_skeleton
from gltrack.observe.keypoints import BODY_JOINTS, LANDMARKS, NAMES, SITE_LANDMARKS, site_points
from gltrack.render.reference import skin_vertices
from gltrack.track.keypoint_sites import SITE_BONES, KeypointSites, keypoint_targets
from gltrack.track.multiview import HpsOptions


def _random_poses(body, n, seed):
    rng = np.random.default_rng(seed)
    d = body.dofs
    lo, hi = np.clip(d.lower, -3, 3), np.clip(d.upper, -3, 3)  # translations are unbounded
    X = rng.uniform(lo, hi, size=(n, d.size)) * 0.5
    X[:, :3] = rng.uniform(-1, 1, size=(n, 3))
    return X


def test_site_points_are_the_landmarks_midpoints():
    pts = np.random.default_rng(0).normal(size=(5, 33, 3))
    pts[2, 7] = np.nan
    ok = [0, 1, 3, 4]
    for name, marks in SITE_LANDMARKS.items():
        got = site_points(pts, name)
        assert got.shape == (5, 3)
        want = pts[:, marks[0]] if len(marks) == 1 else (pts[:, marks[0]] + pts[:, marks[1]]) / 2
        assert np.allclose(got[ok], want[ok])
    assert np.isnan(site_points(pts, "head")[2]).all()
    assert np.isfinite(site_points(pts, "l_toe")[2]).all()
    assert np.allclose(site_points(pts, "l_toe"), pts[:, 31])


@pytest.mark.parametrize("height", [1.55, 1.85])
def test_the_head_site_is_the_centre_of_the_head_the_mesh_draws(height):
    """Independent twin: the posed head vertices' bounding-box centre (reference skinning of the
    procedural mesh), against the site from forward kinematics, on random poses; a joint's
    point is the joint itself; the head site moves when only the head turns."""
    body = BodyModel.build(default_skeleton(height))
    sites = KeypointSites(["l_elbow", "head", "l_toe", "r_heel"], body.skeleton)
    X = _random_poses(body, 6, seed=int(height * 100))
    got = sites.positions(body.kin, X)
    assert got.shape == (6, 4, 3)
    assert np.allclose(got[:, 0], body.joints(X)[:, body.skeleton.index("l_elbow")])
    V = skin_vertices(body.mesh, body.skinning(X))
    head = V[:, body.mesh.part == PARTS.index("head")]
    centre = 0.5 * (head.min(axis=1) + head.max(axis=1))
    # the head tube narrows to 0.85 of its width at the chin, so the box's centre lies ~8 mm
    # from the axis' midpoint; the head joint is ~8 cm from it
    assert np.linalg.norm(got[:, 1] - centre, axis=1).max() < 0.012
    assert np.linalg.norm(body.joints(X)[:, body.skeleton.index("head")] - centre,
                          axis=1).min() > 0.05
    # the toe tip and the heel lie at the foot's front and back ends
    foot = V[:, body.mesh.part == PARTS.index("l_foot")]
    toe = KeypointSites(["l_toe", "l_heel"], body.skeleton).positions(body.kin, X)
    ankle = body.joints(X)[:, body.skeleton.index("l_ankle")]
    for k in (0, 1):
        along = toe[:, k] - ankle  # the foot's ends: the farthest vertices along this axis
        u = along / np.linalg.norm(along, axis=1, keepdims=True)
        reach = np.einsum("nvi,ni->nv", foot - ankle[:, None], u).max(axis=1)
        assert np.allclose(reach, np.linalg.norm(along, axis=1), atol=0.03), (k, reach)
        assert np.linalg.norm(foot - toe[:, k, None], axis=-1).min(axis=1).max() < 0.04
    # turn the head alone: the head joint stays, the head site moves
    Y = X.copy()
    Y[:, body.dofs.joint_dofs(body.skeleton.index("head"))] += 0.3
    moved = sites.positions(body.kin, Y)
    assert np.allclose(body.joints(Y)[:, body.skeleton.index("head")],
                       body.joints(X)[:, body.skeleton.index("head")])
    assert (np.linalg.norm(moved[:, 1] - got[:, 1], axis=1) > 0.005).all()
    assert np.allclose(moved[:, [0, 2, 3]], got[:, [0, 2, 3]])


def test_sites_follow_the_skeleton_they_are_scored_with():
    """The body estimate scores many skeletons with one set of sites: the offsets are the
    skeleton's own."""
    short, tall = default_skeleton(1.5), default_skeleton(1.9)
    sites = KeypointSites(["head", "r_toe"], short)
    a, b = sites.local(short), sites.local(tall)
    assert np.allclose(b, a * 1.9 / 1.5, rtol=0.02)
    assert np.linalg.norm(a[1]) > 0.05


class _Dataset:
    def __init__(self, names, points):
        self._kp = {"names": list(names), "points": points}

    def keypoints(self):
        return self._kp


def _landmarks(frames=3):
    return np.random.default_rng(1).normal(size=(frames, 33, 3))


def test_keypoint_targets_match_joints_and_the_sites_the_preset_turns():
    pts = _landmarks()
    full = BodyModel.build(preset="full")
    sites, target = keypoint_targets(_Dataset(NAMES, pts), full, HpsOptions())
    assert sites.names == tuple(BODY_JOINTS) + tuple(SITE_BONES)
    assert target.shape == (3, len(sites.names), 3)
    assert np.allclose(target[:, 0], pts[:, LANDMARKS[BODY_JOINTS[0]]])
    assert np.allclose(target[:, sites.names.index("head")], site_points(pts, "head"))
    assert np.allclose(target[:, sites.names.index("r_toe")], pts[:, 32])
    # the 38-DOF preset fixes the ankles: the feet's sites are left out, the head's kept
    p38 = BodyModel.build(preset="38")
    assert not p38.dofs.joint_dofs(p38.skeleton.index("l_ankle")).size
    sites38, _ = keypoint_targets(_Dataset(NAMES, pts), p38, HpsOptions())
    assert "head" in sites38.names and not {"l_heel", "r_toe"} & set(sites38.names)
    # upper body: no knees, ankles or feet (hidden, fixed), the head kept
    up, _ = keypoint_targets(_Dataset(NAMES, pts), BodyModel.build(preset="upper"), HpsOptions())
    assert not {"l_knee", "r_ankle", "l_heel", "r_toe"} & set(up.names)
    assert "head" in up.names
    # keypoints that are not MediaPipe's 33: joints by name only
    names = [n for n in NAMES if n]
    idx = [NAMES.index(n) for n in names]
    only, t = keypoint_targets(_Dataset(names, pts[:, idx]), full, HpsOptions())
    assert only.names == tuple(BODY_JOINTS)
    # the body estimate's: joints only (a site's offset is the mesh's, not the subject's)
    bare, t = keypoint_targets(_Dataset(NAMES, pts), full, HpsOptions(), sites=False)
    assert bare.names == tuple(BODY_JOINTS) and t.shape == (3, len(BODY_JOINTS), 3)
    # the option off: nothing
    assert keypoint_targets(_Dataset(NAMES, pts), full, HpsOptions(keypoints=0)) == (None, None)
