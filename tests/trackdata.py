"""Small synthetic datasets for tracker tests, rendered with the CPU reference (not the engine)."""
import numpy as np

from gltrack.body.model import BodyModel, body_to_meta
from gltrack.camera import depth_camera_sr4000
from gltrack.data.dataset import DatasetWriter
from gltrack.render import reference as ref

#: Daz-style joint names (gltrack joint -> Daz), a convention the BVH retargeter recognises:
#: BVH clips written with them test the retargeting path the CMU Daz files take.
DAZ = {"pelvis": "hip", "spine_lower": "abdomen", "spine_upper": "chest", "neck": "neck",
       "head": "head"}
for _s in "lr":
    for _a, _b in (("clavicle", "Collar"), ("shoulder", "Shldr"), ("elbow", "ForeArm"),
                   ("wrist", "Hand"), ("hip", "Thigh"), ("knee", "Shin"), ("ankle", "Foot")):
        DAZ[f"{_s}_{_a}"] = _s + _b


def smooth_motion(body, n, rng, fps=30.0):
    """A slow walk forward with an arm raise and knee bends: (n, D) params."""
    d, sk = body.dofs, body.skeleton
    t = np.arange(n) / fps
    P = np.repeat(d.zero(sk)[None], n, axis=0)
    P[:, 2] += 0.3 * t
    P[:, 0] += 0.1 * np.sin(t)
    P[:, d.index("pelvis_ry")] = 0.3 * np.sin(1.5 * t)
    P[:, d.index("l_shoulder_rz")] = -1.2 + 0.9 * np.clip(t, 0, 1)
    P[:, d.index("r_shoulder_rz")] = 1.2
    P[:, d.index("l_elbow_ry")] = -0.4 - 0.3 * np.sin(2 * t)
    P[:, d.index("l_hip_rx")] = -0.4 * np.sin(4 * t)
    P[:, d.index("r_hip_rx")] = 0.4 * np.sin(4 * t)
    P[:, d.index("l_knee_rx")] = 0.3 + 0.3 * np.sin(4 * t)
    P[:, d.index("r_knee_rx")] = 0.3 - 0.3 * np.sin(4 * t)
    return d.validate(P)


#: a walker in mid-stride: left leg and right arm forward, right knee bent (radians)
MID_STRIDE = {"l_hip_rx": -0.55, "r_hip_rx": 0.4, "r_knee_rx": 0.6, "l_knee_rx": 0.15,
              "l_shoulder_rz": -1.25, "r_shoulder_rz": 1.25, "r_shoulder_rx": -0.5,
              "l_shoulder_rx": 0.45}


def mid_stride(body, **extra):
    """(1, D) the :data:`MID_STRIDE` pose, with ``extra`` DOF values (name -> value) set too."""
    d = body.dofs
    P = d.zero(body.skeleton)[None].copy()
    for name, value in {**MID_STRIDE, **extra}.items():
        P[:, d.index(name)] = value
    return d.validate(P)


def legs_right_way(body, x, truth):
    """Pose ``x`` (D,) faces the way of ``truth`` (D,) and has each ankle nearer its own side's
    true ankle than the other's (a body turned round with the mirror-image stride puts its
    ankles where the truth's are, hence the heading test)."""
    d, sk = body.dofs, body.skeleton
    got, want = body.joints(x[None])[0], body.joints(truth[None])[0]
    l, r = sk.index("l_ankle"), sk.index("r_ankle")
    yaw = d.index("pelvis_ry")
    facing = np.cos(x[yaw] - truth[yaw]) > 0
    return facing and (np.linalg.norm(got[l] - want[l]) + np.linalg.norm(got[r] - want[r])
                       < np.linalg.norm(got[l] - want[r]) + np.linalg.norm(got[r] - want[l]))


def make_depth_dataset(out, n=8, seed=0, noise=0.005):
    rng = np.random.default_rng(seed)
    body = BodyModel.build()
    P = smooth_motion(body, n, rng)
    cam = depth_camera_sr4000((0.3, 1.0, 3.2), (0.0, 0.9, 0.0))
    z, _ = ref.render_candidates(body.mesh, body.skinning(P), cam.K, cam.R, cam.t, cam.width, cam.height)
    with DatasetWriter(out, "depth", 30.0, [cam], body=body_to_meta(body.skeleton)) as w:
        for f in range(n):
            zf = z[f] + rng.normal(size=z[f].shape) * noise * (z[f] > 0)
            w.write_depth(f, 0, zf)
        w.write_groundtruth(body.joints(P), list(body.skeleton.names), body.marker_positions(P), P)
    return body, P


def landmark_model():
    """The installed pose landmark model's path; skips the test without one."""
    import pytest

    from gltrack.observe.keypoints import find_model

    path = find_model()
    if path is None:
        pytest.skip("the pose landmark model is not installed (scripts/setup.sh copies it from "
                    "the mediapipe wheel; or set GLTRACK_POSE_MODEL)")
    return path


def keypoint_dataset(path, body, P, seed=3):
    """A 4-camera ring dataset of the poses ``P`` (N, D) rendered with the CPU reference
    (:func:`gltrack.bench.multiview.render_dataset`) and a ``keypoints.npz`` whose triangulated
    points lie on the true joints: returns the open Dataset and the joints (N, J, 3)."""
    from gltrack.bench.multiview import RING, render_dataset
    from gltrack.bench.rigs import ring_cameras
    from gltrack.data.dataset import Dataset
    from gltrack.observe.keypoints import BODY_JOINTS, LANDMARKS, NAMES

    cams = ring_cameras((0.0, 0.9, 0.0), **dict(RING, radius=3.0))
    render_dataset(path, body, P, cams, 15.0, np.random.default_rng(seed))
    n, c = len(P), len(cams)
    points = np.full((n, 33, 3), np.nan)
    J = body.joints(P)
    for name in BODY_JOINTS:
        points[:, LANDMARKS[name]] = J[:, body.skeleton.names.index(name)]
    np.savez(path / "keypoints.npz", uv=np.zeros((n, c, 33, 2)), visibility=np.ones((n, c, 33)),
             points=points, residual=np.zeros((n, c, 33)), names=np.array(NAMES))
    return Dataset.open(path), J
