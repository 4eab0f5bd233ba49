"""Retargeting BVH motion onto the canonical gltrack body.

Two parts:

* :func:`skeleton_from_bvh` builds a gltrack :class:`~gltrack.body.skeleton.Skeleton` with the
  bone lengths of the file. Limb chains are re-aimed to the gltrack T-pose (arms along +-X,
  legs along -Y) because the joint limits and the DOF presets (which axis is twist, which is a
  hinge) are defined in that rest frame; CMU legs are splayed ~20 deg in their rest pose and the
  3ds Max conversions hang the arms down. ``rest="bvh"`` keeps the file's rest geometry instead.
* :func:`retarget` turns the BVH motion into gltrack parameters, either from the rotations
  (exact up to dropped DOFs when the body was built from the file) or by per-frame inverse
  kinematics on joint positions (for any body).

Rest correction. For every canonical joint ``c`` a constant rotation ``C_c`` relates the two rest
frames: the gltrack bone whose world rotation is ``W_g`` points where the BVH bone with world
rotation ``W_b`` points when ``W_g = W_b @ C_c``. ``C_c`` is derived from the rest bone
directions of both skeletons, chained from the parent (``C_c = R(C_p d_g -> d_b) C_p`` with the
shortest-arc rotation ``R``) so that twist is inherited and not invented.
"""
from __future__ import annotations

import logging
import math

import numpy as np
from scipy.spatial.transform import Rotation

from gltrack.body.dofs import DofSet, make_dofs
from gltrack.body.kinematics import Kinematics
from gltrack.body.skeleton import EULER_ORDER, JOINT_NAMES, PARENTS, Skeleton

from .bvh import Bvh, leading_jumps, read_bvh, resample
from .names import joint_map

log = logging.getLogger(__name__)

_ROOT = JOINT_NAMES.index("pelvis")
#: Canonical rest directions of re-aimed limb bones (subject's left is +X).
_LIMB_DIRS = {
    "l_shoulder": (1, 0, 0), "l_elbow": (1, 0, 0), "l_wrist": (1, 0, 0),
    "r_shoulder": (-1, 0, 0), "r_elbow": (-1, 0, 0), "r_wrist": (-1, 0, 0),
    "l_hip": (0, -1, 0), "l_knee": (0, -1, 0), "r_hip": (0, -1, 0), "r_knee": (0, -1, 0),
}
_EPS = 1e-9


# ---------------------------------------------------------------------- small geometry helpers
def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > _EPS, v / np.maximum(n, _EPS), 0.0)


def _shortest_arc(u, v) -> np.ndarray:
    """(..., 3, 3) rotations taking unit vectors ``u`` onto ``v`` by the shortest arc."""
    u, v = np.broadcast_arrays(_unit(u), _unit(v))
    k = np.cross(u, v)
    c = np.sum(u * v, axis=-1)
    K = np.zeros(u.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = k[..., 2], -k[..., 1], k[..., 0]
    anti = c < -1 + 1e-9
    R = np.eye(3) + K + K @ K / np.maximum(1 + c, 1e-12)[..., None, None]
    if np.any(anti):
        # half turn about any axis perpendicular to u
        uu = u[anti]
        a = np.where(np.abs(uu[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        ax = _unit(np.cross(uu, a))
        R[anti] = 2 * ax[:, :, None] * ax[:, None, :] - np.eye(3)
    degenerate = (np.linalg.norm(u, axis=-1) < 0.5) | (np.linalg.norm(v, axis=-1) < 0.5)
    R[degenerate] = np.eye(3)
    return R


# ---------------------------------------------------------------------- correspondence
class _Correspondence:
    """Which BVH joints carry each canonical joint, its bone target and its rotation driver."""

    def __init__(self, bvh: Bvh, mapping: dict | None):
        self.map = joint_map(bvh.names, mapping)
        self.b = np.array([bvh.index(self.map[c]) for c in JOINT_NAMES])
        self.rest = bvh.rest_positions()
        for c, p in enumerate(PARENTS):
            if p >= 0 and not self._is_ancestor(bvh, self.b[p], self.b[c]):
                raise ValueError(
                    f"{bvh.source}: mapped joint {self.map[JOINT_NAMES[c]]!r} "
                    f"({JOINT_NAMES[c]}) is not below {self.map[JOINT_NAMES[p]]!r} "
                    f"({JOINT_NAMES[p]}) in the BVH hierarchy")
        children = {c: [k for k, p in enumerate(PARENTS) if p == c] for c in range(len(PARENTS))}
        self.children = children
        # tips (head top, hand tip, toe) of canonical joints without canonical children
        self.tip = {}
        for c, kids in children.items():
            if not kids:
                self.tip[c] = self._tip(bvh, self.b[c])
        self.driver = np.array([self._driver(bvh, c) for c in range(len(JOINT_NAMES))])

    @staticmethod
    def _is_ancestor(bvh, a, j) -> bool:
        j = bvh.parents[j]
        while j >= 0:
            if j == a:
                return True
            j = bvh.parents[j]
        return False

    def _tip(self, bvh: Bvh, j: int):
        """Farthest rest point (joint or End Site) in the subtree of ``j``: (joint, local end)."""
        best, best_d = (j, np.zeros(3)), 0.0
        stack = [j]
        while stack:
            k = stack.pop()
            end = bvh.end_sites.get(bvh.names[k])
            cands = [(k, np.zeros(3))] + ([(k, np.asarray(end, float))] if end is not None else [])
            for jj, e in cands:
                d = np.linalg.norm(self.rest[jj] + e - self.rest[j])
                if d > best_d + 1e-12:
                    best, best_d = (jj, e), d
            stack.extend(bvh.children(k))
        return best

    def _path(self, bvh: Bvh, top: int, bottom: int) -> list[int]:
        path = [bottom]
        while path[-1] != top:
            path.append(int(bvh.parents[path[-1]]))
        return path[::-1]

    def _driver(self, bvh: Bvh, c: int) -> int:
        """BVH joint whose world rotation moves the longest BVH bone of canonical bone ``c``."""
        top = int(self.b[c])
        if c == _ROOT:
            return top
        ends = [int(self.b[k]) for k in self.children[c]]
        best, best_len = top, 0.0
        if not ends:
            tj, e = self.tip[c]
            path = self._path(bvh, top, tj)
            segs = [(path[i - 1], np.linalg.norm(bvh.offsets[path[i]]))
                    for i in range(1, len(path))]
            segs.append((tj, np.linalg.norm(e)))
        else:
            segs = []
            for e in ends:
                path = self._path(bvh, top, e)
                segs += [(path[i - 1], np.linalg.norm(bvh.offsets[path[i]]))
                         for i in range(1, len(path))]
        for j, length in segs:
            if length > best_len + 1e-12:
                best, best_len = j, length
        return best

    def bvh_rest_vectors(self):
        """Rest offsets of canonical joints, and tips of end joints, in the BVH rest frame."""
        off = np.zeros((len(JOINT_NAMES), 3))
        for c, p in enumerate(PARENTS):
            off[c] = self.rest[self.b[c]] if p < 0 else self.rest[self.b[c]] - self.rest[self.b[p]]
        ends = np.zeros((len(JOINT_NAMES), 3))
        for c, (tj, e) in self.tip.items():
            ends[c] = self.rest[tj] + e - self.rest[self.b[c]]
        return off, ends

    def target_index(self, c: int):
        """Single canonical child of ``c`` (or "tip"), or None when the bone branches."""
        kids = self.children[c]
        if not kids:
            return "tip"
        if len(kids) == 1:
            return kids[0]
        return None


def _bone_target(off: np.ndarray, ends: np.ndarray, c: int, corr: _Correspondence):
    t = corr.target_index(c)
    if t is None:
        return None
    return ends[c] if t == "tip" else off[t]


def _rest_corrections(sk_off, sk_ends, bvh_off, bvh_ends, corr, limb_dirs=None) -> np.ndarray:
    """(B, 3, 3) rest corrections ``C_c`` (see module docstring)."""
    B = len(JOINT_NAMES)
    C = np.tile(np.eye(3), (B, 1, 1))
    for c, p in enumerate(PARENTS):
        if p < 0:
            continue  # both rest frames are upright and world-aligned at the root
        Cp = C[p]
        tb = _bone_target(bvh_off, bvh_ends, c, corr)
        if limb_dirs is not None:
            d = limb_dirs.get(JOINT_NAMES[c])
            tg = None if d is None else np.asarray(d, float)
        else:
            tg = _bone_target(sk_off, sk_ends, c, corr)
        if tb is None or tg is None or np.linalg.norm(tb) < 1e-6 or np.linalg.norm(tg) < 1e-6:
            C[c] = Cp
            continue
        C[c] = _shortest_arc(Cp @ _unit(tg), _unit(tb)) @ Cp
    return C


# ---------------------------------------------------------------------- skeleton
def skeleton_from_bvh(bvh: Bvh, mapping: dict | None = None, *, rest: str = "tpose") -> Skeleton:
    """A canonical gltrack skeleton with the BVH's bone lengths.

    Parameters
    ----------
    bvh : Bvh (metres)
    mapping : dict, optional
        ``{canonical: bvh_name}`` overrides (see :func:`gltrack.motion.names.joint_map`).
    rest : {"tpose", "bvh"}
        ``"tpose"`` (default): distances between mapped joints are kept, limb bones (upper arm,
        forearm, hand, thigh, shank) are re-aimed to the gltrack T-pose directions and the
        feet follow their shank; torso, neck, head and clavicles keep the file's geometry.
        ``"bvh"``: rest joint positions equal the mapped BVH rest positions exactly.

    Returns
    -------
    Skeleton
        Offsets are differences of mapped rest positions (collapsed BVH joints vanish);
        ``ends`` of head, wrists and ankles are the farthest point (End Site or joint) of the
        mapped joint's BVH subtree; the root offset stands the rest pose on y = 0.
    """
    if rest not in ("tpose", "bvh"):
        raise ValueError(f"rest must be 'tpose' or 'bvh', got {rest!r}")
    corr = _Correspondence(bvh, mapping)
    off_b, ends_b = corr.bvh_rest_vectors()
    if rest == "bvh":
        off, ends = off_b.copy(), ends_b.copy()
    else:
        C = _rest_corrections(None, None, off_b, ends_b, corr, limb_dirs=_LIMB_DIRS)
        off, ends = off_b.copy(), ends_b.copy()
        for c, p in enumerate(PARENTS):
            if p >= 0:
                off[c] = C[p].T @ off_b[c]
        for c in corr.tip:
            ends[c] = C[c].T @ ends_b[c]
    sk = Skeleton(JOINT_NAMES, np.array(PARENTS), off, ends,
                  tuple(EULER_ORDER[n] for n in JOINT_NAMES))
    pos = sk.rest_positions() - off[0]
    lowest = min((pos[:, 1]).min(), (pos + ends)[:, 1].min())
    off[0] = (0.0, -lowest, 0.0)
    sk = sk.with_offsets(off, ends)
    log.info("%s: skeleton from BVH (%s rest), height %.3f m, mapping %s", bvh.source, rest,
             sk.height(), corr.map)
    return sk


# ---------------------------------------------------------------------- Euler extraction
def _euler_choose(L: np.ndarray, order: str, free: np.ndarray, lo: np.ndarray,
                  hi: np.ndarray) -> np.ndarray:
    """(T, 3) angles about x, y, z of rotations ``L`` (T, 3, 3) in ``order``.

    Of the two Euler solutions ``(a, b, c)`` and ``(a+pi, pi-b, c+pi)`` the one is kept whose
    locked axes are smallest and free axes least outside their limits: a knee bent past 90 deg
    is a pure x rotation only in the second solution when x is the middle axis.
    """
    a = Rotation.from_matrix(L).as_euler(order.upper())  # columns in order letters
    b = a + np.array([np.pi, 0.0, np.pi])
    b[:, 1] = np.pi - a[:, 1]
    cands = []
    for e in (a, b):
        e = (e + np.pi) % (2 * np.pi) - np.pi
        xyz = np.zeros_like(e)
        for col, letter in enumerate(order.upper()):
            xyz[:, "XYZ".index(letter)] = e[:, col]
        locked = np.where(free, 0.0, np.abs(xyz)).sum(axis=1)
        excess = np.where(free, np.maximum(lo - xyz, 0) + np.maximum(xyz - hi, 0), 0).sum(axis=1)
        cands.append((xyz, locked + excess))
    (xa, ca), (xb, cb) = cands
    take_b = cb < ca - 1e-6
    return np.where(take_b[:, None], xb, xa)


# ---------------------------------------------------------------------- retargeting
def _world_rotations(bvh: Bvh, skeleton: Skeleton, corr: _Correspondence):
    """(T, B, 3, 3) canonical world rotations reproducing the BVH bone directions."""
    P, W = bvh.fk()
    off_b, ends_b = corr.bvh_rest_vectors()
    C = _rest_corrections(skeleton.offsets, skeleton.ends, off_b, ends_b, corr)
    Wg = W[:, corr.driver] @ C[None]
    for c in range(len(JOINT_NAMES)):
        if c == _ROOT:
            continue
        t = corr.target_index(c)
        if t is None:
            continue
        if t == "tip":
            tj, e = corr.tip[c]
            cur = P[:, tj] + W[:, tj] @ e - P[:, corr.b[c]]
            tg = skeleton.ends[c]
        else:
            cur = P[:, corr.b[t]] - P[:, corr.b[c]]
            tg = skeleton.offsets[t]
        if np.linalg.norm(tg) < 1e-6:
            continue
        # collapsed BVH joints bend the canonical bone: swing it onto the true direction,
        # keeping the driver's twist
        Wg[:, c] = _shortest_arc(Wg[:, c] @ tg, cur) @ Wg[:, c]
    return P, Wg


def _axis_angle_matrix(u: np.ndarray, phi: float) -> np.ndarray:
    return Rotation.from_rotvec(_unit(u) * phi).as_matrix()


def _swing_rotvec(R: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(T, 3) rotation vectors of the swing parts of ``R = swing @ twist`` (twist about ``u``)."""
    q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
    tw = np.zeros_like(q)
    tw[:, :3] = np.outer(q[:, :3] @ u, u)
    tw[:, 3] = q[:, 3]
    n = np.linalg.norm(tw, axis=1)
    tw = np.where(n[:, None] > 1e-9, tw / np.maximum(n, 1e-9)[:, None], [0, 0, 0, 1.0])
    return (Rotation.from_quat(q) * Rotation.from_quat(tw).inv()).as_rotvec()


#: Hinge joints whose rest twist is calibrated from the motion, with the chain they twist.
_HINGES = {"l_elbow": ("l_shoulder", "l_elbow", "l_wrist"),
           "r_elbow": ("r_shoulder", "r_elbow", "r_wrist"),
           "l_knee": ("l_hip", "l_knee", "l_ankle"),
           "r_knee": ("r_hip", "r_knee", "r_ankle")}


def _calibrate_hinges(Wg: np.ndarray, skeleton: Skeleton, dofs: DofSet) -> dict:
    """Re-twist limb rest frames so each elbow/knee flexes about its preset's hinge axis.

    Bone directions do not fix a limb's rest twist: the CMU T-pose, for instance, flexes the
    elbow about an axis 30 deg off -Y, which a flexion-only elbow cannot follow. The hinge axis
    is the principal direction of the joint's swing rotation vectors (swing-twist split about
    the bone axis) over the clip; the upper limb and the bones in line with it are twisted
    about their common bone axis by the angle that maps it onto the preset's flexion axis.
    Joint positions are unchanged because every twisted bone's offsets lie on that axis.

    Modifies ``Wg`` (T, B, 3, 3) in place; returns {hinge joint: twist applied, rad}.
    """
    applied = {}
    par = np.asarray(PARENTS)
    for hinge, chain in _HINGES.items():
        h = skeleton.index(hinge)
        idx = dofs.joint_dofs(h)
        idx = idx[dofs.slot[idx] >= 0]
        u = _unit(skeleton.offsets[skeleton.index(chain[1])])  # upper-limb bone axis
        # the free axis of the hinge that is most perpendicular to the bone is its flexion axis
        axes = [(abs(np.eye(3)[a] @ u), a, i) for i, a in zip(idx, dofs.axis[idx])]
        axes = [x for x in axes if x[0] < 0.3]
        if not axes:
            continue
        _, flex_axis, flex_dof = min(axes)
        e = np.eye(3)[flex_axis]
        # twist only bones whose offsets lie on u (else positions would move); stop at the first
        # bone that is not
        twisted = []
        for name in chain:
            j = skeleton.index(name)
            kids = skeleton.children(j)
            vecs = [skeleton.offsets[k] for k in kids] or [skeleton.ends[j]]
            if all(np.linalg.norm(np.cross(_unit(v), u)) < 0.02 or np.linalg.norm(v) < 1e-6
                   for v in vecs):
                twisted.append(j)
            else:
                break
        if h not in twisted:
            continue
        local = np.swapaxes(Wg[:, par[h]], -1, -2) @ Wg[:, h]
        rv = _swing_rotvec(local, u)
        if np.linalg.norm(rv, axis=1).max() < np.radians(10):
            continue  # too little flexion to tell the axis
        w, V = np.linalg.eigh(rv.T @ rv)
        a = V[:, -1]
        # twist phi about u that maps a onto +-e: R_u(-phi) a = +-e
        v1, v2 = _unit(e - (e @ u) * u), np.cross(u, _unit(e - (e @ u) * u))
        alpha = math.atan2(a @ v2, a @ v1)
        best = None
        for phi in (alpha, alpha + np.pi, alpha - np.pi):
            Rt = _axis_angle_matrix(u, phi)
            flex = (rv @ Rt) @ e  # flexion angle about e after the re-twist
            lo, hi = dofs.lower[flex_dof], dofs.upper[flex_dof]
            bad = np.sum(np.maximum(lo - flex, 0) + np.maximum(flex - hi, 0))
            key = (round(bad, 6), abs(phi))
            if best is None or key < best[0]:
                best = (key, phi)
        phi = best[1]
        Rt = _axis_angle_matrix(u, phi)
        for j in twisted:
            Wg[:, j] = Wg[:, j] @ Rt
        applied[hinge] = float(phi)
    return applied


def retarget(bvh: Bvh, skeleton: Skeleton, dofs: DofSet, *, mapping: dict | None = None,
             method: str = "rotations", return_report: bool = False, max_nfev: int = 20):
    """Express the BVH motion as gltrack pose parameters.

    Parameters
    ----------
    bvh : Bvh (metres)
    skeleton : Skeleton with the canonical joints (usually :func:`skeleton_from_bvh` of ``bvh``)
    dofs : DofSet of ``skeleton``
    mapping : dict, optional, ``{canonical: bvh_name}`` overrides
    method : {"rotations", "ik"}
        ``"rotations"``: compose BVH rotations per canonical bone, apply rest corrections,
        convert to each joint's Euler order, keep the preset's free axes, unwrap over time,
        clamp to limits. ``"ik"``: per-frame joint-position least squares (scipy
        ``least_squares`` within the limits), warm-started from the previous frame and
        initialised with the rotation result; for bodies not built from the BVH.
    return_report : bool
        Also return a dict with ``clamped`` (total values clamped), ``clamped_per_dof``
        ({dof name: count}) and ``max_excess`` ({dof name: largest violation, rad or m}).
    max_nfev : int
        Function-evaluation cap per frame for ``"ik"``.

    Returns
    -------
    params : (T, D) float64
    report : dict, only if ``return_report``
    """
    if method not in ("rotations", "ik"):
        raise ValueError(f"method must be 'rotations' or 'ik', got {method!r}")
    if tuple(skeleton.names) != JOINT_NAMES:
        raise ValueError("retarget needs a skeleton with the canonical gltrack joints")
    corr = _Correspondence(bvh, mapping)
    P, Wg = _world_rotations(bvh, skeleton, corr)
    twists = _calibrate_hinges(Wg, skeleton, dofs)
    if twists:
        log.info("%s: limb rest twists calibrated from the motion (deg): %s", bvh.source,
                 {k: round(math.degrees(v), 1) for k, v in twists.items()})
    T, B = Wg.shape[:2]
    for j in range(1, B):
        if not np.any(dofs.slot[dofs.joint_dofs(j)] >= 0):
            # a joint the preset locks is collapsed like an unmapped BVH joint: its child
            # inherits its rotation
            Wg[:, j] = Wg[:, PARENTS[j]]
    local = np.empty_like(Wg)
    local[:, 0] = Wg[:, 0]
    par = np.asarray(PARENTS)
    local[:, 1:] = np.swapaxes(Wg[:, par[1:]], -1, -2) @ Wg[:, 1:]

    params = np.zeros((T, dofs.size))
    params[:, :3] = P[:, corr.b[_ROOT]]
    for j in range(B):
        idx = dofs.joint_dofs(j)
        idx = idx[dofs.slot[idx] >= 0]
        free = np.zeros(3, bool)
        lo, hi = np.full(3, -np.inf), np.full(3, np.inf)
        free[dofs.axis[idx]] = True
        lo[dofs.axis[idx]], hi[dofs.axis[idx]] = dofs.lower[idx], dofs.upper[idx]
        ang = _euler_choose(local[:, j], skeleton.orders[j], free, lo, hi)
        for i in idx:
            a = np.unwrap(ang[:, dofs.axis[i]])
            # an unwrapped series may sit whole turns away from its range: centre limited DOFs
            # on their median, start unlimited ones (the heading) within one turn of zero
            ref = np.median(a) if np.isfinite(dofs.upper[i] - dofs.lower[i]) else a[0]
            a -= 2 * np.pi * np.round(ref / (2 * np.pi))
            params[:, i] = a

    over = (params < dofs.lower) | (params > dofs.upper)
    excess = np.maximum(dofs.lower - params, 0) + np.maximum(params - dofs.upper, 0)
    report = {"clamped": int(over.sum()), "hinge_twist": twists,
              "clamped_per_dof": {dofs.names[i]: int(over[:, i].sum())
                                  for i in range(dofs.size) if over[:, i].any()},
              "max_excess": {dofs.names[i]: float(excess[:, i].max())
                             for i in range(dofs.size) if over[:, i].any()}}
    if report["clamped"]:
        log.warning("%s: %d of %d values clamped to joint limits (%s)", bvh.source,
                    report["clamped"], params.size,
                    ", ".join(f"{k}: {v} frames, up to {report['max_excess'][k]:.3f}"
                              for k, v in report["clamped_per_dof"].items()))
    params = np.clip(params, dofs.lower, dofs.upper)
    if method == "ik":
        params = _ik(P[:, corr.b], skeleton, dofs, params, max_nfev)
    return (params, report) if return_report else params


def _ik(targets: np.ndarray, skeleton: Skeleton, dofs: DofSet, init: np.ndarray,
        max_nfev: int) -> np.ndarray:
    """Per-frame joint-position least squares, warm-started from the previous frame."""
    from scipy.optimize import least_squares

    kin = Kinematics(skeleton, dofs)
    D = dofs.size
    h = 1e-6
    lo, hi = dofs.lower, dofs.upper
    margin = np.where(np.isfinite(lo) & np.isfinite(hi), 1e-7, 0.0)

    def fun(x, tgt):
        return (kin.forward(x[None], clamp=False).positions[0] - tgt).ravel()

    def jac(x, tgt):
        X = np.repeat(x[None], D + 1, axis=0)
        X[1:] += h * np.eye(D)
        pos = kin.forward(X, clamp=False).positions.reshape(D + 1, -1)
        return ((pos[1:] - pos[0]) / h).T

    out = np.empty_like(init)
    x = init[0]
    nfev = 0
    for t in range(len(targets)):
        # previous frame's solution, moved on by the rotation result's frame-to-frame change
        x0 = x + (init[t] - init[t - 1] if t else 0.0)
        x0 = np.clip(x0, lo + margin, hi - margin)
        res = least_squares(fun, x0, jac=jac, bounds=(lo, hi), args=(targets[t],),
                            method="trf", x_scale=1.0, max_nfev=max_nfev,
                            ftol=1e-6, xtol=1e-7, gtol=1e-8)
        x = res.x
        nfev += res.nfev
        out[t] = x
    log.info("ik: %d frames, %.1f evaluations per frame", len(targets), nfev / max(len(targets), 1))
    return out


def retarget_error(bvh: Bvh, skeleton: Skeleton, dofs: DofSet, params,
                   mapping: dict | None = None) -> dict:
    """Joint-position error of retargeted parameters against the BVH.

    Parameters
    ----------
    bvh, skeleton, dofs : as for :func:`retarget`
    params : (T, D) float, as returned by :func:`retarget`

    Returns
    -------
    dict with ``mean_mm`` and ``max_mm`` (float, over all frames and the 19 mapped joints),
    ``per_joint_mm`` ({canonical name: mean error, mm}) and ``worst_joint``.
    """
    corr = _Correspondence(bvh, mapping)
    P, _ = bvh.fk()
    params = np.asarray(params, dtype=np.float64)
    if params.shape[0] != P.shape[0]:
        raise ValueError(f"params has {params.shape[0]} frames, the BVH {P.shape[0]}")
    pose = Kinematics(skeleton, dofs).forward(params)
    err = np.linalg.norm(pose.positions - P[:, corr.b], axis=-1) * 1000.0
    per = {n: float(err[:, i].mean()) for i, n in enumerate(JOINT_NAMES)}
    return {"mean_mm": float(err.mean()), "max_mm": float(err.max()), "per_joint_mm": per,
            "worst_joint": max(per, key=per.get)}


def _frame_slice(frames) -> slice:
    if frames is None:
        return slice(None)
    if isinstance(frames, slice):
        return frames
    if isinstance(frames, str):
        a, sep, b = frames.partition(":")
        if not sep:
            raise ValueError(f"frames must look like 'A:B', got {frames!r}")
        return slice(int(a) if a.strip() else None, int(b) if b.strip() else None)
    a, b = frames
    return slice(a, b)


def load_motion(path, preset: str = "full", fps: float | None = None, frames=None,
                mapping: dict | None = None, scale=None, skip_jumps: bool = False):
    """Read a BVH clip and express it on a gltrack body built from it.

    Parameters
    ----------
    path : str or Path
    preset : str, DOF preset (see :func:`gltrack.body.dofs.make_dofs`)
    fps : float, optional
        Resample to this frame rate (slerped rotations); default keeps the file's rate.
    frames : (A, B), slice or "A:B", optional
        Source frames to keep (in the file's frame numbering), before resampling.
    mapping : dict, optional, joint-name overrides
    scale : None, "auto" or float, see :func:`gltrack.motion.bvh.read_bvh`
    skip_jumps : bool
        Leave out leading frames of the selection that are discontinuities (CMU clips open
        with a T-pose frame; :func:`gltrack.motion.bvh.leading_jumps`), with a logged warning.

    Returns
    -------
    skeleton : Skeleton
    dofs : DofSet
    params : (T, D) float64
    fps : float, frames per second of ``params``
    """
    bvh = read_bvh(path, scale=scale)
    sl = _frame_slice(frames)
    if skip_jumps:
        first, last, step = sl.indices(bvh.n_frames)
        if step == 1 and last > first:
            n_skip, jump, typical = leading_jumps(bvh, first, last)
            if n_skip:
                ratio = f"{jump / typical:.0f}x" if typical > 0 else "far above"
                log.warning("%s: skipped source frame%s %s (a discontinuity: a %.2f m joint jump "
                            "to the next frame, %s the clip's median per frame; e.g. a "
                            "T-pose frame)", path, "s" if n_skip > 1 else "",
                            f"{first}..{first + n_skip - 1}" if n_skip > 1 else first,
                            jump, ratio)
                sl = slice(first + n_skip, last)
                frames = sl
    if frames is not None:
        bvh = bvh.select_frames(sl)
        if bvh.n_frames == 0:
            raise ValueError(f"{path}: frames {frames!r} select no frames")
    # "Frame Time: .0083333" means 120 frames/s: snap rates within 1e-4 of an integer
    src_fps = bvh.fps
    if abs(src_fps - round(src_fps)) < 1e-4 * src_fps:
        src_fps = float(round(src_fps))
    out_fps = src_fps
    if fps is not None and not math.isclose(fps, src_fps, rel_tol=1e-9):
        bvh = resample(bvh, src_fps, fps)
        out_fps = float(fps)
    skeleton = skeleton_from_bvh(bvh, mapping)
    dofs = make_dofs(skeleton, preset)
    params = retarget(bvh, skeleton, dofs, mapping=mapping)
    return skeleton, dofs, params, out_fps
