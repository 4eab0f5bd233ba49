"""Batched forward kinematics in numpy: N poses -> N x B world bone transforms.

The loop runs over *depth levels* of the tree (7 for the canonical skeleton), not over joints,
so each level is one batched 3x3 product over all poses and all joints at that depth.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dofs import DofSet
from .skeleton import Skeleton


def euler_to_matrix(angles: np.ndarray, order: str) -> np.ndarray:
    """Rotation matrices from Euler angles.

    Parameters
    ----------
    angles : (..., 3) float, radians
        Angles about x, y, z (in that storage order, whatever ``order`` is).
    order : str
        Three letters, e.g. ``"ZXY"``: ``R = Rz @ Rx @ Ry`` (intrinsic; last letter applied first).

    Returns
    -------
    (..., 3, 3) float64
    """
    angles = np.asarray(angles, dtype=np.float64)
    c, s = np.cos(angles), np.sin(angles)
    shape = angles.shape[:-1]
    R = None
    for letter in order.upper():
        k = "XYZ".index(letter)
        E = np.zeros(shape + (3, 3))
        i, j = [(1, 2), (2, 0), (0, 1)][k]
        E[..., k, k] = 1.0
        E[..., i, i] = c[..., k]
        E[..., j, j] = c[..., k]
        E[..., i, j] = -s[..., k]
        E[..., j, i] = s[..., k]
        R = E if R is None else R @ E
    return R


def matrix_to_euler(R: np.ndarray, order: str) -> np.ndarray:
    """Inverse of :func:`euler_to_matrix`: (..., 3, 3) -> (..., 3) angles about x, y, z."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=np.float64)
    flat = R.reshape(-1, 3, 3)
    ang = Rotation.from_matrix(flat).as_euler(order.upper(), degrees=False)  # intrinsic
    out = np.zeros_like(ang)
    for col, letter in enumerate(order.upper()):
        out[:, "XYZ".index(letter)] = ang[:, col]
    return out.reshape(R.shape[:-2] + (3,))


@dataclass
class Pose:
    """Forward-kinematics result for N poses.

    Attributes
    ----------
    rotations : (N, B, 3, 3) float64, world rotation of each bone frame
    positions : (N, B, 3) float64, metres, world position of each joint
    """

    rotations: np.ndarray
    positions: np.ndarray


class Kinematics:
    """Batched FK for one skeleton and DOF set.

    Parameters
    ----------
    skeleton : Skeleton
    dofs : DofSet
    """

    def __init__(self, skeleton: Skeleton, dofs: DofSet):
        self.skeleton = skeleton
        self.dofs = dofs
        B = skeleton.n_joints
        depth = np.zeros(B, dtype=int)
        for j in range(1, B):
            depth[j] = depth[skeleton.parents[j]] + 1
        self._levels = [np.nonzero(depth == d)[0] for d in range(1, depth.max() + 1)]
        rot = dofs.slot >= 0
        self._rot_idx = np.nonzero(rot)[0]
        self._rot_joint = dofs.joint[rot]
        self._rot_axis = dofs.axis[rot]
        self._orders = sorted(set(skeleton.orders))
        self._order_joints = {o: np.array([j for j in range(B) if skeleton.orders[j] == o])
                              for o in self._orders}
        self.rest = skeleton.rest_positions()

    def angles(self, params: np.ndarray) -> np.ndarray:
        """(N, B, 3) Euler angles about x, y, z for every joint (zeros for locked DOFs)."""
        N = params.shape[0]
        ang = np.zeros((N, self.skeleton.n_joints, 3))
        ang[:, self._rot_joint, self._rot_axis] = params[:, self._rot_idx]
        return ang

    def local_rotations(self, params: np.ndarray) -> np.ndarray:
        """(N, B, 3, 3) local joint rotations."""
        ang = self.angles(params)
        N, B = ang.shape[:2]
        R = np.empty((N, B, 3, 3))
        for order, joints in self._order_joints.items():
            R[:, joints] = euler_to_matrix(ang[:, joints], order)
        return R

    def forward(self, params, *, clamp: bool = True) -> Pose:
        """World bone rotations and joint positions for N poses.

        Parameters
        ----------
        params : (N, D) or (D,) float
        clamp : bool
            Clamp to joint limits first (see :meth:`DofSet.validate`).
        """
        p = self.dofs.validate(params, clamp=clamp)
        local = self.local_rotations(p)
        N, B = local.shape[:2]
        Rw = np.empty_like(local)
        Tw = np.empty((N, B, 3))
        Rw[:, 0] = local[:, 0]
        Tw[:, 0] = p[:, :3]
        off = self.skeleton.offsets
        par = self.skeleton.parents
        for joints in self._levels:
            pj = par[joints]
            Rp = Rw[:, pj]
            Rw[:, joints] = Rp @ local[:, joints]
            Tw[:, joints] = Tw[:, pj] + np.einsum("nbij,bj->nbi", Rp, off[joints])
        return Pose(Rw, Tw)

    def skinning_matrices(self, params=None, *, pose: Pose | None = None,
                          dtype=np.float32) -> np.ndarray:
        """(N, B, 3, 4) linear-blend-skinning matrices (top three rows of W_j @ inv(Bind_j)).

        Bind_j is a pure translation to the joint's rest position (rest frames are world-aligned),
        so ``S_j = [R_j | t_j - R_j @ rest_j]``. A rest-pose vertex v maps to ``S_j @ [v, 1]``.
        """
        if pose is None:
            pose = self.forward(params)
        R, T = pose.rotations, pose.positions
        S = np.empty(R.shape[:2] + (3, 4), dtype=dtype)
        S[..., :3] = R
        S[..., 3] = T - np.einsum("nbij,bj->nbi", R, self.rest)
        return S

    def transform_points(self, pose: Pose, bone: np.ndarray, local: np.ndarray) -> np.ndarray:
        """World positions of points rigidly attached to bones.

        Parameters
        ----------
        pose : Pose for N poses
        bone : (M,) int, bone of each point
        local : (M, 3) float, point position relative to its bone's joint, in the rest frame

        Returns
        -------
        (N, M, 3) float64, metres
        """
        R = pose.rotations[:, bone]
        return pose.positions[:, bone] + np.einsum("nmij,mj->nmi", R, local)
