"""The points of a body that a dataset's triangulated keypoints mark.

The keypoints (``keypoints.npz``, :mod:`gltrack.observe.keypoints`) mark twelve joint centres
(:data:`~gltrack.observe.keypoints.BODY_JOINTS`) and, as landmarks or midpoints of two, points
that are no joint (:data:`~gltrack.observe.keypoints.SITE_LANDMARKS`): the head's centre, the
heels and the toe tips. The joints alone leave the head's and the feet's rotations to the
silhouettes, where they are small blobs; the sites pin them. Each site sits where the
procedural mesh draws it (:mod:`gltrack.body.mesh`: the head's centre
:data:`~gltrack.body.mesh.HEAD_CENTRE`, the foot's ends :func:`~gltrack.body.mesh.foot_ends`),
so it follows the skeleton's proportions.
"""
from __future__ import annotations

import logging

import numpy as np

from gltrack.body.mesh import HEAD_CENTRE, foot_ends, segment_tip
from gltrack.observe.keypoints import BODY_JOINTS, site_points

log = logging.getLogger(__name__)


def _on_tip(joint, fraction):
    return lambda skeleton: fraction * segment_tip(skeleton, joint)


def _foot_end(ankle, end):
    return lambda skeleton: foot_ends(skeleton, ankle)[end]


#: each site of :data:`~gltrack.observe.keypoints.SITE_LANDMARKS`: the joint it rides on and
#: its offset from that joint in the rest frame of a skeleton, (3,) metres
SITE_BONES = {"head": ("head", _on_tip("head", HEAD_CENTRE)),
              **{f"{s}_heel": (f"{s}_ankle", _foot_end(f"{s}_ankle", 0)) for s in "lr"},
              **{f"{s}_toe": (f"{s}_ankle", _foot_end(f"{s}_ankle", 1)) for s in "lr"}}


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
        self.bones = np.asarray([skeleton.index(SITE_BONES[n][0] if n in SITE_BONES else n)
                                 for n in self.names], dtype=np.int64)
        self._cached = (None, None)  # (skeleton, local offsets) of the last call

    def local(self, skeleton) -> np.ndarray:
        """(K, 3) metres: each point relative to its joint in the rest frame of ``skeleton``
        (zero for a joint centre)."""
        if self._cached[0] is skeleton:
            return self._cached[1]
        out = np.zeros((len(self.names), 3))
        for k, name in enumerate(self.names):
            if name in SITE_BONES:
                out[k] = SITE_BONES[name][1](skeleton)
        self._cached = (skeleton, out)
        return out

    def positions(self, kin, X) -> np.ndarray:
        """(N, K, 3) metres: the points of the poses ``X`` (N, D) of the body ``kin``
        (:class:`gltrack.body.kinematics.Kinematics`, joint limits clamped as
        :meth:`~gltrack.body.kinematics.Kinematics.forward` does)."""
        pose = kin.forward(np.atleast_2d(X))
        return kin.transform_points(pose, self.bones, self.local(kin.skeleton))


def keypoint_targets(dataset, body, opt, sites: bool = True):
    """The points of ``body`` the dataset's keypoints mark, and those keypoints frame by frame.

    A joint counts when the body has it (with ``--dof upper``, not the hidden knees and
    ankles); a site (:data:`SITE_BONES`) when ``sites`` is set and its joint turns in the body's
    DOF preset, since it is there to orient that joint (``upper`` and ``38`` fix the ankles).
    The body estimate's bone fit leaves the sites out (its start pose, the tracker's automatic
    start, has them): a site's offset from its joint is the mesh's, not the subject's, so it
    would measure bones by the mesh's proportions; a joint's keypoint marks the joint itself.

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
    matched = []
    if sites and len(kp["names"]) == 33:  # MediaPipe's landmarks, the sites' source
        for site, (joint, _) in SITE_BONES.items():
            if joint in names and body.dofs.joint_dofs(names.index(joint)).size:
                matched.append(site)
                points.append(site_points(kp["points"], site))
    if not joints and not matched:
        log.warning("the dataset's keypoints mark none of the body's joints; not used")
        return None, None
    log.info("keypoints: %d joints and %d sites (%s) matched with the dataset's triangulated "
             "keypoints", len(joints), len(matched), ", ".join(matched) or "none")
    return KeypointSites(joints + matched, body.skeleton), np.stack(points, axis=1)
