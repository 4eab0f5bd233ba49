"""Skinned body meshes: the data structure shared by the engine, the reference and the simulator."""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

#: Body-part names; ``BodyMesh.part`` indexes this tuple.
PARTS = ("head", "torso", "pelvis", "l_upper_arm", "l_forearm", "l_hand", "r_upper_arm",
         "r_forearm", "r_hand", "l_thigh", "l_shin", "l_foot", "r_thigh", "r_shin", "r_foot")


@dataclass
class BodyMesh:
    """A linear-blend-skinned triangle mesh in the rest pose of a skeleton.

    Attributes
    ----------
    vertices : (V, 3) float32, metres, rest-pose world positions
    faces : (F, 3) int32, counter-clockwise seen from outside
    joints : (V, 4) int32, bone indices into the skeleton (unused slots point at bone 0 with weight 0)
    weights : (V, 4) float32, non-negative, rows sum to 1
    part : (V,) int32, body-part id (index into ``PARTS``)
    """

    vertices: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    part: np.ndarray

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float32)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int32)
        self.joints = np.ascontiguousarray(self.joints, dtype=np.int32)
        self.weights = np.ascontiguousarray(self.weights, dtype=np.float32)
        self.part = np.ascontiguousarray(self.part, dtype=np.int32)
        V = len(self.vertices)
        if self.vertices.shape != (V, 3) or self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise ValueError(f"mesh: vertices {self.vertices.shape} / faces {self.faces.shape} malformed")
        if self.joints.shape != (V, 4) or self.weights.shape != (V, 4) or self.part.shape != (V,):
            raise ValueError("mesh: joints/weights must be (V, 4) and part (V,)")
        if len(self.faces) and (self.faces.min() < 0 or self.faces.max() >= V):
            raise ValueError("mesh: face index out of range")
        s = self.weights.sum(axis=1)
        if np.any(self.weights < 0) or not np.allclose(s, 1.0, atol=1e-4):
            raise ValueError("mesh: skinning weights must be non-negative and sum to 1 per vertex")

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def without_parts(self, parts) -> "BodyMesh":
        """This mesh without the faces that touch a vertex of any of ``parts`` (names from
        :data:`PARTS`), unused vertices dropped; the same mesh when none is named."""
        drop = np.isin(self.part, [PARTS.index(p) for p in parts])
        if not drop.any():
            return self
        faces = self.faces[~drop[self.faces].any(axis=1)]
        used = np.unique(faces)
        remap = np.full(len(self.vertices), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        return BodyMesh(self.vertices[used], remap[faces], self.joints[used], self.weights[used],
                        self.part[used])

    def nearest_faces(self, other: "BodyMesh") -> np.ndarray:
        """(F_other,) int64, for each face of ``other`` the face of this mesh whose rest-pose
        centroid is nearest to its own among the faces of the same body part (the part of the
        face's first vertex). Carries per-face data (e.g. colour clusters) from one level of
        detail of a body to another."""
        from scipy.spatial import cKDTree

        def centroids(m):
            return m.vertices[m.faces].mean(axis=1).astype(np.float64), m.part[m.faces[:, 0]]

        mine, my_part = centroids(self)
        theirs, their_part = centroids(other)
        out = np.empty(len(theirs), dtype=np.int64)
        for p in np.unique(their_part):
            dst = np.flatnonzero(their_part == p)
            src = np.flatnonzero(my_part == p)
            if not len(src):  # a part this mesh lacks: the nearest face of any part
                src = np.arange(len(mine))
            out[dst] = src[cKDTree(mine[src]).query(theirs[dst])[1]]
        return out

    def skin(self, skinning: np.ndarray) -> np.ndarray:
        """CPU linear blend skinning.

        Parameters
        ----------
        skinning : (N, B, 3, 4) skinning matrices (``Kinematics.skinning_matrices``)

        Returns
        -------
        (N, V, 3) float64 posed vertex positions, metres
        """
        S = np.asarray(skinning, dtype=np.float64)
        vh = np.concatenate([self.vertices, np.ones((self.n_vertices, 1), np.float32)], 1).astype(np.float64)
        out = np.zeros((S.shape[0], self.n_vertices, 3))
        for k in range(4):
            w = self.weights[:, k].astype(np.float64)
            used = w > 0
            if not used.any():
                continue
            Sk = S[:, self.joints[used, k]]  # (N, Vu, 3, 4)
            out[:, used] += w[used, None] * np.einsum("nvij,vj->nvi", Sk, vh[used])
        return out


# ---------------------------------------------------------------------------------------------
# The procedural default body
# ---------------------------------------------------------------------------------------------

#: Default body circumferences as fractions of stature. Rounded from ANSUR II (2012) mean
#: adult male values at a stature of 1.75 m (head 0.57 m, neck 0.38, chest 1.00, waist 0.86,
#: buttock/pelvis 0.99, biceps 0.31, elbow 0.26, forearm 0.28, wrist 0.17, hand 0.21, thigh
#: 0.58, knee 0.39, calf/shin 0.38, ankle 0.23, ball-of-foot 0.25). ``elbow``, ``wrist``, ``knee``
#: and ``ankle`` are the distal ends of the limb segments.
GIRTH_RATIOS = {
    "head": 0.326, "neck": 0.217, "chest": 0.571, "waist": 0.491, "pelvis": 0.566,
    "upper_arm": 0.177, "elbow": 0.149, "forearm": 0.160, "wrist": 0.097, "hand": 0.120,
    "thigh": 0.331, "knee": 0.223, "shin": 0.217, "ankle": 0.131, "foot": 0.143,
}

#: Cross-section aspect ratio (depth / width; thickness / width for hand and foot) of each girth.
GIRTH_ASPECT = {
    "head": 1.2, "neck": 1.0, "chest": 0.7, "waist": 0.75, "pelvis": 0.72,
    "upper_arm": 1.0, "elbow": 0.9, "forearm": 0.9, "wrist": 0.7, "hand": 0.35,
    "thigh": 1.0, "knee": 1.0, "shin": 1.0, "ankle": 0.9, "foot": 0.5,
}

# (slices of large segments, slices of small segments, rings per cap, rings along the body) per
# level of detail. Triangles per segment = 2 * slices * (2 * cap + body); 6 large + 13 small
# segments give lod 0: 1008, lod 1: 1968, lod 2: 7872 triangles.
_LOD = {0: (8, 6, 1, 2), 1: (10, 8, 2, 2), 2: (20, 16, 4, 4)}
#: The levels of detail :func:`make_body_mesh` builds.
MESH_LODS = tuple(sorted(_LOD))

_UP = np.array([0.0, 1.0, 0.0])
_X = np.array([1.0, 0.0, 0.0])
_Z = np.array([0.0, 0.0, 1.0])


def _ellipse_semi_axes(circumference: float, aspect: float) -> np.ndarray:
    """(2,) semi-axes (width, depth) of an ellipse with the given perimeter (Ramanujan II)."""
    b = aspect
    h = ((1.0 - b) / (1.0 + b)) ** 2
    unit_perimeter = np.pi * (1.0 + b) * (1.0 + 3.0 * h / (10.0 + np.sqrt(4.0 - 3.0 * h)))
    a = circumference / unit_perimeter
    return np.array([a, a * b])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


@dataclass
class _Segment:
    """One closed tube: rings from ``a`` to ``b`` plus ellipsoidal caps beyond both ends."""

    bone: int
    part: int
    a: np.ndarray
    b: np.ndarray
    width_ref: np.ndarray          # world direction the first semi-axis should follow
    ra: np.ndarray                 # (2,) semi-axes at a, metres
    rb: np.ndarray                 # (2,) semi-axes at b, metres
    cap0: float                    # cap length beyond a, metres
    cap1: float                    # cap length beyond b, metres
    large: bool = False
    bulge: float = 0.0             # relative radius gain at mid-segment (muscle belly)
    power: float = 2.0             # superellipse exponent of the cross-section (2 = ellipse)
    blends: tuple = ()             # (other bone, joint point (3,), +1 end / -1 start, half width)


def _tube(seg: _Segment, slices: int, n_cap: int, n_body: int):
    """Vertices (V, 3), faces (F, 3) and the axial coordinate s (V,) of one closed tube."""
    axis = seg.b - seg.a
    L = float(np.linalg.norm(axis))
    d = axis / L
    ref = seg.width_ref
    if abs(ref @ d) > 0.95:  # bone along the preferred width axis: any perpendicular will do
        ref = _Z if abs(_Z @ d) < 0.95 else _X
    u = _unit(ref - (ref @ d) * d)
    w = np.cross(d, u)  # (u, w, d) right-handed, so increasing phi winds CCW about d
    s_list, r_list = [], []
    cap_angles = np.arange(1, n_cap + 1) * (0.5 * np.pi / (n_cap + 1))
    for th in cap_angles:
        s_list.append(-seg.cap0 * np.cos(th))
        r_list.append(seg.ra * np.sin(th))
    for t in np.linspace(0.0, 1.0, n_body):
        s_list.append(t * L)
        r_list.append(((1 - t) * seg.ra + t * seg.rb) * (1.0 + seg.bulge * np.sin(np.pi * t)))
    for th in cap_angles[::-1]:
        s_list.append(L + seg.cap1 * np.cos(th))
        r_list.append(seg.rb * np.sin(th))
    s = np.array(s_list)
    r = np.array(r_list)
    phi = 2.0 * np.pi * np.arange(slices) / slices
    c, sn = np.cos(phi), np.sin(phi)
    e = 2.0 / seg.power
    cu, cw = np.sign(c) * np.abs(c) ** e, np.sign(sn) * np.abs(sn) ** e
    ring = (seg.a + s[:, None, None] * d
            + r[:, 0, None, None] * cu[None, :, None] * u
            + r[:, 1, None, None] * cw[None, :, None] * w)            # (R, S, 3)
    R = len(s)
    verts = np.concatenate([ring.reshape(-1, 3),
                            (seg.a - seg.cap0 * d)[None], (seg.b + seg.cap1 * d)[None]])
    s_all = np.concatenate([np.repeat(s, slices), [-seg.cap0, L + seg.cap1]])
    p0, p1 = R * slices, R * slices + 1
    j = np.arange(slices)
    jn = (j + 1) % slices
    faces = [np.stack([np.full(slices, p0), jn, j], 1)]
    for i in range(R - 1):
        lo, hi = i * slices, (i + 1) * slices
        faces.append(np.stack([lo + j, lo + jn, hi + jn], 1))
        faces.append(np.stack([lo + j, hi + jn, hi + j], 1))
    last = (R - 1) * slices
    faces.append(np.stack([np.full(slices, p1), last + j, last + jn], 1))
    return verts, np.concatenate(faces), s_all, d


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _segment_weights(seg: _Segment, s: np.ndarray, d: np.ndarray):
    """Joint indices (V, 4) and weights (V, 4) of one tube.

    Near a joint the bone on the other side takes a smoothly rising share of the weight: 0 one
    half width before the joint, 1/4 at the joint, 1/2 one half width beyond it (inside the
    overlapping cap). Capping the share at 1/2 keeps every vertex mostly on its own bone, and
    because the caps are round about the joint they keep covering it when the joint bends.
    """
    V = len(s)
    joints = np.zeros((V, 4), np.int32)
    weights = np.zeros((V, 4))
    joints[:, 0] = seg.bone
    other = np.zeros(V)
    for k, (bone, point, side, half) in enumerate(seg.blends, start=1):
        s_joint = float((point - seg.a) @ d)
        x = side * (s - s_joint) / half
        wk = 0.5 * _smoothstep(0.5 * (x + 1.0))
        joints[:, k] = bone
        weights[:, k] = wk
        other += wk
    scale = np.where(other > 1.0, 1.0 / np.maximum(other, 1e-12), 1.0)
    weights[:, 1:] *= scale[:, None]
    weights[:, 0] = 1.0 - weights[:, 1:].sum(1)
    return joints, weights


def _stature(skeleton) -> float:
    """Standing height; estimated from the head joint when the skeleton lacks end sites."""
    names = skeleton.names
    ends = skeleton.ends
    has_ends = all(np.linalg.norm(ends[skeleton.index(n)]) > 1e-6
                   for n in ("head", "l_ankle", "r_ankle"))
    if has_ends:
        return skeleton.height()
    pos = skeleton.rest_positions()
    # default_skeleton: head joint 0.88 H above the floor, ankles 0.039 H
    span = pos[names.index("head"), 1] - min(pos[names.index("l_ankle"), 1],
                                             pos[names.index("r_ankle"), 1])
    return float(span / (0.88 - 0.039))


#: The head's axis in the procedural mesh, as fractions of the head joint's tip vector
#: (:func:`segment_tip`): the head is an ellipsoidal tube from 0.2 to 0.5 of it, capped by half
#: the tip's length at either end (chin and crown). Its middle, :data:`HEAD_CENTRE`, is the
#: centre of the head the mesh draws; the trackers fit it to the ears' midpoint, which lies at
#: the head's centre seen from the side and about half way from the chin to the crown.
HEAD_AXIS = (0.2, 0.5)
HEAD_CENTRE = 0.5 * (HEAD_AXIS[0] + HEAD_AXIS[1])
#: The hand's knuckles as a fraction of the wrist's tip vector: the mesh's palm ends there and
#: the fingers' cap begins (palm length / hand length, about 0.55 in adults).
KNUCKLES = 0.55
#: How far the mesh's heel reaches behind the ankle, as a fraction of the foot's length from the
#: ankle to the toe tip (heel-to-ankle about a quarter of the foot's length in adults).
HEEL_BEHIND = 0.28


def segment_tip(skeleton, name: str) -> np.ndarray:
    """(3,) metres: the tip of joint ``name``'s end segment relative to the joint, in the rest
    frame, as the procedural mesh draws it (``"head"``, a wrist or an ankle; the skeleton's end
    site, or the mesh's anthropometric fallback when it has none)."""
    return _end_vector(skeleton, skeleton.rest_positions(), name, _stature(skeleton))


def _end_vector(skeleton, pos, name: str, H: float) -> np.ndarray:
    """Segment tip relative to joint ``name``, with anthropometric fallbacks for missing ends."""
    e = skeleton.ends[skeleton.index(name)]
    if np.linalg.norm(e) > 1e-6:
        return e.copy()
    if name == "head":
        return _UP * 0.12 * H
    if name.endswith("wrist"):
        side = name[0]
        fore = pos[skeleton.index(name)] - pos[skeleton.index(f"{side}_elbow")]
        return _unit(fore) * 0.108 * H
    return np.array([0.0, -0.039 * H, 0.11 * H])  # ankle -> toe tip


def shape_problem(lod, girth_scale, girths) -> tuple[str, str] | None:
    """The first invalid shape parameter of :func:`make_body_mesh`, or None.

    Returns
    -------
    (name, problem) : the parameter's name ("lod", "girth_scale" or "girths") and what is wrong
    """
    if lod not in _LOD:
        return "lod", f"must be one of {sorted(_LOD)}, got {lod!r}"
    if not (np.isfinite(girth_scale) and 0.2 <= girth_scale <= 5.0):
        return "girth_scale", f"must be within 0.2..5, got {girth_scale}"
    girths = dict(girths or {})
    unknown = sorted(set(girths) - set(GIRTH_RATIOS))
    if unknown:
        return "girths", f"unknown girths {unknown}; known: {', '.join(GIRTH_RATIOS)}"
    for k, v in girths.items():
        if not (np.isfinite(v) and v > 0):
            return "girths", f"girth {k!r} must be a positive circumference in metres, got {v}"
    return None


def make_body_mesh(skeleton, *, lod: int = 1, girth_scale: float = 1.0,
                   girths: dict | None = None) -> BodyMesh:
    """A smooth, closed, linear-blend-skinned body in the rest (T-) pose of ``skeleton``.

    The body is 19 closed tubes (one connected component each): head, neck, chest (spine_upper
    to neck), abdomen (spine_lower to spine_upper), pelvis (hip joints to spine_lower), two
    shoulder blobs (clavicle to shoulder), and per side upper arm, forearm, hand (wrist to tip),
    thigh, shin and a flattened, box-like foot lying on the floor from behind the ankle to the toe
    tip. Every tube follows the *actual* rest vector between its joints (BVH-derived skeletons
    with arbitrary offsets work), has elliptical (feet: superelliptic) cross-sections sized from
    :data:`GIRTH_RATIOS` times the stature and ellipsoidal end caps that overlap the neighbours
    so joints can bend without gaps. Skin weights blend smoothly between a tube's bone and its
    parent/child bones near the joints (at most 3 influences, rows sum to 1); head, hands-free
    pelvis and feet are rigid to their own bones except where the neighbour blends into them.

    Triangle counts: lod 0: 1008, lod 1: 1968, lod 2: 7872.

    Parameters
    ----------
    skeleton : Skeleton
        With the canonical joint names (``gltrack.body.skeleton.JOINT_NAMES``). The stature is
        ``skeleton.height()`` (estimated from the head joint if end sites are missing).
    lod : {0, 1, 2}
        Level of detail.
    girth_scale : float
        Multiplies every default circumference (a thinner or stouter body).
    girths : dict, optional
        Circumferences in metres overriding the defaults (keys of :data:`GIRTH_RATIOS`); used
        as given, not scaled by ``girth_scale``.

    Returns
    -------
    BodyMesh
        Vertices float32 metres in the rest pose; ``part`` indexes :data:`PARTS` (the neck and
        the shoulder blobs count as ``torso``).
    """
    bad = shape_problem(lod, girth_scale, girths)
    if bad:
        raise ValueError(f"{bad[0]}: {bad[1]}")
    girths = dict(girths or {})

    H = _stature(skeleton)
    P = skeleton.rest_positions()
    J = skeleton.index
    pos = {n: P[J(n)] for n in skeleton.names}

    def semi(key):
        C = girths[key] if key in girths else GIRTH_RATIOS[key] * H * girth_scale
        return _ellipse_semi_axes(C, GIRTH_ASPECT[key])

    part = PARTS.index
    segs = []

    hip_mid = 0.5 * (pos["l_hip"] + pos["r_hip"])
    pel_top = pos["spine_lower"]
    if np.linalg.norm(pel_top - hip_mid) < 0.03 * H:
        pel_top = hip_mid + _UP * 0.06 * H
    half_hips = 0.5 * np.linalg.norm(pos["l_hip"] - pos["r_hip"])
    r_pel = semi("pelvis")
    r_pel[0] = max(r_pel[0], half_hips + 0.6 * semi("thigh")[0])
    segs.append(_Segment(J("pelvis"), part("pelvis"), hip_mid, pel_top, _X, r_pel, semi("waist"),
                         cap0=0.06 * H, cap1=0.3 * semi("waist")[1], large=True,
                         blends=((J("spine_lower"), pos["spine_lower"], +1,
                                  0.4 * np.linalg.norm(pel_top - hip_mid)),)))
    L_abd = np.linalg.norm(pos["spine_upper"] - pos["spine_lower"])
    segs.append(_Segment(J("spine_lower"), part("torso"), pos["spine_lower"], pos["spine_upper"],
                         _X, semi("waist"), 0.5 * (semi("waist") + semi("chest")),
                         cap0=0.5 * semi("waist")[1], cap1=0.5 * semi("chest")[1], large=True,
                         blends=((J("pelvis"), pos["spine_lower"], -1, 0.4 * L_abd),
                                 (J("spine_upper"), pos["spine_upper"], +1, 0.4 * L_abd))))
    L_chest = np.linalg.norm(pos["neck"] - pos["spine_upper"])
    r_chest = semi("chest")
    r_top = r_chest * np.array([0.9, 0.75])
    # the chest must reach the clavicle joints; the shoulder blobs carry on from there
    clav_half = max(abs((pos[s] - pos["neck"]) @ _X) for s in ("l_clavicle", "r_clavicle"))
    r_top[0] = max(r_top[0], clav_half + 0.5 * semi("upper_arm")[0])
    segs.append(_Segment(J("spine_upper"), part("torso"), pos["spine_upper"], pos["neck"], _X,
                         r_chest, r_top, cap0=0.5 * r_chest[1], cap1=0.5 * r_top[1], large=True,
                         blends=((J("spine_lower"), pos["spine_upper"], -1, 0.4 * L_chest),)))
    L_neck = np.linalg.norm(pos["head"] - pos["neck"])
    r_neck = semi("neck")
    segs.append(_Segment(J("neck"), part("torso"), pos["neck"], pos["head"], _X, r_neck, r_neck,
                         cap0=r_neck[0], cap1=r_neck[0],
                         blends=((J("spine_upper"), pos["neck"], -1, 0.45 * L_neck),
                                 (J("head"), pos["head"], +1, 0.45 * L_neck))))
    e_head = _end_vector(skeleton, P, "head", H)
    r_head = semi("head")
    le = np.linalg.norm(e_head)
    segs.append(_Segment(J("head"), part("head"), pos["head"] + HEAD_AXIS[0] * e_head,
                         pos["head"] + HEAD_AXIS[1] * e_head, _X, 0.85 * r_head, r_head,
                         cap0=0.5 * le, cap1=0.5 * le, large=True))

    for side in "lr":
        n = {k: f"{side}_{k}" for k in ("clavicle", "shoulder", "elbow", "wrist", "hip", "knee",
                                        "ankle")}
        r_delt = 1.15 * semi("upper_arm")
        r_clav = 0.8 * r_delt
        L_cl = np.linalg.norm(pos[n["shoulder"]] - pos[n["clavicle"]])
        segs.append(_Segment(J(n["clavicle"]), part("torso"), pos[n["clavicle"]],
                             pos[n["shoulder"]], _Z, r_clav, r_delt, cap0=r_clav[0],
                             cap1=0.6 * r_delt[0],
                             blends=((J("spine_upper"), pos[n["clavicle"]], -1, 0.4 * L_cl),
                                     (J(n["shoulder"]), pos[n["shoulder"]], +1,
                                      0.6 * r_delt[0]))))
        ra, rb = semi("upper_arm"), semi("elbow")
        segs.append(_Segment(J(n["shoulder"]), part(f"{side}_upper_arm"), pos[n["shoulder"]],
                             pos[n["elbow"]], _Z, ra, rb, cap0=ra[0], cap1=rb[0], bulge=0.05,
                             blends=((J(n["clavicle"]), pos[n["shoulder"]], -1, ra[0]),
                                     (J(n["elbow"]), pos[n["elbow"]], +1, rb[0]))))
        ra, rb = semi("forearm"), semi("wrist")
        segs.append(_Segment(J(n["elbow"]), part(f"{side}_forearm"), pos[n["elbow"]],
                             pos[n["wrist"]], _Z, ra, rb, cap0=ra[0], cap1=rb[0], bulge=0.05,
                             blends=((J(n["shoulder"]), pos[n["elbow"]], -1, ra[0]),
                                     (J(n["wrist"]), pos[n["wrist"]], +1, rb[0]))))
        e_hand = _end_vector(skeleton, P, n["wrist"], H)
        r_hand = semi("hand")
        segs.append(_Segment(J(n["wrist"]), part(f"{side}_hand"), pos[n["wrist"]],
                             pos[n["wrist"]] + KNUCKLES * e_hand, _Z, r_hand * [0.8, 1.2], r_hand,
                             cap0=0.5 * semi("wrist")[0],
                             cap1=0.45 * np.linalg.norm(e_hand),
                             blends=((J(n["elbow"]), pos[n["wrist"]], -1,
                                      0.6 * semi("wrist")[0]),)))
        ra, rb = semi("thigh"), semi("knee")
        segs.append(_Segment(J(n["hip"]), part(f"{side}_thigh"), pos[n["hip"]], pos[n["knee"]],
                             _X, ra, rb, cap0=0.8 * ra[0], cap1=rb[0], large=True,
                             blends=((J("pelvis"), pos[n["hip"]], -1, 0.5 * ra[0]),
                                     (J(n["knee"]), pos[n["knee"]], +1, rb[0]))))
        ra, rb = 0.9 * semi("shin"), semi("ankle")
        segs.append(_Segment(J(n["knee"]), part(f"{side}_shin"), pos[n["knee"]], pos[n["ankle"]],
                             _X, ra, rb, cap0=ra[0], cap1=rb[0], bulge=0.12,
                             blends=((J(n["hip"]), pos[n["knee"]], -1, ra[0]),
                                     (J(n["ankle"]), pos[n["ankle"]], +1, rb[0]))))
        segs.append(_foot_segment(skeleton, P, n["ankle"], H, semi("foot"), J(n["ankle"]),
                                  part(f"{side}_foot")))

    slices_big, slices_small, n_cap, n_body = _LOD[lod]
    verts, faces, joints, weights, parts = [], [], [], [], []
    offset = 0
    for seg in segs:
        v, f, s, d = _tube(seg, slices_big if seg.large else slices_small, n_cap, n_body)
        jt, wt = _segment_weights(seg, s, d)
        verts.append(v)
        faces.append(f + offset)
        joints.append(jt)
        weights.append(wt)
        parts.append(np.full(len(v), seg.part))
        offset += len(v)
    mesh = BodyMesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(joints),
                    np.concatenate(weights), np.concatenate(parts))
    log.debug("body mesh lod %d: %d vertices, %d triangles, stature %.3f m",
              lod, mesh.n_vertices, mesh.n_faces, H)
    return mesh


def _foot_axis(skeleton, P, ankle: str, H: float):
    """The toe tip (3,) in the rest pose, the foot's horizontal forward direction (3,) and its
    length from the ankle to the tip along it (metres)."""
    a_pos = P[skeleton.index(ankle)]
    toe = a_pos + _end_vector(skeleton, P, ankle, H)
    fwd = toe - a_pos
    fwd[1] = 0.0
    length = float(np.linalg.norm(fwd))
    if length < 0.03 * H:  # end site straight down: assume a forward-pointing foot
        fwd, length = _Z.copy(), 0.11 * H
    return toe, fwd / length, length


def foot_ends(skeleton, ankle: str) -> np.ndarray:
    """(2, 3) metres: the back of the heel and the toe tip of the procedural mesh's foot,
    relative to joint ``ankle`` in the rest frame, both at the toe tip's height (the sole)."""
    P = skeleton.rest_positions()
    toe, fwd, length = _foot_axis(skeleton, P, ankle, _stature(skeleton))
    a_pos = P[skeleton.index(ankle)]
    heel = np.array([a_pos[0], toe[1], a_pos[2]]) - fwd * HEEL_BEHIND * length
    return np.stack([heel - a_pos, toe - a_pos])


def _foot_segment(skeleton, P, ankle: str, H: float, r_foot: np.ndarray, bone: int,
                  part_id: int) -> _Segment:
    """A flat, box-like foot on the floor (the toe tip's height) from behind the ankle to the toe.

    Uses the rest-pose convention (+Y up, floor under the toe tip) rather than the bone's
    direction, so the sole is level whatever way the skeleton's ankle->toe vector points.
    """
    a_pos = P[skeleton.index(ankle)]
    toe, fwd, length = _foot_axis(skeleton, P, ankle, H)
    sole = min(toe[1], a_pos[1] - 0.5 * r_foot[1])
    r_heel = r_foot * np.array([0.7, 1.3])
    heel_c = np.array([a_pos[0], sole + r_heel[1], a_pos[2]]) - fwd * HEEL_BEHIND * length
    toe_c = np.array([a_pos[0], sole + r_foot[1], a_pos[2]]) + fwd * length
    d = _unit(toe_c - heel_c)
    cap0, cap1 = 0.8 * r_heel[1], 0.6 * r_foot[0]
    return _Segment(bone, part_id, heel_c + cap0 * d, toe_c - cap1 * d, _X, r_heel, r_foot,
                    cap0=cap0, cap1=cap1, power=3.5)
