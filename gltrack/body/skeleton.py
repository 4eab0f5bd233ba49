"""The kinematic tree of the gltrack body.

Conventions (metres, radians; world right-handed, +Y up). The subject faces +Z in the rest
pose, so the subject's *left* is +X. The rest pose is a T-pose (arms along +-X, legs along -Y) and
every bone's rest frame is axis-aligned with the world, as in BVH: a joint's rest world
position is the sum of its ancestors' offsets, and its local rotation is the identity at rest.

Every joint has a three-letter Euler order (e.g. ``"ZXY"`` means ``R = Rz @ Rx @ Ry``: the
*last* letter is applied first in the joint's frame). The order puts the bone's own axis (its
twist) last so that swing and twist limits stay meaningful: ``"ZYX"`` for the arms (bones along
X), ``"ZXY"`` for spine and legs (bones along Y). Which of the three angles are free is decided
by a DOF preset (``gltrack.body.dofs``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Joints of the canonical gltrack skeleton, parent before child.
JOINT_NAMES = (
    "pelvis", "spine_lower", "spine_upper", "neck", "head",
    "l_clavicle", "l_shoulder", "l_elbow", "l_wrist",
    "r_clavicle", "r_shoulder", "r_elbow", "r_wrist",
    "l_hip", "l_knee", "l_ankle",
    "r_hip", "r_knee", "r_ankle",
)
PARENTS = (
    -1, 0, 1, 2, 3,
    2, 5, 6, 7,
    2, 9, 10, 11,
    0, 13, 14,
    0, 16, 17,
)
EULER_ORDER = {
    "pelvis": "YXZ",  # heading first: yaw about +Y, then pitch, then roll
    "spine_lower": "ZXY", "spine_upper": "ZXY", "neck": "ZXY", "head": "ZXY",
    "l_clavicle": "ZYX", "l_shoulder": "ZYX", "l_elbow": "ZYX", "l_wrist": "ZYX",
    "r_clavicle": "ZYX", "r_shoulder": "ZYX", "r_elbow": "ZYX", "r_wrist": "ZYX",
    "l_hip": "ZXY", "l_knee": "ZXY", "l_ankle": "ZXY",
    "r_hip": "ZXY", "r_knee": "ZXY", "r_ankle": "ZXY",
}


@dataclass(frozen=True)
class Skeleton:
    """A kinematic tree with BVH-style offsets.

    Attributes
    ----------
    names : tuple of str, (B,)
    parents : (B,) int array, -1 for the root; ``parents[j] < j``.
    offsets : (B, 3) float64, metres
        Joint position relative to its parent joint in the (axis-aligned) rest frame; for the
        root, its rest world position.
    ends : (B, 3) float64, metres
        Tip of each bone that has no child carrying the segment (head top, hand tip, toe),
        relative to the joint; zeros where the segment ends at a child joint.
    orders : tuple of str, (B,)
        Euler order of each joint (see module docstring).
    """

    names: tuple
    parents: np.ndarray
    offsets: np.ndarray
    ends: np.ndarray
    orders: tuple
    _index: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self):
        parents = np.asarray(self.parents, dtype=np.int64)
        offsets = np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3)
        ends = np.asarray(self.ends, dtype=np.float64).reshape(-1, 3)
        n = len(self.names)
        if parents.shape != (n,) or offsets.shape != (n, 3) or ends.shape != (n, 3):
            raise ValueError(f"skeleton arrays disagree: {n} names, parents {parents.shape}, "
                             f"offsets {offsets.shape}, ends {ends.shape}")
        if len(self.orders) != n:
            raise ValueError(f"skeleton needs {n} Euler orders, got {len(self.orders)}")
        if parents[0] != -1 or np.any(parents[1:] >= np.arange(1, n)) or np.any(parents[1:] < 0):
            raise ValueError("skeleton parents must be topologically sorted with one root at 0")
        if not np.all(np.isfinite(offsets)) or not np.all(np.isfinite(ends)):
            raise ValueError("skeleton offsets must be finite")
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "ends", ends)
        self._index.update({name: i for i, name in enumerate(self.names)})

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of joint ``name``; ``KeyError`` naming the known joints otherwise."""
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"unknown joint {name!r}; joints are {', '.join(self.names)}") from None

    def rest_positions(self) -> np.ndarray:
        """(B, 3) rest-pose world positions of the joints, metres."""
        pos = np.zeros((self.n_joints, 3))
        for j, p in enumerate(self.parents):
            pos[j] = self.offsets[j] if p < 0 else pos[p] + self.offsets[j]
        return pos

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.nonzero(self.parents == j)[0]]

    def with_offsets(self, offsets, ends=None) -> "Skeleton":
        """Same topology and orders, new bone geometry."""
        return Skeleton(self.names, self.parents, offsets,
                        self.ends if ends is None else ends, self.orders)

    def height(self) -> float:
        """Rest standing height (lowest foot tip to head top), metres."""
        pos = self.rest_positions()
        tips = pos + self.ends
        pts = np.concatenate([pos, tips])
        return float(pts[:, 1].max() - pts[:, 1].min())


def default_skeleton(height: float = 1.75, shoulder_width: float | None = None,
                     hip_width: float | None = None) -> Skeleton:
    """The canonical skeleton scaled from standing height by anthropometric ratios.

    Segment proportions follow Drillis & Contini / Winter's segment-length table (fractions of
    stature H): thigh 0.245 H, shank 0.246 H, upper arm 0.186 H, forearm 0.146 H, hand 0.108 H,
    ankle height 0.039 H, foot length 0.152 H, shoulder width 0.259 H, hip width 0.191 H.

    Parameters
    ----------
    height : float
        Standing height, metres (0.5 .. 2.5).
    shoulder_width, hip_width : float, optional
        Distances between the shoulder (hip) joint centres, metres; default from ``height``.
    """
    if not (0.5 <= height <= 2.5):
        raise ValueError(f"height must be within 0.5..2.5 m, got {height}")
    H = float(height)
    sw = 0.259 * H if shoulder_width is None else float(shoulder_width)
    hw = 0.191 * H * 0.55 if hip_width is None else float(hip_width)  # hip joint centres
    thigh, shank, ankle_h = 0.245 * H, 0.246 * H, 0.039 * H
    pelvis_y = thigh + shank + ankle_h + 0.03 * H  # hip joint sits a little below pelvis origin
    clav = 0.5 * sw - 0.03 * H
    off = {
        "pelvis": (0, pelvis_y, 0),
        "spine_lower": (0, 0.05 * H, 0),
        "spine_upper": (0, 0.12 * H, 0),
        "neck": (0, 0.10 * H, 0),
        "head": (0, 0.05 * H, 0),
        "l_clavicle": (0.03 * H, 0.09 * H, 0), "l_shoulder": (clav, 0, 0),
        "l_elbow": (0.186 * H, 0, 0), "l_wrist": (0.146 * H, 0, 0),
        "r_clavicle": (-0.03 * H, 0.09 * H, 0), "r_shoulder": (-clav, 0, 0),
        "r_elbow": (-0.186 * H, 0, 0), "r_wrist": (-0.146 * H, 0, 0),
        "l_hip": (0.5 * hw, -0.03 * H, 0), "l_knee": (0, -thigh, 0), "l_ankle": (0, -shank, 0),
        "r_hip": (-0.5 * hw, -0.03 * H, 0), "r_knee": (0, -thigh, 0), "r_ankle": (0, -shank, 0),
    }
    ends = {
        "head": (0, 0.12 * H, 0.0),
        "l_wrist": (0.108 * H, 0, 0), "r_wrist": (-0.108 * H, 0, 0),
        "l_ankle": (0, -ankle_h, 0.11 * H), "r_ankle": (0, -ankle_h, 0.11 * H),
    }
    offsets = np.array([off[n] for n in JOINT_NAMES], dtype=np.float64)
    end_arr = np.array([ends.get(n, (0, 0, 0)) for n in JOINT_NAMES], dtype=np.float64)
    return Skeleton(JOINT_NAMES, np.array(PARENTS), offsets, end_arr,
                    tuple(EULER_ORDER[n] for n in JOINT_NAMES))
