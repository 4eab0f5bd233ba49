"""Body-model motion -> BVH (the ``poses.bvh`` of a results folder; opens in Blender).

Each gltrack joint becomes a BVH joint with the same name and rest offset (metres); every joint
gets three rotation channels in its own Euler order (``"ZXY"`` -> ``Zrotation Xrotation
Yrotation``, which BVH reads as ``R = Rz @ Rx @ Ry``, exactly gltrack's convention), the root also
``Xposition Yposition Zposition``. Locked DOFs are written as zeros, so the file is the same for
every DOF preset. Bone tips (head top, hands, toes) become End Sites.
"""
from __future__ import annotations

import numpy as np

from gltrack.motion.bvh import Bvh, write_bvh


def params_to_bvh(body, params, fps: float, name: str = "gltrack") -> Bvh:
    """Convert (T, D) pose parameters of ``body`` (a :class:`gltrack.body.model.BodyModel`) to BVH."""
    sk, kin = body.skeleton, body.kin
    P = body.dofs.validate(params, clamp=False)
    ang = np.degrees(kin.angles(P))  # (T, B, 3) about x, y, z
    channels, cols = [], []
    for j, order in enumerate(sk.orders):
        rot = [f"{a}rotation" for a in order.upper()]
        if j == 0:
            channels.append(["Xposition", "Yposition", "Zposition"] + rot)
            cols.append(P[:, :3])
        else:
            channels.append(rot)
        cols.append(np.stack([ang[:, j, "XYZ".index(a)] for a in order.upper()], axis=1))
    ends = {sk.names[j]: sk.ends[j] for j in range(sk.n_joints)
            if np.any(sk.ends[j] != 0) or not sk.children(j)}
    for k, v in list(ends.items()):
        if not np.any(v):
            ends[k] = np.array([0.0, 0.05, 0.0])  # BVH importers want a non-degenerate tip
    return Bvh(list(sk.names), sk.parents.copy(), sk.offsets.copy(), channels, ends,
               1.0 / float(fps), np.concatenate(cols, axis=1), 1.0, name)


def write_params_bvh(path, body, params, fps: float) -> None:
    """Write (T, D) pose parameters as a BVH file (metres, degrees)."""
    write_bvh(path, params_to_bvh(body, params, fps, name=str(path)))
