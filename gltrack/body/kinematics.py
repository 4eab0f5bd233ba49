"""Batched forward kinematics in numpy: N poses -> N x B world bone transforms.

Local rotations are composed for all poses and joints in one pass (three elementary rotations per
joint, a locked axis turning by 0); the chain is then one batched 3x3 product per tree depth. The
cost of a call is mostly numpy's per-call overhead at the 10-70 poses a hill climb scores at a
time (0.16 ms for 15 poses of the full model on a 2-core machine), and 10,000 poses take about
55 ms (``gltrack bench engine`` reports it). :meth:`Kinematics.chain_points` composes one bone's
chain alone, for inverse kinematics.
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
    shape = angles.shape[:-1]
    a = np.moveaxis(angles.reshape(-1, 3), -1, 0)  # (3, M): contiguous rows per axis
    c, s = np.cos(a), np.sin(a)
    M = a.shape[1]
    R = np.zeros((3, 3, M))
    R[0, 0] = R[1, 1] = R[2, 2] = 1.0
    # Left-multiply by one elementary rotation at a time, last letter first: an elementary rotation
    # about axis k only mixes rows i and j, which is far cheaper than a batched 3x3 product.
    for letter in reversed(order.upper()):
        k = "XYZ".index(letter)
        i, j = [(1, 2), (2, 0), (0, 1)][k]
        ri = R[i].copy()
        R[i] = c[k] * ri - s[k] * R[j]
        R[j] = s[k] * ri + c[k] * R[j]
    return np.moveaxis(R, -1, 0).reshape(shape + (3, 3))


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
        rot = dofs.slot >= 0
        self._rot_idx = np.nonzero(rot)[0]
        self._rot_joint = dofs.joint[rot]
        self._rot_axis = dofs.axis[rot]
        # Local rotations are composed for every joint in one pass: each joint's Euler order has
        # three letters, a locked axis taking angle 0 (its elementary rotation is then the
        # identity). Angles are gathered from the parameters with a zero column appended (column
        # D); an elementary rotation about axis k mixes rows (i, j) of the product so far.
        D = dofs.size
        cols = np.full((B, 3), D, dtype=np.int64)
        rows = np.zeros((2, B, 3), dtype=np.int64)
        for j in range(B):
            for li, letter in enumerate(skeleton.orders[j].upper()):
                k = "XYZ".index(letter)
                rows[:, j, li] = [(1, 2), (2, 0), (0, 1)][k]
                hit = np.nonzero((self._rot_joint == j) & (self._rot_axis == k))[0]
                if hit.size:
                    cols[j, li] = self._rot_idx[hit[0]]
        self._slot_cols = cols
        self._slot_rows = rows
        self._tables: dict = {}  # joint subset -> _slot_tables' result
        self.rest = skeleton.rest_positions()
        # Joints by depth in the tree: FK composes all joints of one depth at once (a handful of
        # numpy calls per depth instead of per joint; a hill climb calls FK ~150 times a frame
        # on ~15 poses, where the per-call overhead is the cost)
        depth = np.zeros(B, dtype=int)
        for j in range(1, B):
            depth[j] = depth[skeleton.parents[j]] + 1
        self._depths = []
        for k in range(1, int(depth.max(initial=0)) + 1):
            js = np.nonzero(depth == k)[0]
            self._depths.append((js, skeleton.parents[js], skeleton.offsets[js][:, :, None]))

    def angles(self, params: np.ndarray) -> np.ndarray:
        """(N, B, 3) Euler angles about x, y, z for every joint (zeros for locked DOFs)."""
        N = params.shape[0]
        ang = np.zeros((N, self.skeleton.n_joints, 3))
        ang[:, self._rot_joint, self._rot_axis] = params[:, self._rot_idx]
        return ang

    def local_rotations(self, params: np.ndarray, joints=None) -> np.ndarray:
        """(N, B, 3, 3) local joint rotations (identity for joints without free DOFs).

        Parameters
        ----------
        params : (N, D) float, radians for the rotational DOFs (not clamped here)
        joints : (J,) int, optional
            Only these joints: the result is then (N, J, 3, 3).
        """
        # Left-multiply by one elementary rotation per Euler slot, last letter first, for every
        # joint at once: a fixed handful of numpy calls for any skeleton and DOF preset, which is
        # what a hill climb's ~15-pose calls pay for (the work itself is tiny).
        cols, steps = self._slot_tables(None if joints is None else tuple(int(j) for j in joints))
        N, J = params.shape[0], cols.shape[0]
        # poses last, so that every gather and scatter below moves whole rows of N values
        a = np.concatenate([params, np.zeros((N, 1))], axis=1).T[cols]  # (J, 3, N)
        c, s = np.cos(a)[:, :, None], np.sin(a)[:, :, None]
        R = np.zeros((J * 9, N))  # row r of joint j at 9 j + 3 r + (0, 1, 2)
        R[9 * np.arange(J)[:, None] + 4 * np.arange(3)] = 1.0  # the diagonals
        for li, i, j in steps:
            Ri, Rj = R[i], R[j]  # (J, 3, N) copies
            R[i] = c[:, li] * Ri - s[:, li] * Rj
            R[j] = s[:, li] * Ri + c[:, li] * Rj
        return R.T.reshape(N, J, 3, 3)

    def joint_table(self) -> dict:
        """What forward kinematics needs per joint, for a GPU twin (``shaders/fk.comp``).

        Returns
        -------
        dict of ``parents`` (B,) int (-1 for the root), ``cols`` (B, 3) int (the parameter column
        of each Euler slot, first letter first; ``D`` = a locked axis), ``axes`` (B, 3) int
        (0 = x, 1 = y, 2 = z), ``offsets`` (B, 3) and ``rest`` (B, 3) float, metres.
        """
        axes = np.array([["XYZ".index(ch) for ch in order.upper()] for order in self.skeleton.orders])
        return {"parents": np.asarray(self.skeleton.parents, dtype=np.int64), "cols": self._slot_cols.copy(),
                "axes": axes, "offsets": np.asarray(self.skeleton.offsets, dtype=np.float64),
                "rest": np.asarray(self.rest, dtype=np.float64)}

    def _slot_tables(self, joints: tuple | None):
        """Angle columns (J, 3) of ``joints`` (all when None) and, per Euler slot from the last
        letter to the first, the flat columns (J, 3) of the two rows its rotation mixes."""
        if joints not in self._tables:
            sel = slice(None) if joints is None else np.asarray(joints, dtype=np.int64)
            cols, ri, rj = self._slot_cols[sel], self._slot_rows[0][sel], self._slot_rows[1][sel]
            base = 9 * np.arange(cols.shape[0])[:, None] + np.arange(3)  # (J, 3)
            steps = [(li, base + 3 * ri[:, li, None], base + 3 * rj[:, li, None])
                     for li in (2, 1, 0)]
            self._tables[joints] = (cols, steps)
        return self._tables[joints]

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
        for js, ps, o in self._depths:
            Rp = Rw[:, ps]  # (N, J, 3, 3) the parents' world rotations
            Rw[:, js] = Rp @ local[:, js]
            # R @ offset as three scaled columns: cheaper than a batched matrix-vector product.
            Tw[:, js] = Tw[:, ps] + Rp[..., 0] * o[:, 0] + Rp[..., 1] * o[:, 1] + \
                Rp[..., 2] * o[:, 2]
        return Pose(Rw, Tw)

    def chain_points(self, params, bone: int, local: np.ndarray, *, clamp: bool = True) -> np.ndarray:
        """World positions of points on one bone, from the joints of its chain alone.

        The same numbers as ``transform_points(forward(params), ...)`` for that bone, at a
        fraction of the cost: only the bone's ancestors are composed (a hand: 7 of 19 joints).
        Inverse kinematics calls this on a few sigma points at a time, hundreds of times a frame.

        Parameters
        ----------
        params : (N, D) or (D,) float
        bone : int, the bone the points are attached to
        local : (M, 3) float, point positions relative to the bone's joint, in the rest frame
        clamp : bool, clamp to joint limits first (as :meth:`forward`)

        Returns
        -------
        (N, M, 3) float64, metres
        """
        p = self.dofs.validate(params, clamp=clamp)
        chain = self._chain(int(bone))
        L = self.local_rotations(p, joints=chain)
        off = self.skeleton.offsets
        R, T = L[:, 0], p[:, :3]
        for k in range(1, len(chain)):
            T = T + R @ off[chain[k]]
            R = R @ L[:, k]
        return T[:, None] + np.einsum("nij,mj->nmi", R, np.asarray(local, dtype=np.float64))

    def _chain(self, bone: int) -> tuple:
        """The joints from the root to ``bone`` (inclusive), root first."""
        chain = [bone]
        while chain[-1] != 0:
            chain.append(int(self.skeleton.parents[chain[-1]]))
        return tuple(reversed(chain))

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
        r = self.rest
        S[..., 3] = T - (R[..., 0] * r[:, 0, None] + R[..., 1] * r[:, 1, None] + R[..., 2] * r[:, 2, None])
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
