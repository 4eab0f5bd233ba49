"""Where is the person? Connected blobs of foreground points, for the automatic start.

The automatic starts place their pose library on "the person's centroid": the visual hull's
voxels (multi-view) or the seen depth surface (depth). With a second person, or a person-sized
object, in the scene, the centroid of all foreground lies between the two, where nobody is.
:func:`person_blobs` splits the points into connected blobs (points closer than ``link``
metres are connected); :func:`pick_person` leaves out the blobs that are person-sized besides
the largest (with a warning naming them) and keeps everything else.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

#: points closer than this are in one blob, metres: a hull voxel is at most 6 cm
#: (``Voxels.points(max_size=0.06)``) and a depth pixel spans under 3 cm at 5 m (SR4000), so
#: one body stays connected through gaps of a few voxels or pixels, while two people standing
#: 0.25 m apart do not merge
LINK = 0.12
#: a blob is person-sized when it spans this much vertically (metres; a seated person's upper
#: body spans 0.6-0.9 m, a standing one 1.5-1.9 m) ...
PERSON_HEIGHT = 0.5
#: ... and holds at least this share of the largest blob's weight
PERSON_SHARE = 0.3
#: more points than this are thinned to every k-th to find the blobs (a 176x144 depth frame has
#: up to 25,000); every point then joins its nearest kept point's blob
MAX_POINTS = 5000


@dataclass
class Blob:
    """One connected blob of foreground points.

    Attributes
    ----------
    centroid : (3,) float, weighted mean of the points, metres
    weight : float, summed weights (voxel volumes, m^3; or pixel areas)
    lo, hi : (3,) float, bounding box, metres
    index : (K,) int, rows of the points in the blob
    """

    centroid: np.ndarray
    weight: float
    lo: np.ndarray
    hi: np.ndarray
    index: np.ndarray

    def height(self, up: int = 1) -> float:
        return float(self.hi[up] - self.lo[up])


def person_blobs(points, weights=None, link: float = LINK) -> list[Blob]:
    """Connected blobs of ``points``, largest (by weight) first.

    Parameters
    ----------
    points : (P, 3) float, metres
    weights : (P,) float, optional (default 1 each)
    link : float, metres, the largest gap inside one blob

    Returns
    -------
    list of Blob
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    w = np.ones(len(pts)) if weights is None else np.asarray(weights, dtype=np.float64)
    if len(pts) == 0:
        return []
    # the blobs are found on every k-th point (the pairs grow with the density squared); every
    # point then joins the blob of its nearest kept point, so a lone person's centroid is the
    # weighted mean of all its points
    keep = np.arange(0, len(pts), max(int(np.ceil(len(pts) / MAX_POINTS)), 1))
    tree = cKDTree(pts[keep])
    pairs = tree.query_pairs(float(link), output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                       shape=(len(keep), len(keep)))
    n, kept_labels = connected_components(graph, directed=False)
    labels = kept_labels if len(keep) == len(pts) else kept_labels[tree.query(pts)[1]]
    blobs = []
    for k in range(n):
        idx = np.nonzero(labels == k)[0]
        wk = w[idx]
        c = (pts[idx].mean(axis=0) if weights is None  # (bit for bit the plain mean)
             else (pts[idx] * wk[:, None]).sum(0) / max(wk.sum(), 1e-12))
        blobs.append(Blob(c, float(wk.sum()), pts[idx].min(0), pts[idx].max(0), idx))
    return sorted(blobs, key=lambda b: -b.weight)


def pick_person(points, weights=None, *, where: str = "", link: float = LINK) -> Blob | None:
    """The person's points: all of ``points`` except the blobs that are person-sized besides
    the largest one (named in a warning). Small blobs stay: a far arm seen through a gap or a
    foot beyond a depth edge is a separate blob of the same person.

    Returns a Blob of the kept points (its centroid bit for bit the plain mean of ``points``
    when nothing is left out), or None when there are no points.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    blobs = person_blobs(pts, weights, link)
    if not blobs:
        return None
    best = blobs[0]
    others = [b for b in blobs[1:] if b.weight >= PERSON_SHARE * best.weight
              and b.height() >= PERSON_HEIGHT]
    if not others or best.height() < PERSON_HEIGHT:
        idx = np.arange(len(pts))
    else:
        log.warning("%s%d person-sized blobs in view; starting from the largest at %s "
                    "(others at %s)", f"{where}: " if where else "", 1 + len(others),
                    np.round(best.centroid, 2).tolist(),
                    ", ".join(str(np.round(b.centroid, 2).tolist()) for b in others))
        idx = np.setdiff1d(np.arange(len(pts)), np.concatenate([b.index for b in others]))
    w = np.ones(len(pts)) if weights is None else np.asarray(weights, dtype=np.float64)
    c = (pts[idx].mean(axis=0) if weights is None
         else (pts[idx] * w[idx, None]).sum(0) / max(w[idx].sum(), 1e-12))
    return Blob(c, float(w[idx].sum()), pts[idx].min(0), pts[idx].max(0), idx)
