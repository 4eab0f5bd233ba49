"""Local descriptors of interest points for the part classifier.

Each interest point gets a square depth patch of fixed *metric* side (so its pixel size shrinks
with distance), rotated so that its "down" axis points along the geodesic path towards the body
centre (so a hand looks the same whichever way the arm points), sampled on an ``n x n`` grid
with nearest-neighbour look-ups (interpolation would blend a limb with the background behind
it). Depths are relative to the interest point and scaled by half the patch side, clipped to
[-1, 1]; background and invalid pixels read +1 ("far").

Feature vector layout (``n * n + len(GEOMETRY)`` floats):
``patch`` row-major (row 0 = the side away from the centre), then :data:`GEOMETRY`.
"""
from __future__ import annotations

import logging

import numpy as np

from .detect import InterestPoints

log = logging.getLogger(__name__)

#: Scalar features appended to the patch, in order.
GEOMETRY = ("centre_distance", "agex_geodesic", "height_above_centre", "dir_u", "dir_v")


def n_features(n: int = 12) -> int:
    """Length of the feature vector for an ``n x n`` patch."""
    return n * n + len(GEOMETRY)


def patch_features(depth, camera, ip: InterestPoints, fg=None, *, size: float = 0.30,
                   n: int = 12, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Feature vectors of interest points.

    Parameters
    ----------
    depth : (H, W) float, metres, 0 = invalid
    camera : gltrack.camera.Camera of ``depth``
    ip : InterestPoints of this frame
    fg : (H, W) bool, optional, the foreground used for detection; pixels outside read "far"
    size : float, metres, patch side
    n : int, patch samples per side
    up : (3,) float, world up direction for ``height_above_centre``

    Returns
    -------
    (k, n*n + 5) float32
    """
    z = np.asarray(depth, dtype=np.float64)
    H, W = z.shape
    valid = np.isfinite(z) & (z > 0)
    if fg is not None:
        valid &= np.asarray(fg, dtype=bool)
    k = len(ip)
    out = np.empty((k, n_features(n)), dtype=np.float32)
    if k == 0:
        return out
    g = (np.arange(n) + 0.5) / n * 2.0 - 1.0  # sample offsets in half-sides, [-1, 1]
    a, b = np.meshgrid(g, g)  # a across (columns), b along (rows); row 0 faces away from centre
    f = 0.5 * (camera.fx + camera.fy)
    half = 0.5 * size
    for i in range(k):
        z0 = ip.points_cam[i, 2]
        hp = half * f / z0  # half-side in pixels at the point's depth
        d_down = ip.direction[i]
        d_right = np.array([-d_down[1], d_down[0]])
        u = ip.pixels[i, 0] + hp * (a * d_right[0] + b * d_down[0])
        v = ip.pixels[i, 1] + hp * (a * d_right[1] + b * d_down[1])
        ui, vi = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
        inside = (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
        vals = np.ones((n, n))
        uc, vc = np.clip(ui, 0, W - 1), np.clip(vi, 0, H - 1)
        ok = inside & valid[vc, uc]
        vals[ok] = np.clip((z[vc, uc][ok] - z0) / half, -1.0, 1.0)
        out[i, :n * n] = vals.ravel()
    upv = np.asarray(up, dtype=np.float64)
    upv = upv / np.linalg.norm(upv)
    out[:, n * n] = ip.centre_distance
    out[:, n * n + 1] = ip.geodesic
    out[:, n * n + 2] = (ip.points - ip.centre_point) @ upv
    out[:, n * n + 3:] = ip.direction
    return out
