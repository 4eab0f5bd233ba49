"""Load a linear-blend-skinned mesh from glTF 2.0 (.glb / .gltf) onto the gltrack skeleton.

A small own parser (JSON chunk + BIN chunk, accessors, node hierarchy with TRS or matrices) keeps
the dependency surface thin and the validation explicit: every malformed field raises a
``ValueError`` naming the file and the field.

Pipeline of :func:`load_gltf_skin`:

1. Read positions, JOINTS_0/WEIGHTS_0 (and _1 if present), indices and the skin's inverse bind
   matrices. The bind pose is the one the inverse bind matrices define, placed in the scene by
   the root joint's default world transform (so a Z-up file under a root matrix comes out Y-up).
2. Map the file's joints onto the gltrack skeleton (``joint_map``, default
   :data:`MAKEHUMAN_CMU_MAP`); weights of file joints that map to the same bone are summed,
   the four largest kept and renormalised (some files store rows summing < 1).
3. Re-pose into the gltrack rest pose: each bone gets the rotation that takes its bind
   direction (towards its child joint / end; a best-fit rotation for several children) onto the
   rest direction of the target skeleton, and the mesh is skinned with those transforms. Without
   a ``skeleton`` the target is built from the file: bind joint positions, with the arm chains
   (shoulder, elbow, wrist, hand tip) straightened out along +-X into a T-pose.
"""
from __future__ import annotations

import base64
import json
import logging
import struct
from pathlib import Path

import numpy as np

from .mesh import PARTS, BodyMesh
from .skeleton import EULER_ORDER, JOINT_NAMES, PARENTS, Skeleton

log = logging.getLogger(__name__)

_SIDES = {"Left": "l", "Right": "r"}


def _cmu_map() -> dict:
    m = {"Hips": "pelvis", "LowerBack": "spine_lower", "Spine": "spine_lower",
         "Spine1": "spine_upper", "Neck": "neck", "Neck1": "neck", "Head": "head",
         "LHipJoint": "pelvis", "RHipJoint": "pelvis", "LThumb": "l_wrist", "RThumb": "r_wrist"}
    for side, s in _SIDES.items():
        m.update({f"{side}Shoulder": f"{s}_clavicle", f"{side}Arm": f"{s}_shoulder",
                  f"{side}ForeArm": f"{s}_elbow", f"{side}Hand": f"{s}_wrist",
                  f"{side}FingerBase": f"{s}_wrist", f"{side}HandFinger1": f"{s}_wrist",
                  f"{side}HandIndex1": f"{s}_wrist", f"{side}HandThumb": f"{s}_wrist",
                  f"{side}UpLeg": f"{s}_hip", f"{side}Leg": f"{s}_knee",
                  f"{side}Foot": f"{s}_ankle", f"{side}ToeBase": f"{s}_ankle"})
    return m


#: File joint name -> gltrack bone, for the CMU / MotionBuilder skeleton used by MakeHuman's
#: ``cmu_mb`` rig (and the CMU BVH conversions). Finger and toe joints fold into wrist / ankle.
MAKEHUMAN_CMU_MAP = _cmu_map()

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
              5126: np.float32}
_N_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


class _Gltf:
    """Parsed JSON plus binary buffers of one file."""

    def __init__(self, path: Path):
        self.path = path
        raw = path.read_bytes()
        self.bin = None
        if raw[:4] == b"glTF":
            self.json = self._parse_glb(raw)
        else:
            try:
                self.json = json.loads(raw.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise ValueError(f"{path}: neither a GLB nor glTF JSON ({exc})") from None
        if not isinstance(self.json, dict) or not str(
                self.json.get("asset", {}).get("version", "")).startswith("2"):
            raise ValueError(f"{path}: asset.version must be 2.x")
        self.buffers = [self._load_buffer(i, b) for i, b in enumerate(self.json.get("buffers", []))]

    def _err(self, field: str, what: str) -> ValueError:
        return ValueError(f"{self.path}: {field}: {what}")

    def _parse_glb(self, raw: bytes) -> dict:
        if len(raw) < 20:
            raise self._err("header", "truncated GLB")
        _, version, length = struct.unpack_from("<4sII", raw, 0)
        if version != 2 or length > len(raw):
            raise self._err("header", f"GLB version {version}, length {length} of {len(raw)}")
        pos, doc = 12, None
        while pos + 8 <= length:
            clen, ctype = struct.unpack_from("<I4s", raw, pos)
            chunk = raw[pos + 8: pos + 8 + clen]
            if len(chunk) != clen:
                raise self._err("chunks", "chunk runs past the end of the file")
            if ctype == b"JSON" and doc is None:
                try:
                    doc = json.loads(chunk.decode("utf-8"))
                except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                    raise self._err("JSON chunk", str(exc)) from None
            elif ctype == b"BIN\x00" and self.bin is None:
                self.bin = chunk
            pos += 8 + clen + (-clen % 4)
        if doc is None:
            raise self._err("chunks", "no JSON chunk")
        return doc

    def _load_buffer(self, i: int, b: dict) -> bytes:
        uri = b.get("uri")
        if uri is None:
            if i != 0 or self.bin is None:
                raise self._err(f"buffers[{i}]", "no uri and no GLB BIN chunk")
            data = self.bin
        elif uri.startswith("data:"):
            try:
                data = base64.b64decode(uri.split(",", 1)[1])
            except (IndexError, ValueError):
                raise self._err(f"buffers[{i}].uri", "bad data URI") from None
        else:
            base = self.path.parent.resolve()
            target = (base / uri).resolve()
            if base not in target.parents:
                raise self._err(f"buffers[{i}].uri", f"{uri!r} points outside {base}")
            if not target.is_file():
                raise self._err(f"buffers[{i}].uri", f"missing file {target}")
            data = target.read_bytes()
        if len(data) < int(b.get("byteLength", 0)):
            raise self._err(f"buffers[{i}].byteLength", f"{b.get('byteLength')} > {len(data)}")
        return data

    def accessor(self, idx: int) -> np.ndarray:
        """Accessor ``idx`` as an (count, n) or (count,) array (normalised ints -> float)."""
        field = f"accessors[{idx}]"
        try:
            acc = self.json["accessors"][idx]
            comp = _COMPONENT[acc["componentType"]]
            n = _N_COMPONENTS[acc["type"]]
            count = int(acc["count"])
        except (KeyError, IndexError, TypeError):
            raise self._err(field, "missing or unsupported componentType/type/count") from None
        if "sparse" in acc:
            raise self._err(field, "sparse accessors are not supported")
        if "bufferView" not in acc:
            return np.zeros((count, n) if n > 1 else count, dtype=comp)
        try:
            view = self.json["bufferViews"][acc["bufferView"]]
            buf = self.buffers[view["buffer"]]
        except (KeyError, IndexError, TypeError):
            raise self._err(field, "bad bufferView / buffer reference") from None
        item = np.dtype(comp).itemsize * n
        stride = int(view.get("byteStride", 0)) or item
        start = int(view.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
        end = start + (count - 1) * stride + item if count else start
        view_end = int(view.get("byteOffset", 0)) + int(view["byteLength"])
        if count < 0 or end > view_end or view_end > len(buf):
            raise self._err(field, f"reads bytes {start}..{end} past its bufferView/buffer")
        if stride == item:
            arr = np.frombuffer(buf, dtype=comp, count=count * n, offset=start)
        else:
            rows = np.frombuffer(buf, dtype=np.uint8)[
                start + np.arange(count)[:, None] * stride + np.arange(item)[None]]
            arr = rows.reshape(-1).view(comp)
        arr = arr.reshape(count, n) if n > 1 else arr.copy()
        if acc.get("normalized") and np.issubdtype(comp, np.integer):
            arr = arr.astype(np.float64) / np.iinfo(comp).max
        return np.array(arr)

    def node_worlds(self) -> np.ndarray:
        """(nodes, 4, 4) world matrices of every node in the default scene pose."""
        nodes = self.json.get("nodes", [])
        local = np.stack([_node_matrix(n, self, i) for i, n in enumerate(nodes)]) \
            if nodes else np.zeros((0, 4, 4))
        parent = np.full(len(nodes), -1)
        for i, n in enumerate(nodes):
            for c in n.get("children", []):
                if not (0 <= c < len(nodes)) or parent[c] != -1:
                    raise self._err(f"nodes[{i}].children", f"bad or shared child {c}")
                parent[c] = i
        world = np.full_like(local, np.nan)

        def solve(i, depth=0):
            if depth > len(nodes):
                raise self._err("nodes", "cycle in the node hierarchy")
            if np.isnan(world[i, 0, 0]):
                world[i] = local[i] if parent[i] < 0 else solve(parent[i], depth + 1) @ local[i]
            return world[i]

        for i in range(len(nodes)):
            solve(i)
        self.parent = parent
        return world


def _node_matrix(node: dict, g: _Gltf, i: int) -> np.ndarray:
    if "matrix" in node:
        m = np.asarray(node["matrix"], dtype=np.float64)
        if m.shape != (16,) or not np.all(np.isfinite(m)):
            raise g._err(f"nodes[{i}].matrix", "must be 16 finite numbers")
        return m.reshape(4, 4).T  # column-major in the file
    t = np.asarray(node.get("translation", [0, 0, 0]), dtype=np.float64)
    q = np.asarray(node.get("rotation", [0, 0, 0, 1]), dtype=np.float64)
    s = np.asarray(node.get("scale", [1, 1, 1]), dtype=np.float64)
    if t.shape != (3,) or q.shape != (4,) or s.shape != (3,) or not (
            np.all(np.isfinite(t)) and np.all(np.isfinite(q)) and np.all(np.isfinite(s))):
        raise g._err(f"nodes[{i}]", "translation/rotation/scale malformed")
    x, y, z, w = q / max(np.linalg.norm(q), 1e-12)
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    M = np.eye(4)
    M[:3, :3] = R * s[None]
    M[:3, 3] = t
    return M


def read_gltf_skin(path) -> dict:
    """The first skinned mesh of a glTF file, in its bind pose, in scene (world) coordinates.

    Parameters
    ----------
    path : str or Path, .glb or .gltf

    Returns
    -------
    dict with
        ``vertices`` (V, 3) float64 metres, bind pose; ``faces`` (F, 3) int32;
        ``joints`` (V, K) int (indices into ``joint_names``); ``weights`` (V, K) float64 as stored;
        ``joint_names`` tuple (J,) (``joint<i>`` for unnamed); ``joint_parents`` (J,) int, -1 for
        joints whose parent is not a joint; ``bind_matrices`` (J, 4, 4) world bind transforms;
        ``bind_positions`` (J, 3) metres.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no glTF file at {path}")
    g = _Gltf(path)
    nodes = g.json.get("nodes", [])
    skinned = [i for i, n in enumerate(nodes) if "mesh" in n and "skin" in n]
    if not skinned:
        raise ValueError(f"{path}: nodes: no node has both a mesh and a skin (missing skin)")
    node = nodes[skinned[0]]
    try:
        skin = g.json["skins"][node["skin"]]
        mesh = g.json["meshes"][node["mesh"]]
        joint_nodes = [int(j) for j in skin["joints"]]
    except (KeyError, IndexError, TypeError):
        raise ValueError(f"{path}: skins/meshes: bad skin or mesh reference") from None
    J = len(joint_nodes)
    if J == 0 or any(not 0 <= j < len(nodes) for j in joint_nodes):
        raise ValueError(f"{path}: skins[{node['skin']}].joints: empty or out of range")
    if "inverseBindMatrices" in skin:
        ibm = g.accessor(skin["inverseBindMatrices"]).astype(np.float64)
        if ibm.shape != (J, 16):
            raise ValueError(f"{path}: skins.inverseBindMatrices: shape {ibm.shape}, "
                             f"need ({J}, 16)")
        ibm = ibm.reshape(J, 4, 4).transpose(0, 2, 1)
    else:
        ibm = np.tile(np.eye(4), (J, 1, 1))
    world = g.node_worlds()
    # skin space -> scene: the root joint's default world transform times its inverse bind
    depth = np.zeros(J, int)
    for k, jn in enumerate(joint_nodes):
        p = g.parent[jn]
        while p >= 0:
            depth[k] += 1
            p = g.parent[p]
    root = int(np.argmin(depth))
    W = world[joint_nodes[root]] @ ibm[root]
    try:
        bind = W @ np.linalg.inv(ibm)
    except np.linalg.LinAlgError:
        raise ValueError(f"{path}: skins.inverseBindMatrices: singular matrix") from None

    verts, faces, joints, weights = [], [], [], []
    offset = 0
    for p_i, prim in enumerate(mesh.get("primitives", [])):
        field = f"meshes[{node['mesh']}].primitives[{p_i}]"
        if prim.get("mode", 4) != 4:
            raise ValueError(f"{path}: {field}.mode: only triangle lists (4) are supported")
        attr = prim.get("attributes", {})
        for key in ("POSITION", "JOINTS_0", "WEIGHTS_0"):
            if key not in attr:
                raise ValueError(f"{path}: {field}.attributes: missing {key}")
        pos = g.accessor(attr["POSITION"]).astype(np.float64)
        n = len(pos)
        js = [g.accessor(attr[f"JOINTS_{s}"]).astype(np.int64) for s in range(2)
              if f"JOINTS_{s}" in attr]
        ws = [g.accessor(attr[f"WEIGHTS_{s}"]).astype(np.float64) for s in range(len(js))]
        jt, wt = np.concatenate(js, 1), np.concatenate(ws, 1)
        if pos.shape != (n, 3) or jt.shape != wt.shape or len(jt) != n:
            raise ValueError(f"{path}: {field}.attributes: POSITION/JOINTS/WEIGHTS disagree")
        if jt.min() < 0 or jt.max() >= J:
            raise ValueError(f"{path}: {field}.attributes.JOINTS_0: index outside the skin")
        if not np.all(np.isfinite(pos)) or not np.all(np.isfinite(wt)) or wt.min() < 0:
            raise ValueError(f"{path}: {field}.attributes: non-finite positions or bad weights")
        idx = (g.accessor(prim["indices"]).astype(np.int64) if "indices" in prim
               else np.arange(n))
        if len(idx) % 3 or (len(idx) and (idx.min() < 0 or idx.max() >= n)):
            raise ValueError(f"{path}: {field}.indices: not triangles or out of range")
        verts.append(pos)
        faces.append(idx.reshape(-1, 3) + offset)
        joints.append(jt)
        weights.append(wt)
        offset += n
    if not verts:
        raise ValueError(f"{path}: meshes[{node['mesh']}].primitives: empty")
    width = max(j.shape[1] for j in joints)
    pad = lambda a: np.pad(a, ((0, 0), (0, width - a.shape[1])))  # noqa: E731
    v = np.concatenate(verts)
    v = v @ W[:3, :3].T + W[:3, 3]
    names = tuple(str(nodes[jn].get("name", f"joint{k}")) for k, jn in enumerate(joint_nodes))
    node_to_joint = {jn: k for k, jn in enumerate(joint_nodes)}
    parents = np.array([node_to_joint.get(int(g.parent[jn]), -1) for jn in joint_nodes])
    return {"vertices": v, "faces": np.concatenate(faces).astype(np.int32),
            "joints": np.concatenate([pad(j) for j in joints]),
            "weights": np.concatenate([pad(w) for w in weights]),
            "joint_names": names, "joint_parents": parents, "bind_matrices": bind,
            "bind_positions": bind[:, :3, 3].copy()}


def _top4(joints: np.ndarray, weights: np.ndarray, n_bones: int, path, root: int = 0):
    """Sum weights per bone, keep the four largest, renormalise. Returns joints, weights, count."""
    V = len(joints)
    dense = np.zeros((V, n_bones))
    np.add.at(dense, (np.repeat(np.arange(V), joints.shape[1]), joints.reshape(-1)),
              weights.reshape(-1))
    total = dense.sum(1)
    renorm = int(np.sum(np.abs(total - 1.0) > 1e-3))
    empty = total <= 1e-8
    if empty.any():
        log.warning("%s: %d vertices have no skin weight; bound to bone %d",
                    path, empty.sum(), root)
        dense[empty, root] = 1.0
    order = np.argsort(-dense, axis=1, kind="stable")[:, :4]
    w4 = np.take_along_axis(dense, order, 1)
    j4 = order.copy()
    if n_bones < 4:
        w4 = np.pad(w4, ((0, 0), (0, 4 - n_bones)))
        j4 = np.pad(j4, ((0, 0), (0, 4 - n_bones)))
    w4 /= w4.sum(1, keepdims=True)
    j4[w4 == 0] = 0
    if renorm:
        log.info("%s: renormalised %d weight rows", path, renorm)
    return j4, w4, renorm


def _swing(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction u onto direction v (3, 3)."""
    u = u / np.linalg.norm(u)
    v = v / np.linalg.norm(v)
    c = float(u @ v)
    axis = np.cross(u, v)
    s = np.linalg.norm(axis)
    if s < 1e-9:
        if c > 0:
            return np.eye(3)
        perp = np.cross(u, [1.0, 0, 0] if abs(u[0]) < 0.9 else [0, 1.0, 0])
        axis, s, c = perp / np.linalg.norm(perp), 1.0, -1.0
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        return np.eye(3) + 2 * K @ K
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def _fit_rotation(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rotation R minimising sum |R src_i - dst_i|^2 over unit directions (Kabsch)."""
    if len(src) == 1:
        return _swing(src[0], dst[0])
    a = src / np.linalg.norm(src, axis=1, keepdims=True)
    b = dst / np.linalg.norm(dst, axis=1, keepdims=True)
    U, _, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def load_gltf_skin(path, skeleton: Skeleton | None = None, joint_map: dict | None = None):
    """A skinned glTF body as a :class:`BodyMesh` in the gltrack rest (T-) pose.

    Parameters
    ----------
    path : str or Path
        .glb or .gltf with a skinned mesh.
    skeleton : Skeleton, optional
        Target skeleton (canonical joint names). Default: built from the file's bind joints with
        the arms straightened into a T-pose (returned as ``info["skeleton"]``).
    joint_map : dict or False, optional
        File joint name -> gltrack bone name; default :data:`MAKEHUMAN_CMU_MAP`. ``False`` loads
        the raw skin: the mesh stays in the file's bind pose and ``joints`` index the file's
        joints (``info["joint_names"]``); ``part`` is then all 0.

    Returns
    -------
    mesh : BodyMesh
        Vertices float32 metres in the target rest pose, four influences, rows sum to 1,
        ``part`` from each vertex's dominant bone.
    info : dict
        ``joint_names``, ``joint_parents``, ``bind_positions`` (file joints), ``renormalised``
        (count of weight rows that did not sum to 1), and unless raw: ``skeleton``,
        ``bind_vertices`` (V, 3), ``bone_rotations`` (B, 3, 3) rest-pose corrections.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Malformed file, no skinned mesh, or joints missing from ``joint_map`` (all listed).
    """
    if skeleton is not None and tuple(skeleton.names) != JOINT_NAMES:
        raise ValueError("load_gltf_skin: skeleton must have the canonical gltrack joints "
                         f"{JOINT_NAMES}, got {tuple(skeleton.names)}")
    raw = read_gltf_skin(path)
    info = {k: raw[k] for k in ("joint_names", "joint_parents", "bind_positions")}
    names = raw["joint_names"]
    if joint_map is False:
        j4, w4, renorm = _top4(raw["joints"], raw["weights"], len(names), path,
                               root=int(np.argmax(raw["joint_parents"] < 0)))
        info["renormalised"] = renorm
        mesh = BodyMesh(raw["vertices"], raw["faces"], j4, w4, np.zeros(len(j4), np.int32))
        return mesh, info
    jmap = MAKEHUMAN_CMU_MAP if joint_map is None else dict(joint_map)
    unknown = [n for n in names if n not in jmap]
    if unknown:
        raise ValueError(f"{path}: skins.joints: {len(unknown)} joint names not in the joint map: "
                         f"{', '.join(unknown)}")
    bad = sorted({b for b in jmap.values() if b not in JOINT_NAMES})
    if bad:
        raise ValueError(f"joint_map targets unknown gltrack bones: {', '.join(bad)}")
    bone_of = np.array([JOINT_NAMES.index(jmap[n]) for n in names])
    B = len(JOINT_NAMES)
    j4, w4, renorm = _top4(bone_of[raw["joints"]], raw["weights"], B, path)
    info["renormalised"] = renorm

    # each bone's origin is its mapped file joint nearest the root (Hips for pelvis, ...)
    depth = np.zeros(len(names), int)
    for k in range(len(names)):
        p = raw["joint_parents"][k]
        while p >= 0:
            depth[k] += 1
            p = raw["joint_parents"][p]
    bind = np.full((B, 3), np.nan)
    for b in range(B):
        ks = np.nonzero(bone_of == b)[0]
        if len(ks) == 0:
            raise ValueError(f"{path}: no file joint maps to gltrack bone {JOINT_NAMES[b]!r}")
        bind[b] = raw["bind_positions"][ks[np.argmin(depth[ks])]]
    V = raw["vertices"]
    dom = j4[:, 0]
    bind_ends = np.zeros((B, 3))
    for name in ("head", "l_wrist", "r_wrist", "l_ankle", "r_ankle"):
        b = JOINT_NAMES.index(name)
        own = V[dom == b]
        if len(own) == 0:
            raise ValueError(f"{path}: no vertex is weighted mainly to {name!r}")
        if name.endswith("ankle"):  # foot tip: farthest forward, on the sole
            fwd = (own.mean(0) - bind[b]) * [1, 0, 1]
            tip = own[np.argmax(own @ fwd)]
            bind_ends[b] = [tip[0], own[:, 1].min(), tip[2]] - bind[b]
            continue
        # head: on along the neck (the face would pull a centroid forward); hand: to its centroid
        direction = (bind[b] - bind[PARENTS[b]]) if name == "head" else own.mean(0) - bind[b]
        direction = direction / np.linalg.norm(direction)
        bind_ends[b] = direction * np.max((own - bind[b]) @ direction)

    if skeleton is None:
        skeleton = _t_pose_skeleton(bind, bind_ends)
    rest = skeleton.rest_positions()
    R = _rest_rotations(bind, bind_ends, rest, skeleton.ends)
    # LBS into the rest pose: v_rest = sum_b w_b (R_b (v - bind_b) + rest_b)
    out = np.zeros_like(V)
    for k in range(4):
        b = j4[:, k]
        out += w4[:, k, None] * (np.einsum("vij,vj->vi", R[b], V - bind[b]) + rest[b])
    part = _parts_from_bones(dom)
    info.update(skeleton=skeleton, bind_vertices=V, bone_rotations=R)
    chain = [JOINT_NAMES.index(n) for n in ("l_elbow", "l_wrist", "l_knee", "l_ankle")]
    len_file = np.linalg.norm(bind[chain] - bind[[PARENTS[c] for c in chain]], axis=1)
    len_skel = np.linalg.norm(skeleton.offsets[chain], axis=1)
    if np.any(np.abs(len_skel / len_file - 1) > 0.15):
        log.warning("%s: limb lengths differ from the target skeleton by more than 15 %%; "
                    "the skin is re-posed, not stretched", path)
    return BodyMesh(out, raw["faces"], j4, w4, part), info


def _t_pose_skeleton(bind: np.ndarray, bind_ends: np.ndarray) -> Skeleton:
    """Skeleton from bind joint positions, arm chains straightened out along +-X."""
    B = len(JOINT_NAMES)
    offsets = np.empty((B, 3))
    for b in range(B):
        p = PARENTS[b]
        offsets[b] = bind[b] if p < 0 else bind[b] - bind[p]
    ends = bind_ends.copy()
    for s, sign in (("l", 1.0), ("r", -1.0)):
        for name in ("elbow", "wrist"):
            b = JOINT_NAMES.index(f"{s}_{name}")
            offsets[b] = [sign * np.linalg.norm(offsets[b]), 0.0, 0.0]
        b = JOINT_NAMES.index(f"{s}_wrist")
        ends[b] = [sign * np.linalg.norm(ends[b]), 0.0, 0.0]
    return Skeleton(JOINT_NAMES, np.array(PARENTS), offsets, ends,
                    tuple(EULER_ORDER[n] for n in JOINT_NAMES))


def _rest_rotations(bind, bind_ends, rest, rest_ends) -> np.ndarray:
    """(B, 3, 3) world rotation per bone taking its bind directions onto its rest directions."""
    B = len(JOINT_NAMES)
    R = np.tile(np.eye(3), (B, 1, 1))
    for b in range(B):
        kids = [c for c in range(B) if PARENTS[c] == b]
        src = [bind[c] - bind[b] for c in kids]
        dst = [rest[c] - rest[b] for c in kids]
        if np.linalg.norm(bind_ends[b]) > 1e-6 and np.linalg.norm(rest_ends[b]) > 1e-6:
            src.append(bind_ends[b])
            dst.append(rest_ends[b])
        pairs = [(s, d) for s, d in zip(src, dst)
                 if np.linalg.norm(s) > 1e-6 and np.linalg.norm(d) > 1e-6]
        if pairs:
            R[b] = _fit_rotation(np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]))
        elif PARENTS[b] >= 0:
            R[b] = R[PARENTS[b]]
    return R


_PART_OF_BONE = {
    "pelvis": "pelvis", "spine_lower": "torso", "spine_upper": "torso", "neck": "torso",
    "head": "head", "l_clavicle": "torso", "r_clavicle": "torso",
    "l_shoulder": "l_upper_arm", "l_elbow": "l_forearm", "l_wrist": "l_hand",
    "r_shoulder": "r_upper_arm", "r_elbow": "r_forearm", "r_wrist": "r_hand",
    "l_hip": "l_thigh", "l_knee": "l_shin", "l_ankle": "l_foot",
    "r_hip": "r_thigh", "r_knee": "r_shin", "r_ankle": "r_foot",
}


def _parts_from_bones(bones: np.ndarray) -> np.ndarray:
    table = np.array([PARTS.index(_PART_OF_BONE[n]) for n in JOINT_NAMES], dtype=np.int32)
    return table[bones]
