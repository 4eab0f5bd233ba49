"""Measurements of a skeleton: canonical segment lengths and the error of an estimated body.

:func:`body_error` compares a body estimated from the observations
(:mod:`gltrack.track.body_estimate`) with a true skeleton (a synthetic dataset's ``meta.json``
record); ``gltrack eval`` reports it.
"""
from __future__ import annotations

import numpy as np

from .skeleton import Skeleton



def _mid(pos, a, b):
    return 0.5 * (pos[a] + pos[b])


#: The segments :func:`body_error` compares: name -> function of (rest joint positions by name,
#: rest segment tips by name) giving the segment's two end points. Limb bones per side, the
#: hand and foot (joint to end site), the two widths, the trunk (hip-joint midpoint to
#: shoulder-joint midpoint) and head-and-neck (shoulder-joint midpoint to head top). The spine's
#: inner joints (lower / upper spine, neck, head joint) are left out: where a skeleton puts them
#: is a convention of its mocap file that no surface shows.
CANONICAL_BONES = {
    **{f"{s}_{name}": (lambda P, T, s=s, a=a, b=b: (P[f"{s}_{a}"], P[f"{s}_{b}"]))
       for s in "lr" for name, a, b in (("upper_arm", "shoulder", "elbow"),
                                        ("forearm", "elbow", "wrist"),
                                        ("thigh", "hip", "knee"), ("shank", "knee", "ankle"))},
    **{f"{s}_{name}": (lambda P, T, s=s, j=j: (P[f"{s}_{j}"], T[f"{s}_{j}"]))
       for s in "lr" for name, j in (("hand", "wrist"), ("foot", "ankle"))},
    "shoulder_width": lambda P, T: (P["l_shoulder"], P["r_shoulder"]),
    "hip_width": lambda P, T: (P["l_hip"], P["r_hip"]),
    "trunk": lambda P, T: (_mid(P, "l_hip", "r_hip"), _mid(P, "l_shoulder", "r_shoulder")),
    "head_neck": lambda P, T: (_mid(P, "l_shoulder", "r_shoulder"), T["head"]),
}


def bone_lengths(skeleton: Skeleton) -> dict:
    """Lengths of the :data:`CANONICAL_BONES` of ``skeleton`` in its rest pose, metres.

    ``head_neck`` is the vertical distance (shoulder line to head top); the others are
    Euclidean distances between the segment's end points.
    """
    pos = skeleton.rest_positions()
    P = {n: pos[i] for i, n in enumerate(skeleton.names)}
    T = {n: pos[i] + skeleton.ends[i] for i, n in enumerate(skeleton.names)}
    out = {}
    for name, ends in CANONICAL_BONES.items():
        a, b = ends(P, T)
        out[name] = float(abs(b[1] - a[1]) if name == "head_neck" else np.linalg.norm(b - a))
    return out


def body_error(estimated: Skeleton, true: Skeleton) -> dict:
    """How far an estimated skeleton is from the true one.

    Parameters
    ----------
    estimated, true : Skeleton
        With the canonical joint names (``true`` may come from any mocap file retargeted to
        them, e.g. a synthetic dataset's ``meta.json`` body record).

    Returns
    -------
    dict
        ``mean_bone_mm``, ``max_bone_mm``: mean and largest absolute length error over the
        :data:`CANONICAL_BONES` (millimetres); ``worst_bone``: its name; ``height_mm``: signed
        stature error, estimated minus true (millimetres, :meth:`Skeleton.height`);
        ``bones_mm``: {bone: signed error, mm}.
    """
    e, t = bone_lengths(estimated), bone_lengths(true)
    err = {k: 1000.0 * (e[k] - t[k]) for k in CANONICAL_BONES}
    worst = max(err, key=lambda k: abs(err[k]))
    return {"mean_bone_mm": float(np.mean(np.abs(list(err.values())))),
            "max_bone_mm": float(abs(err[worst])), "worst_bone": worst,
            "height_mm": 1000.0 * (estimated.height() - true.height()), "bones_mm": err}


#: How far the procedural foot's heel reaches behind the ankle, as a fraction of the ankle's
#: horizontal reach to the toe tip (:func:`gltrack.body.mesh._foot_segment` builds it so).
HEEL_BEHIND = 0.28


def lowest_sole(kin, params) -> np.ndarray:
    """Height (world y, metres) of the lowest sole point of each pose: the toe tips and the
    heels of both feet, as the procedural foot places them (the toe tip at the ankle's end
    site, the heel at the sole's height :data:`HEEL_BEHIND` of the foot behind the ankle).

    Parameters
    ----------
    kin : gltrack.body.kinematics.Kinematics
    params : (N, D) or (D,) float, poses

    Returns
    -------
    (N,) float64, metres
    """
    sk = kin.skeleton
    bones, local = [], []
    for name in ("l_ankle", "r_ankle"):
        j = sk.index(name)
        toe = np.asarray(sk.ends[j], dtype=np.float64)
        heel = toe * np.array([-HEEL_BEHIND, 1.0, -HEEL_BEHIND])
        bones += [j, j]
        local += [toe, heel]
    pts = kin.transform_points(kin.forward(params), np.array(bones), np.array(local))
    return pts[..., 1].min(axis=1)
