"""The five body parts that evidence propagation reasons about, and their classes.

Ganapathi et al. (2010) represent head, hands and feet by one surface point each, a
deterministic function of the pose. Here that point is the segment tip from the skeleton's end
sites (head top, hand tip, toe tip): where a geodesic extremum of the measured surface lands.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

log = logging.getLogger(__name__)

#: Detector classes; index 0 is the rejection class.
CLASSES = ("none", "head", "hand", "foot")
#: Body parts, the bone that carries each part's point, and each part's class.
PART_NAMES = ("head", "l_hand", "r_hand", "l_foot", "r_foot")
PART_BONES = ("head", "l_wrist", "r_wrist", "l_ankle", "r_ankle")
PART_CLASSES = {"head": "head", "l_hand": "hand", "r_hand": "hand", "l_foot": "foot",
                "r_foot": "foot"}


@dataclass
class Detections:
    """Classified part detections of one frame.

    Attributes
    ----------
    points : (J, 3) float64, world positions, metres
    classes : tuple of str, (J,), each in :data:`CLASSES` minus ``"none"``
    confidence : (J,) float64, classifier probability of the class
    pixels : (J, 2) float64, (u, v) image coordinates, pixels
    """

    points: np.ndarray
    classes: tuple
    confidence: np.ndarray = field(default=None)
    pixels: np.ndarray = field(default=None)

    def __post_init__(self):
        self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        self.classes = tuple(str(c) for c in self.classes)
        J = len(self.points)
        if len(self.classes) != J:
            raise ValueError(f"detections: {J} points but {len(self.classes)} classes")
        self.confidence = (np.ones(J) if self.confidence is None
                           else np.asarray(self.confidence, dtype=np.float64).reshape(J))
        self.pixels = (np.full((J, 2), np.nan) if self.pixels is None
                       else np.asarray(self.pixels, dtype=np.float64).reshape(J, 2))

    def __len__(self) -> int:
        return len(self.points)


def part_points(skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Bones and bone-local offsets of the part points (segment tips).

    Returns
    -------
    bone : (5,) int, skeleton bone of each part in :data:`PART_NAMES` order
    local : (5, 3) float64, metres, offset from the bone's joint in its rest frame
    """
    from gltrack.body.mesh import _end_vector, _stature

    P = skeleton.rest_positions()
    H = _stature(skeleton)
    bone = np.array([skeleton.index(b) for b in PART_BONES])
    local = np.array([_end_vector(skeleton, P, b, H) for b in PART_BONES])
    return bone, local


class PartModel:
    """World positions of the five part points for batches of poses.

    Parameters
    ----------
    kin : gltrack.body.kinematics.Kinematics
    """

    def __init__(self, kin):
        self.kin = kin
        self.bone, self.local = part_points(kin.skeleton)

    def positions(self, X) -> np.ndarray:
        """(N, 5, 3) float64 part positions (metres) of poses ``X`` (N, D) or (D,)."""
        pose = self.kin.forward(np.atleast_2d(X))
        return self.kin.transform_points(pose, self.bone, self.local)

    def part_fn(self, name: str):
        """``X (N, D) -> (N, 3)`` position of part ``name`` (see :data:`PART_NAMES`)."""
        if name not in PART_NAMES:
            raise KeyError(f"unknown part {name!r}; parts are {', '.join(PART_NAMES)}")
        i = PART_NAMES.index(name)
        bone, local = self.bone[i:i + 1], self.local[i:i + 1]

        def fn(X):
            return self.kin.chain_points(np.atleast_2d(X), int(bone[0]), local)[:, 0]

        return fn

    def part_fns(self) -> dict:
        """Every part's function, keyed by :data:`PART_NAMES`."""
        return {n: self.part_fn(n) for n in PART_NAMES}


class TrainingFrame(NamedTuple):
    """One depth frame with ground truth.

    Training and test data of the part classifier (:mod:`gltrack.evidence.classifier`).

    Attributes
    ----------
    depth : (H, W) float, metres, 0 = invalid
    camera : gltrack.camera.Camera
    parts : (5, 3) float, world positions of :data:`PART_NAMES`, metres (NaN = unknown)
    mask : (H, W) bool or None, foreground
    background : (H, W) float or None, empty-scene depth, metres
    """

    depth: np.ndarray
    camera: object
    parts: np.ndarray
    mask: np.ndarray | None = None
    background: np.ndarray | None = None


def parts_from_groundtruth(gt: dict, where: str = "groundtruth") -> tuple[np.ndarray, float]:
    """Part positions of every frame of a dataset's ground truth.

    Uses, in order of preference: a ``parts`` (N, 5, 3) array with ``part_names`` equal to
    :data:`PART_NAMES` (exact tips); the markers ``head_top``, ``l_hand``, ``r_hand``, ``l_toe``,
    ``r_toe``; the joints ``head``, ``l_wrist``, ``r_wrist``, ``l_ankle``, ``r_ankle``. The proxies
    sit several centimetres from the tips, so a larger labelling radius is returned with them.

    Parameters
    ----------
    gt : dict from :func:`gltrack.data.dataset.load_groundtruth`
    where : str, name for messages

    Returns
    -------
    parts : (N, 5, 3) float64, metres
    radius : float, metres, suggested labelling radius for these positions
    """
    if "parts" in gt:
        names = [str(s) for s in np.asarray(gt.get("part_names", PART_NAMES))]
        a = np.asarray(gt["parts"], dtype=np.float64)
        if a.ndim != 3 or a.shape[2] != 3 or a.shape[1] != len(names):
            raise ValueError(f"{where}: field 'parts' must be (N, {len(names)}, 3), got {a.shape}")
        missing = [n for n in PART_NAMES if n not in names]
        if missing:
            raise ValueError(f"{where}: field 'part_names' lacks {missing}")
        return a[:, [names.index(n) for n in PART_NAMES]], 0.10
    if "markers" in gt and "marker_names" in gt:
        want = ("head_top", "l_hand", "r_hand", "l_toe", "r_toe")
        names = list(gt["marker_names"])
        if all(w in names for w in want):
            return gt["markers"][:, [names.index(w) for w in want]], 0.16
    want = PART_BONES
    names = list(gt["joint_names"])
    missing = [w for w in want if w not in names]
    if missing:
        raise ValueError(f"{where}: field 'joint_names' lacks {missing} (and there are no "
                         "'parts' or head/hand/toe markers)")
    log.warning("%s: no part tips or markers; labelling with joint positions", where)
    return gt["joints"][:, [names.index(w) for w in want]], 0.22
