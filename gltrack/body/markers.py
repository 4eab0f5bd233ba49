"""Surface markers rigidly attached to bones, and the joint subset used for joint-error metrics.

A marker is a point on the skin at a well-defined anatomical spot (loosely following the Vicon
Plug-in Gait set). Each is placed where a ray from an interior anatomical anchor (a joint, or a
point between joints) in a fixed rest-pose direction leaves the body: the outermost surface
crossing within reach, so the point lies on the mesh whichever mesh (procedural or loaded) is
used. After placement a marker moves rigidly with its bone.

Default markers (23; ``l_``/``r_`` pairs mirror in x; rest pose faces +Z, left is +X):

=============  ============  ==============================================================
name           bone          spot
=============  ============  ==============================================================
head_top       head          vertex: from mid-head along the head's end vector
head_front     head          forehead: from mid-head towards +Z
neck_back      spine_upper   C7: from the neck joint towards -Z
sternum        spine_upper   from mid-chest towards +Z
sacrum         pelvis        from between pelvis and spine_lower towards -Z
?_shoulder     ?_clavicle    acromion: from the shoulder joint upwards (+Y)
?_elbow        ?_shoulder    lateral epicondyle (faces up in a palms-down T-pose): elbow, +Y
?_wrist        ?_elbow       dorsal wrist: from the wrist joint upwards (+Y)
?_hand         ?_wrist       back of the hand: mid-hand upwards (+Y)
?_hip          pelvis        ASIS: above the hip joint, forwards and slightly lateral
?_knee         ?_hip         lateral femoral epicondyle: from the knee joint laterally
?_ankle        ?_knee        lateral malleolus: from the ankle joint laterally
?_heel         ?_ankle       calcaneus: low behind the ankle, backwards
?_toe          ?_ankle       second metatarsal head: three quarters to the toe, upwards
=============  ============  ==============================================================
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

#: HumanEva-style joint subset for joint-position errors (15 skeleton joint names): pelvis,
#: neck, head, and per side shoulder, elbow, wrist, hip, knee, ankle (the joints every
#: HumanEva / Human3.6M-style evaluation shares; clavicles and spine joints are left out because
#: their placement differs between skeleton conventions).
JOINT_SET_EVAL = (
    "pelvis", "neck", "head",
    "l_shoulder", "l_elbow", "l_wrist", "r_shoulder", "r_elbow", "r_wrist",
    "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle",
)

MARKER_NAMES = (
    "head_top", "head_front", "neck_back", "sternum", "sacrum",
    "l_shoulder", "l_elbow", "l_wrist", "l_hand", "l_hip", "l_knee", "l_ankle", "l_heel", "l_toe",
    "r_shoulder", "r_elbow", "r_wrist", "r_hand", "r_hip", "r_knee", "r_ankle", "r_heel", "r_toe",
)


@dataclass
class Markers:
    """Points rigidly attached to bones.

    Attributes
    ----------
    names : tuple of str, (M,)
    bone : (M,) int, skeleton bone index of each marker
    local : (M, 3) float64, metres
        Rest position minus the bone's rest joint position (rest frames are world-aligned, so
        this is also the offset in the bone frame).
    """

    names: tuple
    bone: np.ndarray
    local: np.ndarray

    def __post_init__(self):
        self.names = tuple(self.names)
        self.bone = np.asarray(self.bone, dtype=np.int64).reshape(-1)
        self.local = np.asarray(self.local, dtype=np.float64).reshape(-1, 3)
        if not (len(self.names) == len(self.bone) == len(self.local)):
            raise ValueError(f"markers: {len(self.names)} names, {len(self.bone)} bones, "
                             f"{len(self.local)} offsets")

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"unknown marker {name!r}; markers are "
                           f"{', '.join(self.names)}") from None

    def rest_positions(self, skeleton) -> np.ndarray:
        """(M, 3) float64 rest-pose world positions, metres."""
        return skeleton.rest_positions()[self.bone] + self.local

    def positions(self, kin, pose) -> np.ndarray:
        """World marker positions for N poses.

        Parameters
        ----------
        kin : Kinematics
        pose : Pose (from ``kin.forward``) for N poses

        Returns
        -------
        (N, M, 3) float64, metres
        """
        return kin.transform_points(pose, self.bone, self.local)


def _ray_hits(origin: np.ndarray, direction: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distances along one ray to every triangle it crosses (Moller-Trumbore), both faces.

    tri : (F, 3, 3) float64. Returns the sorted positive hit distances.
    """
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    p = np.cross(direction, e2)
    det = np.einsum("fi,fi->f", e1, p)
    ok = np.abs(det) > 1e-14
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = origin - tri[:, 0]
    u = np.einsum("fi,fi->f", tv, p) * inv
    q = np.cross(tv, e1)
    v = (q @ direction) * inv
    t = np.einsum("fi,fi->f", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return np.sort(t[hit])


def closest_points_on_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray):
    """Nearest surface points of a triangle mesh (brute force over all triangles).

    Parameters
    ----------
    points : (P, 3) float, metres
    vertices : (V, 3) float, metres
    faces : (F, 3) int

    Returns
    -------
    closest : (P, 3) float64, metres
    distance : (P,) float64, metres
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    out = np.empty_like(pts)
    dist = np.empty(len(pts))
    for k, p in enumerate(pts):
        c = _closest_on_triangles(p, tri)
        d2 = ((c - p) ** 2).sum(1)
        i = int(np.argmin(d2))
        out[k], dist[k] = c[i], np.sqrt(d2[i])
    return out, dist


def _closest_on_triangles(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(F, 3) closest point of each triangle to p (Ericson, Real-Time Collision Detection 5.1.5)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v = vb * denom
        w = vc * denom
        res = a + ab * v[:, None] + ac * w[:, None]  # interior
        # edge regions (later assignments win over earlier, so vertices come last)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        res[m] = (b + (c - b) * t_bc[:, None])[m]
        t_ac = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        res[m] = (a + ac * t_ac[:, None])[m]
        t_ab = d1 / (d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        res[m] = (a + ab * t_ab[:, None])[m]
    m = (d6 >= 0) & (d5 <= d6)
    res[m] = c[m]
    m = (d3 >= 0) & (d4 <= d3)
    res[m] = b[m]
    m = (d1 <= 0) & (d2 <= 0)
    res[m] = a[m]
    return res


def _marker_specs(skeleton):
    """(name, bone name, anchor (3,), direction (3,)) of every default marker, rest pose."""
    from .mesh import _end_vector, _stature

    P = skeleton.rest_positions()
    H = _stature(skeleton)
    pos = {n: P[i] for i, n in enumerate(skeleton.names)}
    up, fwd = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    e_head = _end_vector(skeleton, P, "head", H)
    specs = [
        ("head_top", "head", pos["head"] + 0.4 * e_head, e_head / np.linalg.norm(e_head)),
        ("head_front", "head", pos["head"] + 0.6 * e_head, fwd),
        ("neck_back", "spine_upper", pos["neck"], -fwd),
        ("sternum", "spine_upper", 0.5 * (pos["spine_upper"] + pos["neck"]), fwd),
        ("sacrum", "pelvis", 0.5 * (pos["pelvis"] + pos["spine_lower"]), -fwd),
    ]
    for side, lat in (("l", 1.0), ("r", -1.0)):
        n = lambda k: f"{side}_{k}"  # noqa: E731
        lateral = np.array([lat, 0.0, 0.0])
        e_hand = _end_vector(skeleton, P, n("wrist"), H)
        e_foot = _end_vector(skeleton, P, n("ankle"), H)
        foot_fwd = e_foot * [1, 0, 1]
        foot_fwd = foot_fwd / np.linalg.norm(foot_fwd) if np.linalg.norm(foot_fwd) > 1e-6 else fwd
        hip_up = max(pos["spine_lower"][1] - pos[n("hip")][1], 0.03 * H)
        ankle_h = pos[n("ankle")][1] - (pos[n("ankle")] + e_foot)[1]
        specs += [
            (n("shoulder"), n("clavicle"), pos[n("shoulder")], up),
            (n("elbow"), n("shoulder"), pos[n("elbow")], up),
            (n("wrist"), n("elbow"), pos[n("wrist")], up),
            (n("hand"), n("wrist"), pos[n("wrist")] + 0.35 * e_hand, up),
            (n("hip"), "pelvis", pos[n("hip")] + up * 0.5 * hip_up,
             np.array([0.35 * lat, 0.0, 1.0]) / np.hypot(0.35, 1.0)),
            (n("knee"), n("hip"), pos[n("knee")], lateral),
            (n("ankle"), n("knee"), pos[n("ankle")], lateral),
            (n("heel"), n("ankle"), pos[n("ankle")] - up * 0.6 * max(ankle_h, 0.0), -foot_fwd),
            (n("toe"), n("ankle"), pos[n("ankle")] + 0.75 * e_foot * [1, 0, 1]
             - up * 0.75 * max(ankle_h, 0.0), up),
        ]
    return specs


def default_markers(skeleton, mesh) -> Markers:
    """The default surface marker set placed on ``mesh`` (see the module docstring).

    Parameters
    ----------
    skeleton : Skeleton with the canonical joint names, in whose rest pose ``mesh`` is
    mesh : BodyMesh in that rest pose (procedural or loaded)

    Returns
    -------
    Markers with the 23 markers of ``MARKER_NAMES``, in that order.
    """
    from .mesh import _stature

    reach = 0.25 * _stature(skeleton)
    tri = mesh.vertices.astype(np.float64)[mesh.faces]
    P = skeleton.rest_positions()
    names, bones, local = [], [], []
    for name, bone_name, anchor, direction in _marker_specs(skeleton):
        t = _ray_hits(anchor, direction, tri)
        t = t[t <= reach]
        if len(t):
            point = anchor + t[-1] * direction
        else:  # anchor outside the body or a gap: fall back to the nearest skin point
            log.warning("marker %s: no surface crossing within %.2f m, using nearest point",
                        name, reach)
            point = closest_points_on_mesh(anchor[None], mesh.vertices, mesh.faces)[0][0]
        b = skeleton.index(bone_name)
        names.append(name)
        bones.append(b)
        local.append(point - P[b])
    return Markers(tuple(names), np.array(bones), np.array(local))
