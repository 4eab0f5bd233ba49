"""Interest points at geodesic extrema of a measured depth surface (AGEX).

Plagemann, Ganapathi, Koller & Thrun (ICRA 2010), used by Ganapathi et al. (CVPR 2010) for their
part detections: the foreground pixels of a depth image form a graph whose 8-neighbour edges are
weighted by the 3-D distance of the back-projected points; edges that jump across a depth
discontinuity are cut so a hand in front of the chest is not connected to it. Starting from the
pixel nearest the centroid of the largest connected component (smaller pieces cut off by a
discontinuity are linked back through their shortest 3-D gap), the pixel with the largest
geodesic distance is an extremum (head, hand, foot tips, in a typical pose); it becomes a source
too, and the next extremum is the pixel farthest from *all* sources, and so on.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

log = logging.getLogger(__name__)

#: (row, column) steps of the four "forward" 8-neighbours; the graph is undirected.
_STEPS = ((0, 1), (1, 0), (1, 1), (1, -1))


@dataclass
class InterestPoints:
    """Geodesic extrema of one depth frame, in the order found.

    Attributes
    ----------
    pixels : (k, 2) float64, ``(u, v)`` = (column, row) pixel coordinates
    points : (k, 3) float64, world positions, metres
    points_cam : (k, 3) float64, camera-frame positions (OpenCV axes), metres
    geodesic : (k,) float64, metres, geodesic distance to the nearest earlier source (the AGEX
        score at selection; decreases along the list)
    centre_distance : (k,) float64, metres, geodesic distance to the centre pixel
    direction : (k, 2) float64, unit image vector from the point towards the centre along the
        shortest geodesic path (its first ``step_back`` metres); orients the local patch
    centre_pixel : (2,) float64, ``(u, v)`` of the start pixel
    centre_point : (3,) float64, world position of the start pixel, metres
    n_pixels : int, pixels in the (linked) surface that was searched
    """

    pixels: np.ndarray
    points: np.ndarray
    points_cam: np.ndarray
    geodesic: np.ndarray
    centre_distance: np.ndarray
    direction: np.ndarray
    centre_pixel: np.ndarray
    centre_point: np.ndarray
    n_pixels: int

    def __len__(self) -> int:
        return len(self.pixels)

    @classmethod
    def empty(cls) -> "InterestPoints":
        z2, z3 = np.zeros((0, 2)), np.zeros((0, 3))
        return cls(z2, z3, z3.copy(), np.zeros(0), np.zeros(0), z2.copy(),
                   np.full(2, np.nan), np.full(3, np.nan), 0)


def foreground_mask(depth, *, mask=None, background=None, bg_threshold: float = 0.08,
                    min_depth: float = 0.05, max_depth: float = np.inf) -> np.ndarray:
    """Valid foreground pixels of a depth image.

    Parameters
    ----------
    depth : (H, W) float, metres, 0 = invalid
    mask : (H, W) bool, optional, known foreground (e.g. a dataset's ``cam0_mask``)
    background : (H, W) float, metres, optional, empty-scene depth; a pixel is foreground when
        it is at least ``bg_threshold`` metres in front of the background, or the background is
        invalid there
    bg_threshold, min_depth, max_depth : float, metres

    Returns
    -------
    (H, W) bool
    """
    z = np.asarray(depth, dtype=np.float64)
    if z.ndim != 2:
        raise ValueError(f"depth must be (H, W), got {z.shape}")
    fg = np.isfinite(z) & (z > min_depth) & (z < max_depth)
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != z.shape:
            raise ValueError(f"mask {m.shape} and depth {z.shape} differ in shape")
        fg &= m
    if background is not None:
        b = np.asarray(background, dtype=np.float64)
        if b.shape != z.shape:
            raise ValueError(f"background {b.shape} and depth {z.shape} differ in shape")
        fg &= ~(b > 0) | (z < b - bg_threshold)
    return fg


def _surface_graph(fg: np.ndarray, P: np.ndarray, index: np.ndarray, max_edge: float):
    """Sparse symmetric graph of 8-neighbour edges shorter than ``max_edge`` (3-D, metres)."""
    H, W = fg.shape
    rows, cols, wts = [], [], []
    for dr, dc in _STEPS:
        r0, r1 = 0, H - dr
        c0, c1 = max(0, -dc), W - max(0, dc)
        a = fg[r0:r1, c0:c1] & fg[r0 + dr:r1 + dr, c0 + dc:c1 + dc]
        ia = index[r0:r1, c0:c1][a]
        ib = index[r0 + dr:r1 + dr, c0 + dc:c1 + dc][a]
        d = np.linalg.norm(P[ia] - P[ib], axis=1)
        keep = d <= max_edge
        rows.append(ia[keep])
        cols.append(ib[keep])
        # an explicit zero would be read as "no edge": coincident points get a tiny weight
        wts.append(np.maximum(d[keep], 1e-9))
    n = len(P)
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(wts)
    return coo_matrix((np.concatenate([w, w]), (np.concatenate([r, c]), np.concatenate([c, r]))),
                      shape=(n, n)).tocsr()


def _link_components(G, P, labels, sizes, big, max_gap, min_link_pixels):
    """Attach smaller components to the largest one through their shortest 3-D gaps.

    A limb seen end-on, or one crossing in front of the body, is cut from the rest by the
    depth-discontinuity test; dropping it would lose exactly the hands and feet the detector
    is for. Components are merged greedily, nearest first (a spanning tree over components),
    each through one edge as long as the gap itself; those farther than ``max_gap`` from
    everything merged (other objects, noise) stay out.

    Returns
    -------
    keep : (n,) int64, node indices of the merged set
    G : csr_matrix with the linking edges added
    """
    merged = [int(big)]
    rest = [c for c in np.nonzero(sizes >= min_link_pixels)[0] if c != big]
    if not rest or not max_gap > 0:
        return np.nonzero(labels == big)[0], G
    members = {c: np.nonzero(labels == c)[0] for c in rest + [big]}
    extra_r, extra_c, extra_w = [], [], []
    while rest:
        core = np.concatenate([members[c] for c in merged])
        tree = cKDTree(P[core])
        best = None
        for c in rest:
            d, i = tree.query(P[members[c]])
            j = int(np.argmin(d))
            if best is None or d[j] < best[0]:
                best = (float(d[j]), c, int(members[c][j]), int(core[i[j]]))
        gap, c, a, b = best
        if gap > max_gap:
            break
        extra_r.append(a)
        extra_c.append(b)
        extra_w.append(max(gap, 1e-9))
        merged.append(c)
        rest.remove(c)
    if extra_r:
        n = G.shape[0]
        link = coo_matrix((extra_w * 2, (extra_r + extra_c, extra_c + extra_r)), shape=(n, n))
        G = (G + link).tocsr()
    keep = np.sort(np.concatenate([members[c] for c in merged]))
    return keep, G


def geodesic_extrema(depth, camera, *, mask=None, background=None, k: int = 6,
                     max_edge: float = 0.05, min_geodesic: float = 0.10,
                     step_back: float = 0.10, min_pixels: int = 30, max_gap: float = 0.30,
                     min_link_pixels: int = 5) -> InterestPoints:
    """Accumulative geodesic extrema (AGEX) of the largest foreground surface.

    Parameters
    ----------
    depth : (H, W) float, metres, 0 = invalid
    camera : gltrack.camera.Camera of the depth image
    mask, background : optional, see :func:`foreground_mask`
    k : int, at most this many extrema (5..8 is typical for a full body)
    max_edge : float, metres, longest 3-D edge kept between neighbouring pixels; longer edges
        are depth discontinuities
    min_geodesic : float, metres, stop when the farthest pixel is closer than this to every
        source (the rest would be noise bumps, not limbs)
    step_back : float, metres, geodesic length of the path used for :attr:`InterestPoints.direction`
    min_pixels : int, a largest component smaller than this gives no interest points
    max_gap : float, metres; smaller components (of at least ``min_link_pixels`` pixels) within
        this 3-D distance of the body are linked to it through their nearest pixel pair (see
        :func:`_link_components`); 0 searches the largest component only
    min_link_pixels : int

    Returns
    -------
    InterestPoints
    """
    z = np.asarray(depth, dtype=np.float64)
    if z.shape != (camera.height, camera.width):
        raise ValueError(f"depth is {z.shape} but camera {camera.name} is "
                         f"{camera.height}x{camera.width}")
    fg = foreground_mask(z, mask=mask, background=background)
    rr, cc = np.nonzero(fg)
    if len(rr) < min_pixels:
        return InterestPoints.empty()
    index = np.full(fg.shape, -1, dtype=np.int64)
    index[rr, cc] = np.arange(len(rr))
    uv = np.stack([cc, rr], axis=1).astype(np.float64)
    P = camera.backproject(uv, z[rr, cc], frame="camera")
    G = _surface_graph(fg, P, index, max_edge)

    n_comp, labels = connected_components(G, directed=False)
    sizes = np.bincount(labels, minlength=n_comp)
    big = int(np.argmax(sizes))
    if sizes[big] < min_pixels:
        return InterestPoints.empty()
    keep, G = _link_components(G, P, labels, sizes, big, max_gap, min_link_pixels)
    G = G[keep][:, keep]
    P, uv = P[keep], uv[keep]

    centre = int(np.argmin(((P - P.mean(0)) ** 2).sum(1)))
    d_centre, pred = dijkstra(G, directed=False, indices=centre, return_predecessors=True)
    dist = d_centre.copy()
    found, scores = [], []
    for _ in range(int(k)):
        j = int(np.argmax(np.where(np.isfinite(dist), dist, -1.0)))
        if not dist[j] >= min_geodesic:
            break
        found.append(j)
        scores.append(float(dist[j]))
        # only pixels nearer to j than to every earlier source can change
        d_j = dijkstra(G, directed=False, indices=j, limit=dist[j])
        np.minimum(dist, d_j, out=dist)

    found = np.array(found, dtype=np.int64)
    direction = np.zeros((len(found), 2))
    for i, j in enumerate(found):
        node = j
        while pred[node] >= 0 and d_centre[j] - d_centre[node] < step_back:
            node = pred[node]
        v = uv[node] - uv[j]
        nv = np.linalg.norm(v)
        direction[i] = v / nv if nv > 0 else (0.0, 1.0)

    return InterestPoints(
        pixels=uv[found], points=camera.to_world(P[found]), points_cam=P[found],
        geodesic=np.array(scores), centre_distance=d_centre[found], direction=direction,
        centre_pixel=uv[centre], centre_point=camera.to_world(P[centre][None])[0],
        n_pixels=len(keep))
