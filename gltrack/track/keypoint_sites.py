"""The points of a body that a dataset's triangulated keypoints mark.

The keypoints (``keypoints.npz``, :mod:`gltrack.observe.keypoints`) mark twelve joint centres
(:data:`~gltrack.observe.keypoints.BODY_JOINTS`) and, as midpoints of two landmarks, three
points that are no joint (:data:`~gltrack.observe.keypoints.SITE_LANDMARKS`): the head's centre
and the two hands' knuckles. The joints alone leave the head's and the hands' rotations to the
silhouettes, where a head is a small blob; the sites pin them. Each site sits where the
procedural mesh draws it, a fraction of its segment's tip vector from the joint
(:data:`gltrack.body.mesh.HEAD_CENTRE`, :data:`gltrack.body.mesh.KNUCKLES`), so it follows the
skeleton's proportions (the body estimate scores many skeletons with one set of sites).
"""
from __future__ import annotations

import logging

import numpy as np

from gltrack.body.mesh import HEAD_CENTRE, KNUCKLES, segment_tip
from gltrack.observe.keypoints import BODY_JOINTS, SITE_LANDMARKS, site_points

log = logging.getLogger(__name__)

#: each site of :data:`~gltrack.observe.keypoints.SITE_LANDMARKS`: the joint it rides on and
#: the fraction of that joint's tip vector where it sits
SITE_BONES = {"head": ("head", HEAD_CENTRE), "l_hand": ("l_wrist", KNUCKLES),
              "r_hand": ("r_wrist", KNUCKLES)}


class KeypointSites:
    """The K points of a body that keypoints mark: joint centres and sites on segments.

    Parameters
    ----------
    names : sequence (K) of str, a joint's name or a key of :data:`SITE_BONES`
    skeleton : Skeleton, whose joint indices the names resolve to

    Attributes
    ----------
    names : tuple (K) of str
    bones : (K,) int, the joint each point rides on
    """

    def __init__(self, names, skeleton):
        self.names = tuple(names)
        bones, fractions, tips = [], [], []
        for n in self.names:
            joint, frac = SITE_BONES.get(n, (n, 0.0))
            bones.append(skeleton.index(joint))
            fractions.append(frac)
            tips.append(joint)
        self.bones = np.asarray(bones, dtype=np.int64)
        self._fractions = np.asarray(fractions, dtype=np.float64)
        self._tips = tuple(tips)
        self._cached = (None, None)  # (skeleton, local offsets) of the last call

    def local(self, skeleton) -> np.ndarray:
        """(K, 3) metres: each point relative to its joint in the rest frame of ``skeleton``
        (zero for a joint centre)."""
        if self._cached[0] is skeleton:
            return self._cached[1]
        out = np.zeros((len(self.names), 3))
        for k, frac in enumerate(self._fractions):
            if frac:
                out[k] = frac * segment_tip(skeleton, self._tips[k])
        self._cached = (skeleton, out)
        return out

    def positions(self, kin, X) -> np.ndarray:
        """(N, K, 3) metres: the points of the poses ``X`` (N, D) of the body ``kin``
        (:class:`gltrack.body.kinematics.Kinematics`, joint limits clamped as
        :meth:`~gltrack.body.kinematics.Kinematics.forward` does)."""
        pose = kin.forward(np.atleast_2d(X))
        return kin.transform_points(pose, self.bones, self.local(kin.skeleton))


def keypoint_targets(dataset, body, opt):
    """The points of ``body`` the dataset's keypoints mark, and those keypoints frame by frame.

    A joint counts when the body has it (with ``--dof upper``, not the hidden knees and
    ankles); a site (:data:`SITE_BONES`) when its joint turns in the body's DOF preset, since
    it is there to orient that joint.

    Returns
    -------
    sites : KeypointSites (K points), or None
    points : (F, K, 3) float64 metres (internal frame; NaN where not triangulated), or None
        when the option ``opt.keypoints`` is off, the dataset has no keypoints or none matches
    """
    kp = dataset.keypoints() if opt.keypoints else None
    if kp is None:
        return None, None
    names = body.skeleton.names
    tracked = [n for n in BODY_JOINTS
               if body.dofs.preset != "upper" or n.split("_", 1)[1] not in ("knee", "ankle")]
    joints = [n for n in tracked if n in names and n in kp["names"]]
    points = [kp["points"][:, kp["names"].index(n)] for n in joints]
    sites = []
    if len(kp["names"]) == 33:  # MediaPipe's landmarks, of which the sites are midpoints
        for site, (joint, _) in SITE_BONES.items():
            if joint in names and body.dofs.joint_dofs(names.index(joint)).size:
                sites.append(site)
                points.append(site_points(kp["points"], site))
    if not joints and not sites:
        log.warning("the dataset's keypoints mark none of the body's joints; not used")
        return None, None
    log.info("keypoints: %d joints and %d sites (%s) matched with the dataset's triangulated "
             "keypoints", len(joints), len(sites), ", ".join(sites) or "none")
    return KeypointSites(joints + sites, body.skeleton), np.stack(points, axis=1)
