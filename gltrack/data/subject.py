"""The simulated subject's surface: whose skin the sensor simulator draws (``gltrack synth``).

By default the simulator draws the tracker's own procedural mesh
(:func:`gltrack.body.mesh.make_body_mesh` of the clip's skeleton), so a tracker scores with the
very surface that made the images. Two options break that match (issue 12, "model mismatch"):

``--girth-scale S`` (:data:`GIRTH_SCALE_RANGE`, default 1)
    A thinner (< 1) or stouter (> 1) subject. The procedural mesh is made with
    ``make_body_mesh(..., girth_scale=S)`` (every circumference times S); a glTF subject is
    scaled radially about its bones (below).
``--mesh FILE.glb``
    A rigged glTF body nobody on the project modelled, e.g. the MakeHuman mesh in
    ``../shared/meshes``. :func:`fit_gltf_subject` reads it with
    :func:`gltrack.body.gltf.load_gltf_skin` (the file's joints mapped onto gltrack bones by
    name, :data:`gltrack.body.gltf.MAKEHUMAN_CMU_MAP`; the skin re-posed into a T-pose of the
    file's own skeleton) and then fits it to the clip's skeleton in the rest pose, so that the
    clip's joints lie inside the skin. From then on it is skinned like any
    :class:`~gltrack.body.mesh.BodyMesh` of that skeleton: linear blend skinning with the
    clip's joint rotations (``Kinematics.skinning_matrices``), each vertex with the file's
    weights summed per gltrack bone.

Fitting (rest pose to rest pose). Every bone gets an affine map ``v -> o + A (v - o_f)`` that
takes a file segment onto a clip segment, and each vertex moves by the blend of its bones' maps
with its skinning weights, as in linear blend skinning. ``s`` is the stature ratio (head joint
above the lower ankle, clip over file) and ``g`` the girth scale. A segment map rotates the
file's segment direction onto the clip's by the shortest arc, scales along the segment to the
clip's length and by ``s g`` across it:

* trunk (pelvis, spine_lower, spine_upper, neck): one map, from the midpoint of the hip joints
  to the midpoint of the shoulder joints. Sources disagree about where the spine, neck and head
  joints sit (CMU's lower back starts at the hips, MakeHuman's neck joint is above the
  shoulders, the default skeleton's is level with them), so per-bone maps would squash or
  stretch parts of the trunk; hips and shoulders are the same anatomical joints everywhere;
* head: uniform scale ``s`` about the trunk's image of the file's head joint (it may sit a few
  centimetres off the clip's head joint, which is then inside the neck);
* clavicle: from the trunk's image of the file's clavicle joint to the clip's shoulder joint
  (it bridges trunk and arm, so neither tears at the shoulder);
* upper arm, forearm, thigh, shin: joint to joint;
* hands, feet: uniform scale ``s`` about their joint, no rotation (end sites are unreliable
  lengths: CMU hands end at the knuckles; the soles stay level).

Head, hands and feet get no girth scale (fat does not grow feet). Adjacent maps agree at the
joint they share, so the blended skin does not tear.

Colours: the glTF file's own materials are ignored. Every vertex gets the body part of its
dominant bone (``BodyMesh.part``), the trunk split at a waist line (:func:`waist_parts`), and
:func:`gltrack.data.simulate.clothing_colours` dresses it exactly like the procedural subject:
shirt on torso (the neck included) and upper arms, bare forearms, hands and head, trousers on
pelvis and legs, shoes, hair cut from the top and back of the head (:func:`top_of_head` gives
the top of the fitted head).

Record: :func:`subject_record` is the ``"subject"`` entry of ``meta.json`` (``{"mesh": file
name or "procedural", "girth_scale": S}``, plus ``"sha256"`` of a glTF file); the default subject
has none, so default datasets stay byte for byte as they were. The ``"body"`` record (the true
skeleton) and the ground truth (joints and markers of the clip's skeleton and the tracker's
body) do not depend on the subject.
"""
from __future__ import annotations

import hashlib
import logging
import math
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from gltrack.body.gltf import load_gltf_skin
from gltrack.body.mesh import PARTS, BodyMesh, make_body_mesh
from gltrack.body.skeleton import JOINT_NAMES

log = logging.getLogger(__name__)

#: Allowed ``--girth-scale`` values (inclusive).
GIRTH_SCALE_RANGE = (0.5, 2.0)

_TRUNK = ("pelvis", "spine_lower", "spine_upper", "neck")
_ENDS = ("head", "l_wrist", "r_wrist", "l_ankle", "r_ankle")
#: Bone -> the joint that ends its segment (limbs; the clavicle is handled apart).
_LIMB_END = {"l_shoulder": "l_elbow", "l_elbow": "l_wrist", "r_shoulder": "r_elbow",
             "r_elbow": "r_wrist", "l_hip": "l_knee", "l_knee": "l_ankle",
             "r_hip": "r_knee", "r_knee": "r_ankle"}


def girth_scale_problem(value) -> str | None:
    """What is wrong with a girth scale, or None (finite and within :data:`GIRTH_SCALE_RANGE`)."""
    lo, hi = GIRTH_SCALE_RANGE
    try:
        v = float(value)
    except (TypeError, ValueError):
        return f"must be a number within {lo:g}..{hi:g}, got {value!r}"
    if not (math.isfinite(v) and lo <= v <= hi):
        return f"must be within {lo:g}..{hi:g}, got {value}"
    return None


def _segment_map(u, v, across: float) -> np.ndarray:
    """(3, 3) map taking segment ``u`` onto ``v``: scale ``|v|/|u|`` along, ``across`` across."""
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    nu, nv = np.linalg.norm(u), np.linalg.norm(v)
    if nu < 1e-6 or nv < 1e-6:
        raise ValueError("cannot fit a glTF subject onto a bone of zero length")
    d = u / nu
    rot, _ = Rotation.align_vectors([v / nv], [d])
    stretch = (nv / nu) * np.outer(d, d) + across * (np.eye(3) - np.outer(d, d))
    return rot.as_matrix() @ stretch


def _stature(positions: np.ndarray) -> float:
    """Head joint above the lower ankle joint, metres (end sites are not comparable)."""
    head = positions[JOINT_NAMES.index("head"), 1]
    ankle = min(positions[JOINT_NAMES.index(a), 1] for a in ("l_ankle", "r_ankle"))
    return float(head - ankle)


def fit_to_skeleton(mesh: BodyMesh, source, skeleton, girth_scale: float = 1.0) -> BodyMesh:
    """Move a skinned mesh from the rest pose of ``source`` into that of ``skeleton``.

    Parameters
    ----------
    mesh : BodyMesh, rest pose of ``source``, bones of the canonical gltrack skeleton
    source, skeleton : Skeleton, canonical joint names (``JOINT_NAMES``), T-poses
    girth_scale : float, scale across trunk and limb segments (see the module docstring)

    Returns
    -------
    BodyMesh with the same faces, weights and parts, vertices in ``skeleton``'s rest pose.
    """
    for sk in (source, skeleton):
        if tuple(sk.names) != JOINT_NAMES:
            raise ValueError(f"fit_to_skeleton needs the canonical gltrack joints, got "
                             f"{tuple(sk.names)}")
    J = JOINT_NAMES.index
    pf, pt = source.rest_positions(), skeleton.rest_positions()
    s = _stature(pt) / _stature(pf)
    across = s * float(girth_scale)
    B = len(JOINT_NAMES)
    origin_f, origin_t, A = pf.copy(), pt.copy(), np.tile(np.eye(3), (B, 1, 1))
    mid_f, mid_t = (0.5 * (p[J("l_hip")] + p[J("r_hip")]) for p in (pf, pt))
    top_f, top_t = (0.5 * (p[J("l_shoulder")] + p[J("r_shoulder")]) for p in (pf, pt))
    trunk = _segment_map(top_f - mid_f, top_t - mid_t, across)

    def in_trunk(x):
        return mid_t + trunk @ (x - mid_f)

    for name in _TRUNK:
        origin_f[J(name)], origin_t[J(name)], A[J(name)] = mid_f, mid_t, trunk
    for name in _ENDS:
        A[J(name)] = s * np.eye(3)
    origin_t[J("head")] = in_trunk(pf[J("head")])
    for side in "lr":
        c, sh = J(f"{side}_clavicle"), J(f"{side}_shoulder")
        origin_t[c] = in_trunk(pf[c])
        A[c] = _segment_map(pf[sh] - pf[c], pt[sh] - origin_t[c], across)
    for name, end in _LIMB_END.items():
        b, e = J(name), J(end)
        A[b] = _segment_map(pf[e] - pf[b], pt[e] - pt[b], across)
    v = mesh.vertices.astype(np.float64)
    out = np.zeros_like(v)
    for k in range(mesh.joints.shape[1]):
        b = mesh.joints[:, k]
        moved = origin_t[b] + np.einsum("vij,vj->vi", A[b], v - origin_f[b])
        out += mesh.weights[:, k, None].astype(np.float64) * moved
    return BodyMesh(out, mesh.faces, mesh.joints, mesh.weights, mesh.part)


#: Waist line (top of the trousers) between the hip joints (0) and the shoulder joints (1).
WAIST = 0.2


def waist_parts(mesh: BodyMesh, skeleton) -> np.ndarray:
    """(V,) parts with the trunk split at the waist line: ``pelvis`` below, ``torso`` above.

    A skin's weights do not follow clothing: MakeHuman's lower-back bone reaches down between
    the buttocks, which would put a shirt there. Rest-pose heights do.
    """
    J = skeleton.index
    pos = skeleton.rest_positions()
    hips = 0.5 * (pos[J("l_hip"), 1] + pos[J("r_hip"), 1])
    shoulders = 0.5 * (pos[J("l_shoulder"), 1] + pos[J("r_shoulder"), 1])
    waist = hips + WAIST * (shoulders - hips)
    part = mesh.part.copy()
    trunk = np.isin(part, [PARTS.index("torso"), PARTS.index("pelvis")])
    below = mesh.vertices[:, 1] < waist
    part[trunk & below] = PARTS.index("pelvis")
    part[trunk & ~below] = PARTS.index("torso")
    return part


def fit_gltf_subject(path, skeleton, girth_scale: float = 1.0) -> BodyMesh:
    """A rigged glTF body (default name map) fitted to ``skeleton``'s rest pose.

    Parameters
    ----------
    path : str or Path, .glb / .gltf whose joint names :data:`MAKEHUMAN_CMU_MAP` knows
    skeleton : Skeleton, the clip's (canonical joint names)
    girth_scale : float, within :data:`GIRTH_SCALE_RANGE`

    Returns
    -------
    BodyMesh bound to ``skeleton`` (see the module docstring).

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Malformed file, joints the name map does not know, or a bad girth scale; the message
        names the file or the parameter.
    """
    bad = girth_scale_problem(girth_scale)
    if bad:
        raise ValueError(f"girth_scale {bad}")
    mesh, info = load_gltf_skin(path)
    fitted = fit_to_skeleton(mesh, info["skeleton"], skeleton, girth_scale)
    fitted.part = waist_parts(fitted, skeleton)
    log.info("%s: %d vertices fitted to a %.2f m skeleton (file: %.2f m), girth scale %g",
             path, fitted.n_vertices, skeleton.height(), info["skeleton"].height(), girth_scale)
    return fitted


def subject_mesh(skeleton, default: BodyMesh, *, gltf=None, girth_scale: float = 1.0,
                 lod: int = 1, custom: bool = False) -> BodyMesh:
    """The mesh the simulator draws.

    Parameters
    ----------
    skeleton : Skeleton, the clip's
    default : BodyMesh, the tracker's body mesh (returned as is for the default subject)
    gltf : path, optional, a rigged glTF body (:func:`fit_gltf_subject`)
    girth_scale : float
    lod : int, level of detail of a girth-scaled procedural mesh
    custom : bool, ``default`` is not the procedural mesh (then only 1 is a valid girth scale
        without ``gltf``)
    """
    bad = girth_scale_problem(girth_scale)
    if bad:
        raise ValueError(f"girth_scale {bad}")
    if gltf is not None:
        return fit_gltf_subject(gltf, skeleton, girth_scale)
    if float(girth_scale) == 1.0:
        return default
    if custom:
        raise ValueError("girth_scale needs the procedural mesh or a glTF subject, not a "
                         "custom mesh")
    return make_body_mesh(skeleton, lod=lod, girth_scale=float(girth_scale))


def subject_record(gltf=None, girth_scale: float = 1.0, drawn: BodyMesh | None = None
                   ) -> dict | None:
    """``meta.json``'s ``"subject"`` entry, or None for the default subject (procedural, 1).

    With ``drawn`` (the subject's rest-pose mesh) the entry also records its
    :func:`surface_stature` as ``"stature_m"``.
    """
    if gltf is None and float(girth_scale) == 1.0:
        return None
    rec = {"mesh": "procedural" if gltf is None else Path(gltf).name,
           "girth_scale": float(girth_scale)}
    if drawn is not None:
        rec["stature_m"] = round(surface_stature(drawn), 4)
    if gltf is not None:
        rec["sha256"] = hashlib.sha256(Path(gltf).read_bytes()).hexdigest()
    return rec


def surface_stature(mesh: BodyMesh) -> float:
    """Standing height of a mesh's surface in its rest pose (lowest sole to head top), metres.

    Not :meth:`~gltrack.body.skeleton.Skeleton.height`, which ends at the skeleton's end
    sites: a glTF subject fitted joint to joint keeps its own head and feet (scaled about their
    joints), and stands 91-129 mm taller than the CMU skeletons it is fitted to; a body
    estimate measures the surface, so that is what its height is compared with.
    """
    y = np.asarray(mesh.vertices, dtype=np.float64)[:, 1]
    return float(y.max() - y.min())


def recorded_stature(meta: dict) -> float | None:
    """The subject's surface stature a dataset's ``meta.json`` records (metres; see
    :func:`subject_record`), or None (the default subject, or a dataset made before it was
    recorded)."""
    value = (meta.get("subject") or {}).get("stature_m")
    return None if value is None else float(value)


def top_of_head(mesh: BodyMesh, skeleton) -> np.ndarray:
    """(3,) head joint -> top of the head of ``mesh`` (rest pose), for the hair line."""
    h = skeleton.index("head")
    p = skeleton.rest_positions()[h]
    own = mesh.vertices[mesh.part == PARTS.index("head")].astype(np.float64)
    if len(own) == 0:
        return skeleton.ends[h].copy()
    top = own[np.argmax(own[:, 1])]
    return np.array([0.0, top[1] - p[1], 0.0])
