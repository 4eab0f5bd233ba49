"""A small library of canonical poses: where an automatic start begins its search.

A tracker that starts from nothing tries every pose of the library at many headings and
positions and keeps the ones that explain the first frame best, then refines them with its own
search. The library spans what people do when a recording starts: standing with the arms down,
at the sides or out (T-pose), reaching forward, mid-stride either way, standing on one leg and
sitting. Signs follow :mod:`gltrack.body.dofs` (the body faces +Z at rest, its left is +X): a
negative hip ``rx`` swings the leg forward, a positive knee ``rx`` bends it, a negative left /
positive right shoulder ``rz`` lowers the arm, a negative left / positive right shoulder ``ry``
brings it forward.
"""
from __future__ import annotations

import numpy as np

#: name -> {DOF name: radians}; DOFs a preset lacks are skipped
CANONICAL = {
    "t_pose": {},
    "arms_down": {"l_shoulder_rz": -1.3, "r_shoulder_rz": 1.3},
    "arms_low": {"l_shoulder_rz": -0.7, "r_shoulder_rz": 0.7},
    "arms_forward": {"l_shoulder_rz": -0.2, "r_shoulder_rz": 0.2, "l_shoulder_ry": -1.3,
                     "r_shoulder_ry": 1.3},
    "elbows_bent": {"l_shoulder_rz": -1.3, "r_shoulder_rz": 1.3, "l_elbow_ry": -1.5,
                    "r_elbow_ry": 1.5},
    "stride_left": {"l_shoulder_rz": -1.2, "r_shoulder_rz": 1.2, "l_hip_rx": -0.45,
                    "r_hip_rx": 0.35, "r_knee_rx": 0.3},
    "stride_right": {"l_shoulder_rz": -1.2, "r_shoulder_rz": 1.2, "r_hip_rx": -0.45,
                     "l_hip_rx": 0.35, "l_knee_rx": 0.3},
    "one_leg": {"l_shoulder_rz": -0.7, "r_shoulder_rz": 0.7, "l_hip_rx": -0.9,
                "l_knee_rx": 1.3},
    "seated": {"l_shoulder_rz": -1.2, "r_shoulder_rz": 1.2, "l_hip_rx": -1.5, "r_hip_rx": -1.5,
               "l_knee_rx": 1.5, "r_knee_rx": 1.5},
}


def canonical_poses(dofs, skeleton=None) -> tuple[list[str], np.ndarray]:
    """The library as poses of ``dofs``, each standing at the rest root position.

    Parameters
    ----------
    dofs : gltrack.body.dofs.DofSet
    skeleton : gltrack.body.skeleton.Skeleton, optional, sets the root's rest position

    Returns
    -------
    names : list of str, (K,)
    poses : (K, D) float64, within the joint limits; heading 0 (facing +Z)
    """
    names = list(CANONICAL)
    P = np.repeat(dofs.zero(skeleton)[None], len(names), axis=0)
    for k, name in enumerate(names):
        for dof, value in CANONICAL[name].items():
            if dof in dofs.names:
                P[k, dofs.index(dof)] = value
    return names, dofs.validate(P)
