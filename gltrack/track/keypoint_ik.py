"""Limb proposals from the keypoints: each limb solved onto its keypoints by inverse kinematics.

The keypoint term of the multi-view weighting (``keypoints``) says how far a pose's joints are
from the triangulated keypoints, but a particle filter only weighs the poses it draws: a limb
the track has lost (an arm pointing the other way, the legs exchanged) lies far outside the
particles' diffusion, and the keypoints that would bring it back are never reached. This is
Ganapathi's evidence propagation carried to the multi-view tracker: after the sampler, each
limb whose elbow or wrist (knee or ankle) has a keypoint in this frame, and lies at least
:data:`NEAR` from it, is solved onto its keypoints by the project's unscented-transform IK
(:func:`gltrack.evidence.ik.ut_ik`) over its swing joint's and its middle joint's DOFs, from
three starts; the tracker weighs the solved limbs against the estimate and keeps those that
weigh more (:meth:`gltrack.track.multiview.MultiviewTracker.solve_limbs`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gltrack.evidence.ik import ut_ik

#: (swing joint, middle joint, end joint) of each limb: the DOFs of the first two move, the
#: middle and end joints' keypoints are the targets
LIMBS = {"l_arm": ("l_shoulder", "l_elbow", "l_wrist"),
         "r_arm": ("r_shoulder", "r_elbow", "r_wrist"),
         "l_leg": ("l_hip", "l_knee", "l_ankle"), "r_leg": ("r_hip", "r_knee", "r_ankle")}
#: radians: the prior spread of a limb DOF's change. Wide: the proposal is for a limb far from
#: where the track has it; the keypoints, not the estimate, are meant to place it
PRIOR_SIGMA = 1.0
#: metres: a keypoint's standard deviation (triangulated keypoints are 4-6 cm from hand labels)
KEYPOINT_SIGMA = 0.05
#: metres: a limb whose two joints are already this close to their keypoints (mean) gets no
#: proposal: there the particles' own search is finer than the keypoints
NEAR = 0.08


@dataclass(frozen=True)
class LimbProposal:
    """A limb of the estimate solved onto its keypoints.

    Attributes
    ----------
    limb : str, a key of :data:`LIMBS`
    pose : (D,) float, the estimate with the limb's DOFs replaced
    before, after : float, metres, the limb's mean joint distance to its keypoints (those it
        has in the frame)
    """

    limb: str
    pose: np.ndarray
    before: float
    after: float


def limb_targets(site_names) -> dict:
    """The limbs of :data:`LIMBS` whose middle and end joints are among ``site_names`` (the
    :class:`~gltrack.track.keypoint_sites.KeypointSites` names): limb -> (k_middle, k_end)
    indices into them."""
    names = list(site_names)
    return {limb: (names.index(mid), names.index(end))
            for limb, (_, mid, end) in LIMBS.items() if mid in names and end in names}


def propose_limbs(kin, x, targets, limbs: dict, *, near: float = NEAR) -> list[LimbProposal]:
    """Solve each limb of ``x`` that is off its keypoints onto them.

    Parameters
    ----------
    kin : gltrack.body.kinematics.Kinematics
    x : (D,) float, the estimate
    targets : (K, 3) float, metres, this frame's keypoints (NaN rows: none), in the order of
        the sites :func:`limb_targets` indexed
    limbs : dict from :func:`limb_targets`
    near : float, metres, see :data:`NEAR`

    Returns
    -------
    list of LimbProposal, one per limb with a keypoint of its middle or end joint (or both),
    whose joints are at least ``near`` from them (mean) and whose solution is closer to them
    than the estimate's limb. With the middle joint's keypoint alone only the swing joint's DOFs
    move; with the end joint's alone both joints' DOFs do, and the prior picks the bend
    """
    x = np.asarray(x, dtype=np.float64)
    skel, dofs = kin.skeleton, kin.dofs
    sigma = np.zeros(dofs.size)
    out = []
    for limb, (k_mid, k_end) in limbs.items():
        y = np.asarray(targets, dtype=np.float64)[[k_mid, k_end]]
        have = np.isfinite(y).all(axis=1)
        if not have.any():
            continue
        swing, mid, end = (skel.index(n) for n in LIMBS[limb])
        # with the middle joint's keypoint alone only the swing joint turns (the end is free)
        idx = np.concatenate([dofs.joint_dofs(swing)] + ([dofs.joint_dofs(mid)] if have[1]
                                                         else []))
        if idx.size == 0:  # a preset that fixes the limb (the legs of ``upper``)
            continue
        joints = [j for j, h in zip((mid, end), have) if h]
        y = y[have]

        def part(X, joints=joints):
            z = np.zeros((1, 3))
            return np.concatenate([kin.chain_points(X, j, z) for j in joints],
                                  axis=1).reshape(len(X), 3 * len(joints))

        before = float(np.linalg.norm(part(x[None]).reshape(-1, 3) - y, axis=1).mean())
        if before < near:
            continue
        s = sigma.copy()
        s[idx] = PRIOR_SIGMA
        best = None
        # the IK is local: from the estimate's limb, and from the rest pose's and the limits'
        # middle, so that a limb pointing the other way does not stay in its own basin
        for start in (x[idx], np.clip(0.0, dofs.lower[idx], dofs.upper[idx]),
                      0.5 * (dofs.lower[idx] + dofs.upper[idx])):
            x0 = x.copy()
            x0[idx] = start
            res = ut_ik(x0, part, y.ravel(), KEYPOINT_SIGMA ** 2, s, dofs=idx,
                        lower=dofs.lower, upper=dofs.upper)
            after = float(np.linalg.norm(res.residual.reshape(-1, 3), axis=1).mean())
            if best is None or after < best[1]:
                best = (res.x, after)
        if best[1] < before:
            out.append(LimbProposal(limb, best[0], before, best[1]))
    return out
