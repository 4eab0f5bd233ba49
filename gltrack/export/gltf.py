"""Tracked motion -> glTF 2.0 binary (.glb): the skinned body mesh with one animation.

What the file holds (glTF units and axes are gltrack's: metres, +Y up, the body faces +Z):

* one node per skeleton joint, named like the joint, in the skeleton's hierarchy, with the
  rest offset as ``translation``. gltrack's rest frames are world-aligned (as in BVH), so the
  rest node hierarchy *is* the bind pose and each inverse bind matrix is a pure translation by
  ``-rest_position``;
* a mesh node (``"body"``) with one triangle primitive: ``POSITION``, ``NORMAL``,
  ``JOINTS_0`` (unsigned short), ``WEIGHTS_0`` (float) and unsigned-int ``indices``, and a
  skin over the joint nodes (``skeleton`` = the root joint);
* one animation ``"tracked"``: a ``rotation`` sampler (unit quaternions ``x, y, z, w``) for every
  joint and a ``translation`` sampler for the root, LINEAR, keyed at ``frame / fps`` seconds.
  Consecutive quaternions are sign-aligned so that LINEAR (slerp) interpolation takes the short
  way between frames.

With these conventions a glTF viewer's joint matrix ``world_j @ inverseBind_j`` equals
:meth:`gltrack.body.kinematics.Kinematics.skinning_matrices`, so the animated mesh is exactly
the posed gltrack body.
"""
from __future__ import annotations

import json
import logging
import struct
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

_FLOAT, _USHORT, _UINT = 5126, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TYPES = {1: "SCALAR", 3: "VEC3", 4: "VEC4", 16: "MAT4"}


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of a triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int, counter-clockwise seen from outside

    Returns
    -------
    (V, 3) float32 unit normals; ``(0, 1, 0)`` for vertices on no (or only degenerate) faces,
    because glTF requires every NORMAL to be unit length.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # length = 2 * area
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1)
    ok = length > 1e-12
    n[ok] /= length[ok, None]
    n[~ok] = (0.0, 1.0, 0.0)
    return n.astype(np.float32)


def _quaternions(R: np.ndarray) -> np.ndarray:
    """(T, B, 3, 3) rotations -> (T, B, 4) float64 ``x, y, z, w``, sign-continuous over T."""
    from scipy.spatial.transform import Rotation

    T, B = R.shape[:2]
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat().reshape(T, B, 4)  # scalar last
    for t in range(1, T):
        flip = np.einsum("bi,bi->b", q[t], q[t - 1]) < 0
        q[t, flip] *= -1.0
    return q


class _Bin:
    """Accumulates the BIN chunk, its bufferViews and accessors."""

    def __init__(self):
        self.data = bytearray()
        self.views, self.accessors = [], []

    def add(self, array, component, target=None, minmax=False) -> int:
        a = np.ascontiguousarray(array)
        count = a.shape[0]
        width = int(np.prod(a.shape[1:])) if a.ndim > 1 else 1
        self.data.extend(b"\0" * (-len(self.data) % 4))  # every view starts 4-byte aligned
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": a.nbytes}
        if target is not None:
            view["target"] = target
        self.data.extend(a.tobytes())
        self.views.append(view)
        acc = {"bufferView": len(self.views) - 1, "componentType": component, "count": count,
               "type": _TYPES[width]}
        if minmax:
            flat = a.reshape(count, width)
            cast = float if component == _FLOAT else int
            acc["min"] = [cast(x) for x in flat.min(axis=0)]
            acc["max"] = [cast(x) for x in flat.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def build_glb(body, params, fps: float, frames=None, name: str = "gltrack") -> bytes:
    """The animated, skinned body as GLB bytes (see the module docstring for the layout).

    Parameters
    ----------
    body : gltrack.body.model.BodyModel
        Skeleton, DOF set and mesh; ``params`` must use its DOF preset.
    params : (T, D) float
        Pose parameters per frame (metres for the root translation, radians); clamped to the
        joint limits as :meth:`Kinematics.forward` does, so the animation shows the same pose
        as the results' joint positions.
    fps : float
        Frames per second of the motion.
    frames : (T,) int, optional
        Frame index of each row (dataset frame numbers); keys are at ``frames / fps`` seconds.
        Default ``0..T-1``. Must be strictly increasing.
    name : str
        Scene and animation name.

    Returns
    -------
    bytes
        A complete GLB file.
    """
    sk, mesh = body.skeleton, body.mesh
    P = np.asarray(params, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != body.dofs.size:
        raise ValueError(f"params must be (T, {body.dofs.size}) for the {body.dofs.preset!r} "
                         f"DOF preset, got {P.shape}")
    T = len(P)
    if T == 0:
        raise ValueError("params hold no frames: nothing to animate")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps!r}")
    frames = np.arange(T) if frames is None else np.asarray(frames, dtype=np.int64).reshape(-1)
    if frames.shape != (T,) or np.any(np.diff(frames) <= 0):
        raise ValueError(f"frames must be ({T},) strictly increasing frame indices")
    P = body.dofs.validate(P)
    local = body.kin.local_rotations(P)  # (T, B, 3, 3)
    B = sk.n_joints
    rest = sk.rest_positions()

    buf = _Bin()
    pos = mesh.vertices.astype(np.float32)
    a_pos = buf.add(pos, _FLOAT, _ARRAY_BUFFER, minmax=True)
    a_nrm = buf.add(vertex_normals(pos, mesh.faces), _FLOAT, _ARRAY_BUFFER)
    joints = np.where(mesh.weights > 0, mesh.joints, 0).astype(np.uint16)
    a_jnt = buf.add(joints, _USHORT, _ARRAY_BUFFER)
    a_wgt = buf.add(mesh.weights.astype(np.float32), _FLOAT, _ARRAY_BUFFER)
    a_idx = buf.add(mesh.faces.astype(np.uint32).reshape(-1), _UINT, _ELEMENT_ARRAY_BUFFER,
                    minmax=True)
    ibm = np.tile(np.eye(4, dtype=np.float32), (B, 1, 1))
    ibm[:, :3, 3] = -rest
    # glTF matrices are column-major: the transpose's row-major bytes are the matrix's columns.
    a_ibm = buf.add(ibm.transpose(0, 2, 1).reshape(B, 16), _FLOAT)
    a_time = buf.add((frames / float(fps)).astype(np.float32), _FLOAT, minmax=True)
    a_root = buf.add(P[:, :3].astype(np.float32), _FLOAT)
    quats = _quaternions(local).astype(np.float32)
    a_rot = [buf.add(np.ascontiguousarray(quats[:, j]), _FLOAT) for j in range(B)]

    nodes = []
    for j in range(B):
        node = {"name": str(sk.names[j]), "translation": [float(x) for x in sk.offsets[j]]}
        kids = sk.children(j)
        if kids:
            node["children"] = kids
        nodes.append(node)
    nodes.append({"name": "body", "mesh": 0, "skin": 0})
    samplers = [{"input": a_time, "output": a_root, "interpolation": "LINEAR"}]
    channels = [{"sampler": 0, "target": {"node": 0, "path": "translation"}}]
    for j in range(B):
        samplers.append({"input": a_time, "output": a_rot[j], "interpolation": "LINEAR"})
        channels.append({"sampler": j + 1, "target": {"node": j, "path": "rotation"}})
    doc = {
        "asset": {"version": "2.0", "generator": "gltrack"},
        "scene": 0,
        "scenes": [{"name": name, "nodes": [0, B]}],
        "nodes": nodes,
        "meshes": [{"name": "body", "primitives": [{
            "attributes": {"POSITION": a_pos, "NORMAL": a_nrm, "JOINTS_0": a_jnt,
                           "WEIGHTS_0": a_wgt},
            "indices": a_idx, "mode": 4}]}],
        "skins": [{"name": "skeleton", "joints": list(range(B)), "skeleton": 0,
                   "inverseBindMatrices": a_ibm}],
        "animations": [{"name": "tracked", "samplers": samplers, "channels": channels}],
        "buffers": [{"byteLength": len(buf.data)}],
        "bufferViews": buf.views,
        "accessors": buf.accessors,
    }
    js = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    js += b" " * (-len(js) % 4)  # the spec pads the JSON chunk with spaces, BIN with zeros
    bin_ = bytes(buf.data) + b"\0" * (-len(buf.data) % 4)
    total = 12 + 8 + len(js) + 8 + len(bin_)
    return b"".join([struct.pack("<4sII", b"glTF", 2, total),
                     struct.pack("<I4s", len(js), b"JSON"), js,
                     struct.pack("<I4s", len(bin_), b"BIN\0"), bin_])


def write_glb(path, body, params, fps: float, frames=None) -> Path:
    """Write the animated body as a .glb file (see :func:`build_glb`); returns the path."""
    path = Path(path)
    data = build_glb(body, params, fps, frames, name=path.stem or "gltrack")
    path.write_bytes(data)
    log.info("wrote %s (%d frames, %.1f kB)", path, len(np.asarray(params)), len(data) / 1e3)
    return path
