"""Procedural training frames: random plausible poses rendered by the CPU reference rasteriser.

Only the numpy twin (:mod:`gltrack.render.reference`) is used, never the GL engine, so the
classifier can be regenerated on any machine without a GPU or a dataset.
"""
from __future__ import annotations

import logging

import numpy as np

from gltrack.body.dofs import make_dofs
from gltrack.body.kinematics import Kinematics
from gltrack.body.mesh import make_body_mesh
from gltrack.body.skeleton import default_skeleton

from .parts import PartModel, TrainingFrame

log = logging.getLogger(__name__)

#: Fraction of each joint's range of motion the random poses use: full swings of the limbs,
#: gentle torso and head, so poses look like everyday activity rather than contortions.
RANGE_FRACTION = {"spine_lower": 0.3, "spine_upper": 0.3, "neck": 0.3, "head": 0.3,
                  "l_clavicle": 0.5, "r_clavicle": 0.5, "l_wrist": 0.5, "r_wrist": 0.5,
                  "l_ankle": 0.4, "r_ankle": 0.4}
LIMB_FRACTION = 0.7


def random_poses(rng: np.random.Generator, skeleton, dofs, n: int, *,
                 max_yaw: float = np.pi / 2) -> np.ndarray:
    """Random poses of a standing subject facing roughly +Z, root near the world origin.

    Parameters
    ----------
    rng : numpy.random.Generator
    skeleton : Skeleton; dofs : DofSet
    n : int
    max_yaw : float, radians, heading range about +Y (+-)

    Returns
    -------
    (n, D) float64
    """
    D = dofs.size
    X = np.zeros((n, D))
    X[:, :3] = skeleton.offsets[0]
    X[:, 0] += rng.uniform(-0.3, 0.3, n)
    X[:, 2] += rng.uniform(-0.4, 0.4, n)
    for i in range(3, D):
        jname = skeleton.names[dofs.joint[i]]
        if jname == "pelvis":
            yaw = dofs.names[i].endswith("ry")
            X[:, i] = rng.uniform(-max_yaw, max_yaw, n) if yaw else rng.normal(0, 0.05, n)
            continue
        f = RANGE_FRACTION.get(jname, LIMB_FRACTION)
        X[:, i] = rng.uniform(f * dofs.lower[i], f * dofs.upper[i], n)
    return X


def default_depth_camera(distance: float = 3.6, height: float = 1.0):
    """An SR4000-like camera (176x144) ``distance`` metres in front of the origin, level."""
    from gltrack.camera import depth_camera_sr4000

    return depth_camera_sr4000([0.0, height, distance], [0.0, 0.92, 0.0])


def render_frames(rng: np.random.Generator, n_frames: int, *, camera=None, noise: float = 0.01,
                  dropout: float = 0.005, skeleton=None, lod: int = 1):
    """Render random poses to noisy depth frames with their part positions.

    Parameters
    ----------
    rng : numpy.random.Generator
    n_frames : int
    camera : gltrack.camera.Camera, optional (:func:`default_depth_camera`)
    noise : float, metres, Gaussian depth noise on valid pixels
    dropout : float, fraction of valid pixels set invalid (ToF sensors lose pixels)
    skeleton : Skeleton, optional (``default_skeleton()``)
    lod : int, mesh level of detail

    Returns
    -------
    list of :class:`gltrack.evidence.parts.TrainingFrame`
    """
    from gltrack.render.reference import render_candidates

    sk = skeleton or default_skeleton()
    dofs = make_dofs(sk, "full")
    kin = Kinematics(sk, dofs)
    mesh = make_body_mesh(sk, lod=lod)
    cam = camera or default_depth_camera()
    X = random_poses(rng, sk, dofs, int(n_frames))
    parts = PartModel(kin).positions(X)
    S = kin.skinning_matrices(X, dtype=np.float64)
    frames = []
    for i in range(len(X)):
        z = render_candidates(mesh, S[i:i + 1], cam.K, cam.R, cam.t, cam.width, cam.height)[0][0]
        valid = z > 0
        z[valid] += rng.normal(0.0, noise, int(valid.sum()))
        z[valid & (rng.random(z.shape) < dropout)] = 0.0
        frames.append(TrainingFrame(z.astype(np.float32), cam, parts[i]))
    return frames
