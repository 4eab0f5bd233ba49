"""Partitions of a DOF set by body part, built from the DOF names.

DOF names are ``<joint>_r<axis>`` or ``pelvis_t<axis>`` (see ``gltrack.body.dofs``), so the
partitions work for every preset without a skeleton. Indices within a partition keep the DOF
order, which is the kinematic (parent-before-child) order.
"""
from __future__ import annotations

from itertools import zip_longest

import numpy as np

#: Coarse partitions: torso first (it carries every limb), then the four limbs.
COARSE = {
    "torso": ("pelvis", "spine_lower", "spine_upper", "neck", "head"),
    "l_arm": ("l_clavicle", "l_shoulder", "l_elbow", "l_wrist"),
    "r_arm": ("r_clavicle", "r_shoulder", "r_elbow", "r_wrist"),
    "l_leg": ("l_hip", "l_knee", "l_ankle"),
    "r_leg": ("r_hip", "r_knee", "r_ankle"),
}

#: Fine partitions for partitioned sampling, in Bandouch's PS order (pose and lower torso,
#: upper torso, then each limb proximal segment before distal).
FINE = {
    "root": ("pelvis", "spine_lower"),
    "upper_torso": ("spine_upper", "neck", "head"),
    "l_thigh": ("l_hip",), "l_shin": ("l_knee", "l_ankle"),
    "r_thigh": ("r_hip",), "r_shin": ("r_knee", "r_ankle"),
    "l_upper_arm": ("l_clavicle", "l_shoulder"), "l_forearm": ("l_elbow", "l_wrist"),
    "r_upper_arm": ("r_clavicle", "r_shoulder"), "r_forearm": ("r_elbow", "r_wrist"),
}

LIMBS = ("l_arm", "r_arm", "l_leg", "r_leg")


def dof_joints(dofs) -> list[str]:
    """Joint name of each DOF of a ``DofSet`` (or any object with ``names``)."""
    return [str(n).rsplit("_", 1)[0] for n in dofs.names]


def _group(dofs, table: dict) -> dict[str, np.ndarray]:
    joints = dof_joints(dofs)
    owner = {j: part for part, js in table.items() for j in js}
    missing = sorted({j for j in joints if j not in owner})
    if missing:
        raise ValueError(f"DOFs of joints {missing} belong to no partition")
    parts = {part: np.array([i for i, j in enumerate(joints) if owner[j] == part], dtype=np.int64)
             for part in table}
    return {k: v for k, v in parts.items() if v.size}


def default_partitions(dofs) -> dict[str, np.ndarray]:
    """Torso and limb partitions: ``{"torso", "l_arm", "r_arm", "l_leg", "r_leg"}`` -> (K,) int
    DOF indices, in that order. Raises ``ValueError`` if a DOF's joint is not a canonical one."""
    return _group(dofs, COARSE)


def fine_partitions(dofs) -> dict[str, np.ndarray]:
    """The finer split for partitioned sampling (upper arm / forearm, thigh / shin, root /
    upper torso), in Bandouch's PS order; empty partitions (absent in a preset) are dropped."""
    return _group(dofs, FINE)


def hill_climb_order(dofs, *, group_limbs: bool = True) -> list:
    """DOF order for :func:`gltrack.sample.hillclimb.hill_climb`: base of the chain first.

    Torso DOFs come one at a time. With ``group_limbs`` the limb DOFs are then given as tuples
    ``(l_arm[i], r_arm[i], l_leg[i], r_leg[i])`` of the i-th DOF of each limb, which
    ``hill_climb(batch_independent=True)`` evaluates in one batch; otherwise each limb is
    walked to its end before the next.
    """
    parts = default_partitions(dofs)
    order: list = [int(i) for i in parts.get("torso", [])]
    limbs = [parts[k] for k in LIMBS if k in parts]
    if group_limbs:
        for row in zip_longest(*limbs):
            order.append(tuple(int(i) for i in row if i is not None))
    else:
        order.extend(int(i) for limb in limbs for i in limb)
    return order


def limb_pairs(dofs) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The legs, then the arms (where the preset has both sides), as ``(left, right, sign)``:
    the DOF indices of each side (in the same joint and axis order) and the sign each DOF's
    angle takes on the other side (+1 about x, -1 about y and z: a mirror image through the
    body's sagittal plane, whose normal is the body's x axis)."""
    parts = default_partitions(dofs)
    pairs = []
    for a, b in (("l_leg", "r_leg"), ("l_arm", "r_arm")):
        if a in parts and b in parts:
            left, right = parts[a], parts[b]
            sign = np.array([1.0 if dofs.names[i].endswith("_rx") else -1.0 for i in left])
            pairs.append((left, right, sign))
    return pairs


def exchange_limbs(x, pairs) -> np.ndarray:
    """Pose(s) ``x`` (D,) or (N, D) with each pair of :func:`limb_pairs` exchanged, mirrored:
    a stride with the left leg forward becomes one with the right leg forward. Not clamped."""
    x = np.asarray(x, dtype=np.float64)
    y = x.copy()
    for left, right, sign in pairs:
        y[..., left], y[..., right] = sign * x[..., right], sign * x[..., left]
    return y
