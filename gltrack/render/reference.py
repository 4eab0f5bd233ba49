"""Independent CPU oracle for the GPU scoring engine: skinning, rasterisation and costs in numpy.

This module is the twin the GL engine (``gltrack.render.engine``) is tested against, so it
deliberately shares no code with it and never touches OpenGL. Everything is float64.

Conventions (identical to the engine's, stated once here):

* Candidates are posed by linear blend skinning with ``(N, B, 3, 4)`` matrices from
  ``Kinematics.skinning_matrices``.
* Pinhole camera, no distortion, OpenCV axes: ``X_cam = R @ X_world + t``;
  ``u = fx * x / z + cx``, ``v = fy * y / z + cy``. Pixel (column ``i``, row ``r``) has its
  centre at ``(u, v) = (i, r)``; row 0 is the top of the image.
* A pixel is covered by a triangle iff its centre lies inside the projected triangle, either
  winding, edges inclusive (no culling). Triangles with any vertex at ``z < near`` are dropped,
  as are triangles of zero screen area.
* Depth = camera-frame ``z`` (metres) of the nearest surface at the pixel centre, interpolated
  perspective-correctly (``1/z`` is affine in screen space). Exact depth ties go to the lower
  face index (what a ``GL_LESS`` depth test gives when faces are drawn in order).
* Empty pixels: depth ``0.0``, triangle id ``-1``.
* Costs are sums over all pixels of one image (see each function).
"""
from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger(__name__)

#: Most (triangle x pixel) edge-function evaluations held in memory at once by the rasteriser.
_CHUNK_ELEMENTS = 1 << 20


# ---------------------------------------------------------------------------------------------
# geometry


def skin_vertices(mesh, skinning: np.ndarray) -> np.ndarray:
    """Linear blend skinning by blending matrices per vertex (not points, unlike ``BodyMesh.skin``).

    Parameters
    ----------
    mesh : gltrack.body.mesh.BodyMesh
    skinning : (N, B, 3, 4) float, skinning matrices

    Returns
    -------
    (N, V, 3) float64, posed world positions, metres
    """
    S = np.asarray(skinning, dtype=np.float64)
    if S.ndim != 4 or S.shape[2:] != (3, 4):
        raise ValueError(f"skinning must have shape (N, B, 3, 4), got {S.shape}")
    if mesh.n_vertices and int(mesh.joints.max()) >= S.shape[1]:
        raise ValueError(f"mesh references bone {int(mesh.joints.max())} but skinning has "
                         f"{S.shape[1]} bones")
    w = mesh.weights.astype(np.float64)
    # (N, V, 3, 4): one blended affine matrix per vertex
    M = np.zeros((S.shape[0], mesh.n_vertices, 3, 4))
    for k in range(mesh.joints.shape[1]):
        M += w[None, :, k, None, None] * S[:, mesh.joints[:, k]]
    v = mesh.vertices.astype(np.float64)
    return np.einsum("nvij,vj->nvi", M[..., :3], v) + M[..., 3]


def world_to_camera(points: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """OpenCV extrinsics: ``(..., 3)`` world points, metres -> ``(..., 3)`` camera-frame points."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(3)
    if R.shape != (3, 3):
        raise ValueError(f"R must be (3, 3), got {R.shape}")
    return np.asarray(points, dtype=np.float64) @ R.T + t


def _check_K(K) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K must be (3, 3), got {K.shape}")
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise ValueError("K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
    return K


def rasterize(verts_cam: np.ndarray, faces: np.ndarray, K: np.ndarray, width: int, height: int,
              near: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer rasterisation of a camera-frame triangle mesh at pixel centres.

    Parameters
    ----------
    verts_cam : (V, 3) float, camera-frame vertex positions (OpenCV axes), metres
    faces : (F, 3) int, vertex indices
    K : (3, 3) float, intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, pixels
    width, height : int, image size in pixels
    near : float, metres; triangles with any vertex at ``z < near`` are dropped

    Returns
    -------
    depth : (H, W) float64, camera ``z`` of the nearest surface, metres (0 where empty)
    tri : (H, W) int32, face index of the nearest surface (-1 where empty)
    """
    K = _check_K(K)
    W, H = int(width), int(height)
    if W <= 0 or H <= 0:
        raise ValueError(f"image size must be positive, got {W}x{H}")
    P = np.asarray(verts_cam, dtype=np.float64)
    F = np.asarray(faces)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"verts_cam must be (V, 3), got {P.shape}")
    if F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"faces must be (F, 3), got {F.shape}")
    F = F.astype(np.int64)
    if len(F) and (F.min() < 0 or F.max() >= len(P)):
        raise ValueError(f"faces index vertices 0..{len(P) - 1}, found {F.min()}..{F.max()}")
    depth = np.zeros((H, W))
    tri = np.full((H, W), -1, dtype=np.int32)
    if len(F) == 0:
        return depth, tri

    z = P[:, 2]
    zs = np.where(z > 0, z, 1.0)  # placeholder avoids division warnings; those faces are dropped
    u = K[0, 0] * P[:, 0] / zs + K[0, 2]
    v = K[1, 1] * P[:, 1] / zs + K[1, 2]

    fu, fv, fz = u[F], v[F], z[F]  # (F, 3)
    with np.errstate(invalid="ignore"):  # inf - inf from non-finite vertices: dropped below
        area = ((fu[:, 1] - fu[:, 0]) * (fv[:, 2] - fv[:, 0])
                - (fu[:, 2] - fu[:, 0]) * (fv[:, 1] - fv[:, 0]))
    c0 = np.maximum(np.ceil(fu.min(1)), 0)
    c1 = np.minimum(np.floor(fu.max(1)), W - 1)
    r0 = np.maximum(np.ceil(fv.min(1)), 0)
    r1 = np.minimum(np.floor(fv.max(1)), H - 1)
    # comparisons with NaN are False, so faces touching non-finite vertices drop out here
    keep = (fz.min(1) >= near) & (area != 0) & np.isfinite(area) & (c1 >= c0) & (r1 >= r0)
    ids = np.nonzero(keep)[0]
    if len(ids) == 0:
        return depth, tri
    bw = (c1[ids] - c0[ids] + 1).astype(np.int64)
    bh = (r1[ids] - r0[ids] + 1).astype(np.int64)
    # Group triangles of similar box size so padding each chunk to its largest box wastes little.
    order = np.argsort(bw * bh, kind="stable")
    ids, bw, bh = ids[order], bw[order], bh[order]

    pix_all, z_all, tri_all = [], [], []
    start = 0
    while start < len(ids):
        stop = start + 1
        mw, mh = bw[start], bh[start]
        # grow the chunk while the padded (T, mh, mw) block stays within budget
        while stop < len(ids):
            nw, nh = max(mw, bw[stop]), max(mh, bh[stop])
            if (stop - start + 1) * nw * nh > _CHUNK_ELEMENTS:
                break
            mw, mh, stop = nw, nh, stop + 1
        cid = ids[start:stop]
        px = c0[cid, None, None] + np.arange(mw)[None, None, :]  # (T, 1, mw)
        py = r0[cid, None, None] + np.arange(mh)[None, :, None]  # (T, mh, 1)
        U, Vv, Z, Fc = fu[cid], fv[cid], fz[cid], F[cid]
        inv_area = 1.0 / area[cid][:, None, None]
        rows = np.arange(len(cid))

        def edge(a, b):
            # Twice the signed area of (vertex a, vertex b, pixel centre). Evaluated from the
            # lower vertex id and negated when needed, so that two faces sharing an edge get
            # bit-identical values of opposite sign: no pixel centre on a shared edge is lost.
            swap = Fc[:, a] > Fc[:, b]
            ia, ib = np.where(swap, b, a), np.where(swap, a, b)
            ua, va = U[rows, ia][:, None, None], Vv[rows, ia][:, None, None]
            ub, vb = U[rows, ib][:, None, None], Vv[rows, ib][:, None, None]
            e = (ub - ua) * (py - va) - (vb - va) * (px - ua)
            return np.where(swap[:, None, None], -e, e)

        b0 = edge(1, 2) * inv_area
        b1 = edge(2, 0) * inv_area
        b2 = edge(0, 1) * inv_area
        inside = (b0 >= 0) & (b1 >= 0) & (b2 >= 0)
        inside &= (px <= c1[cid, None, None]) & (py <= r1[cid, None, None])
        t_idx, yy, xx = np.nonzero(inside)
        invz = (b0[t_idx, yy, xx] / Z[t_idx, 0] + b1[t_idx, yy, xx] / Z[t_idx, 1]
                + b2[t_idx, yy, xx] / Z[t_idx, 2])
        pix_all.append(py[t_idx, yy, 0] * W + px[t_idx, 0, xx])
        z_all.append(1.0 / invz)
        tri_all.append(cid[t_idx])
        start = stop

    pix = np.concatenate(pix_all).astype(np.int64)
    zz = np.concatenate(z_all)
    tt = np.concatenate(tri_all)
    if len(pix) == 0:
        return depth, tri
    srt = np.lexsort((tt, zz, pix))  # by pixel, then depth, then face index
    pix, zz, tt = pix[srt], zz[srt], tt[srt]
    first = np.ones(len(pix), dtype=bool)
    first[1:] = pix[1:] != pix[:-1]
    depth.reshape(-1)[pix[first]] = zz[first]
    tri.reshape(-1)[pix[first]] = tt[first]
    return depth, tri


def render_candidates(mesh, skinning: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                      width: int, height: int, near: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Skin and rasterise N candidate poses for one camera.

    Parameters
    ----------
    mesh : gltrack.body.mesh.BodyMesh
    skinning : (N, B, 3, 4) float, skinning matrices
    K : (3, 3) float, intrinsics, pixels
    R : (3, 3) float, world->camera rotation (OpenCV)
    t : (3,) float, world->camera translation, metres
    width, height : int, pixels
    near : float, metres

    Returns
    -------
    depth : (N, H, W) float64, metres (0 = empty)
    tri : (N, H, W) int32, face index (-1 = empty)
    """
    S = np.asarray(skinning, dtype=np.float64)
    if S.ndim != 4:
        raise ValueError(f"skinning must have shape (N, B, 3, 4), got {S.shape}")
    N = S.shape[0]
    depth = np.zeros((N, int(height), int(width)))
    tri = np.full((N, int(height), int(width)), -1, dtype=np.int32)
    for n in range(N):
        posed = skin_vertices(mesh, S[n:n + 1])[0]  # one at a time bounds memory for large N
        depth[n], tri[n] = rasterize(world_to_camera(posed, R, t), mesh.faces, K,
                                     width, height, near)
    return depth, tri


# ---------------------------------------------------------------------------------------------
# costs


def smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    """GLSL ``smoothstep``: ``t = clamp((x - e0) / (e1 - e0), 0, 1); t * t * (3 - 2 t)``."""
    t = np.clip((np.asarray(x, dtype=np.float64) - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _pixel_cost(z_obs, z_model, scale, c_model_only, c_obs_only):
    """Ganapathi's per-pixel depth cost; 0 in an input means 'absent'."""
    has_o = z_obs > 0
    has_m = z_model > 0
    both = smoothstep(0.0, scale, np.abs(z_obs - z_model))
    return np.where(has_o & has_m, both,
                    np.where(has_m, c_model_only, np.where(has_o, c_obs_only, 0.0)))


def _same_shape(name_a, a, name_b, b):
    if a.shape != b.shape:
        raise ValueError(f"{name_a} {a.shape} and {name_b} {b.shape} must have the same shape")


def depth_cost(model_z: np.ndarray, obs_z: np.ndarray, *, scale: float = 0.15,
               c_model_only: float = 1.0, c_obs_only: float = 1.0, smooth: bool = False,
               penalty: float = 0.02) -> float:
    """Ganapathi (2010) depth cost of one rendered image against one observation.

    Per pixel, with ``d = |z_obs - z_model|``: ``smoothstep(0, scale, d)`` where both are present,
    ``c_model_only`` / ``c_obs_only`` where only one is, 0 where neither. With ``smooth=True``
    (Ganapathi's L_smooth) each pixel ``k`` instead takes the minimum over the in-image 3x3
    neighbours ``j`` of ``pixelcost(z_obs[k], model_z[j]) + (penalty if j != k else 0)``.

    Parameters
    ----------
    model_z : (H, W) float, rendered depth, metres (0 = no model)
    obs_z : (H, W) float, observed depth, metres (0 = no observation)
    scale : float, metres, distance at which the both-present cost saturates at 1
    c_model_only, c_obs_only : float, costs of one-sided pixels
    smooth : bool, use the 3x3 minimum
    penalty : float, added for a neighbour other than the pixel itself

    Returns
    -------
    float, the sum over all pixels
    """
    m = np.asarray(model_z, dtype=np.float64)
    o = np.asarray(obs_z, dtype=np.float64)
    _same_shape("model_z", m, "obs_z", o)
    if m.ndim != 2:
        raise ValueError(f"model_z must be (H, W), got {m.shape}")
    if not scale > 0:
        raise ValueError(f"scale must be positive, got {scale}")
    if not smooth:
        return float(_pixel_cost(o, m, scale, c_model_only, c_obs_only).sum())
    H, W = m.shape
    padded = np.zeros((H + 2, W + 2))
    padded[1:-1, 1:-1] = m
    inside = np.zeros((H + 2, W + 2), dtype=bool)
    inside[1:-1, 1:-1] = True
    best = np.full((H, W), np.inf)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            mj = padded[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
            ok = inside[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
            c = _pixel_cost(o, mj, scale, c_model_only, c_obs_only)
            if dy or dx:
                c = c + penalty
            best = np.minimum(best, np.where(ok, c, np.inf))
    return float(best.sum())


def silhouette_cost(model_mask: np.ndarray, fg_mask: np.ndarray,
                    block_mask: np.ndarray | None = None) -> float:
    """Bandouch's silhouette cost: pixels where model and foreground disagree, minus blocked ones.

    Parameters
    ----------
    model_mask : (H, W) bool, or a depth image (covered where ``> 0``)
    fg_mask : (H, W) bool, observed foreground
    block_mask : (H, W) bool or None, True = ignore the pixel

    Returns
    -------
    float, ``count((model XOR fg) AND NOT block)``
    """
    m, f, keep = _masks(model_mask, fg_mask, block_mask)
    return float(np.count_nonzero((m ^ f) & keep))


def _masks(model_mask, fg_mask=None, block_mask=None):
    """(model, foreground, unblocked) as (H, W) bool arrays of one shape (foreground None when
    not given); a depth image covers where ``> 0``."""
    m = np.asarray(model_mask)
    m = m if m.dtype == bool else m > 0
    f = None
    if fg_mask is not None:
        f = np.asarray(fg_mask).astype(bool)
        _same_shape("model_mask", m, "fg_mask", f)
    keep = np.ones_like(m)
    if block_mask is not None:
        b = np.asarray(block_mask).astype(bool)
        _same_shape("model_mask", m, "block_mask", b)
        keep = ~b
    return m, f, keep


def model_area(model_mask: np.ndarray, block_mask: np.ndarray | None = None) -> float:
    """The engine's ``model`` channel: pixels the model covers outside the blocking mask.

    Parameters
    ----------
    model_mask : (H, W) bool, or a depth image (covered where ``> 0``)
    block_mask : (H, W) bool or None, True = ignore the pixel

    Returns
    -------
    float, ``count(model AND NOT block)``
    """
    m, _, keep = _masks(model_mask, None, block_mask)
    return float(np.count_nonzero(m & keep))


def silhouette_iou(model_mask: np.ndarray, fg_mask: np.ndarray,
                   block_mask: np.ndarray | None = None) -> float:
    """Silhouette IoU of model and foreground over the unblocked pixels, counted directly.

    Parameters
    ----------
    model_mask : (H, W) bool, or a depth image (covered where ``> 0``)
    fg_mask : (H, W) bool, observed foreground
    block_mask : (H, W) bool or None, True = ignore the pixel

    Returns
    -------
    float in 0..1, ``count(M & F & ~B) / count((M | F) & ~B)``; NaN when the union is empty
    (nothing to compare)
    """
    return silhouette_overlap(model_mask, fg_mask, block_mask)[0]


def silhouette_overlap(model_mask: np.ndarray, fg_mask: np.ndarray,
                       block_mask: np.ndarray | None = None) -> tuple[float, float, float]:
    """IoU, share of the model on the foreground and share of the foreground covered,
    counted directly over the unblocked pixels (the twin of
    :func:`gltrack.render.engine.silhouette_overlap`).

    Returns
    -------
    (iou, model_on_fg, fg_covered) floats in 0..1: ``|M & F| / |M | F|``, ``|M & F| / |M|``,
    ``|M & F| / |F|``; NaN where the denominator is empty
    """
    m, f, keep = _masks(model_mask, fg_mask, block_mask)
    both = float(np.count_nonzero(m & f & keep))

    def share(n):
        return both / n if n else float("nan")
    return (share(np.count_nonzero((m | f) & keep)), share(np.count_nonzero(m & keep)),
            share(np.count_nonzero(f & keep)))


def appearance_score(tri: np.ndarray, obs_bits: np.ndarray, tri_bits: np.ndarray,
                     block_mask: np.ndarray | None = None) -> float:
    """Bandouch's appearance score: covered pixels whose colour bits match the triangle's clusters.

    Parameters
    ----------
    tri : (H, W) int, face index per pixel (-1 = empty)
    obs_bits : (H, W, 3) uint32, observed hue / lightness / saturation bitmasks
    tri_bits : (F, 3) uint32, per-face cluster bitmasks in the same three channels
    block_mask : (H, W) bool or None, True = ignore the pixel

    Returns
    -------
    float, the number of covered, unblocked pixels where all three channels share a bit
    """
    tri = np.asarray(tri)
    ob = np.asarray(obs_bits)
    tb = np.asarray(tri_bits)
    if ob.shape != tri.shape + (3,):
        raise ValueError(f"obs_bits must be {tri.shape + (3,)}, got {ob.shape}")
    if tb.ndim != 2 or tb.shape[1] != 3:
        raise ValueError(f"tri_bits must be (F, 3), got {tb.shape}")
    if tri.size and tri.max() >= len(tb):
        raise ValueError(f"tri refers to face {int(tri.max())} but tri_bits has {len(tb)} rows")
    covered = tri >= 0
    if block_mask is not None:
        b = np.asarray(block_mask).astype(bool)
        _same_shape("tri", tri, "block_mask", b)
        covered &= ~b
    bits = tb.astype(np.uint32)[np.where(covered, tri, 0)]  # (H, W, 3)
    match = np.all((ob.astype(np.uint32) & bits) != 0, axis=-1)
    return float(np.count_nonzero(match & covered))


# ---------------------------------------------------------------------------------------------
# scores of N candidates for one camera


def score_depth(mesh, skinning, K, R, t, width, height, obs_z, *, near: float = 0.05,
                **cost_kw) -> np.ndarray:
    """Depth cost (:func:`depth_cost`) of N candidates in one camera.

    Parameters
    ----------
    mesh, skinning, K, R, t, width, height, near : see :func:`render_candidates`
    obs_z : (H, W) float, observed depth, metres (0 = none)
    **cost_kw : keyword arguments of :func:`depth_cost`

    Returns
    -------
    (N,) float64
    """
    depth, _ = render_candidates(mesh, skinning, K, R, t, width, height, near)
    return np.array([depth_cost(d, obs_z, **cost_kw) for d in depth])


def score_silhouette(mesh, skinning, K, R, t, width, height, fg_mask, block_mask=None, *,
                     near: float = 0.05) -> np.ndarray:
    """Silhouette cost (:func:`silhouette_cost`) of N candidates in one camera; (N,) float64."""
    depth, _ = render_candidates(mesh, skinning, K, R, t, width, height, near)
    return np.array([silhouette_cost(d > 0, fg_mask, block_mask) for d in depth])


def score_appearance(mesh, skinning, K, R, t, width, height, obs_bits, tri_bits,
                     block_mask=None, *, near: float = 0.05) -> np.ndarray:
    """Appearance score (:func:`appearance_score`) of N candidates in one camera; (N,) float64."""
    _, tri = render_candidates(mesh, skinning, K, R, t, width, height, near)
    return np.array([appearance_score(tr, obs_bits, tri_bits, block_mask) for tr in tri])
