"""Bandouch's colour-cluster appearance model: one HLS colour cluster per mesh triangle (sec. 3.3).

Colours are collected per triangle by rendering triangle ids at the known pose (z-buffer, so only
visible surface counts), keeping pixels inside the foreground mask whose triangle faces the camera.
Each triangle's colours form a Gaussian cluster that is turned into the three 32-bit masks the
scoring engine ANDs with the observed masks (:mod:`gltrack.observe.hls`).

Cluster construction (coordinates in bins: a raw 0..255 HLS_FULL value ``v`` sits at ``v / 8``)
-------------------------------------------------------------------------------------------
1. Hue is circular (32 bins around). Its centre is the circular mean of the samples whose hue is
   meaningful (:func:`gltrack.observe.hls.significance`); each such sample's hue deviation is
   wrapped to [-16, 16) bins around it. Saturation's centre is the mean of the samples whose
   saturation is meaningful. Lightness uses every sample.
2. A sample's meaningless hue / saturation is replaced by the centre (zero deviation), so
   noise-only values never inflate the spread. The covariance ``C`` (3x3, bins^2) of the
   deviations ``(dh, dl, ds)`` is eigen-decomposed, ``C = sum_i lambda_i e_i e_i^T``.
3. The cluster box is the bounding box of the principal-axis segments
   ``centre +- k sqrt(lambda_i) e_i``: the half-width on axis ``j`` is
   ``w_j = max(k * max_i sqrt(lambda_i) |e_ij|, min_halfwidth)``. (This sits inside the shadow of
   the k-sigma ellipsoid, ``k sqrt(C_jj)``: Bandouch's boxes can only be axis-aligned, the axes
   keep them tight.)
4. Bin ``b`` of channel ``j`` is set when ``[b, b + 1)`` overlaps ``[c_j - w_j, c_j + w_j]``,
   i.e. ``|b + 0.5 - c_j| < w_j + 0.5``, with the circular distance for hue (so a red cluster
   sets bins 31 and 0). A box wider than the channel sets every bin.
5. Hue (saturation) is given all 32 bits when fewer than ``min_significant`` of the triangle's
   samples had a meaningful hue (saturation): dark, bright or grey clothing carries none.

Unknown clusters
----------------
A triangle with fewer than ``min_samples`` colours (never seen facing a camera) gets all bits in
hue and saturation and, in lightness, the union of the known clusters' lightness masks: it then
matches any colour at a lightness seen somewhere on the person, so an unseen triangle neither
wins against nor loses to a seen one by much. Unknown clusters are left out of the human lookup
table (else every colour would look human).

Human lookup table (I_H)
------------------------
:meth:`AppearanceModel.human_lut` is a (32768,) bool table: voxel ``v`` is True when a colour in
it matches at least one known cluster (all three ANDs non-zero with ``HLS_BITS_LUT[v]``).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from gltrack.observe import hls
from gltrack.render import reference

log = logging.getLogger(__name__)

_TWO_PI = 2.0 * np.pi
_BIT_VALUES = (np.uint64(1) << np.arange(32, dtype=np.uint64))


@dataclass(frozen=True)
class AppearanceParams:
    """Parameters of the cluster model (see the module docstring).

    k : float
        Half-width of a cluster box in standard deviations along each principal axis.
    min_halfwidth : float, bins
        Smallest half-width of a box; 1 bin tolerates small lighting drift.
    min_samples : int
        Colours a triangle needs before its cluster is built (else it is "unknown").
    min_significant : float in [0, 1]
        Fraction of a triangle's colours with meaningful hue (saturation) needed to use that channel.
    min_cos : float
        A triangle counts as facing a camera when the cosine between its outward normal and the
        direction to the camera centre exceeds this (0.3: within about 72 degrees).
    gate : float
        :meth:`AppearanceModel.refine` adds a colour only when its Mahalanobis distance to the
        triangle's cluster is below this.
    var_floor : float, bins^2
        Added to the covariance diagonal before inverting it for the gate (a cluster of
        identical colours would otherwise reject every new colour).
    max_samples : int
        Colours kept per triangle; beyond that the oldest (or, with an rng, random ones) are dropped.
    adopt_unseen : bool
        Let :meth:`AppearanceModel.refine` start clusters of triangles not seen so far.
    """

    k: float = 2.5
    min_halfwidth: float = 1.0
    min_samples: int = 3
    min_significant: float = 0.5
    min_cos: float = 0.3
    gate: float = 3.0
    var_floor: float = 0.25
    max_samples: int = 512
    adopt_unseen: bool = True

    def __post_init__(self):
        if not (self.k > 0 and self.min_halfwidth > 0 and self.gate > 0 and self.var_floor > 0):
            raise ValueError("k, min_halfwidth, gate and var_floor must be positive")
        if self.min_samples < 1 or self.max_samples < self.min_samples:
            raise ValueError("need 1 <= min_samples <= max_samples")
        if not 0.0 <= self.min_significant <= 1.0:
            raise ValueError(f"min_significant must be in [0, 1], got {self.min_significant}")


# ---------------------------------------------------------------------------------------------
# cluster construction (pure numpy, vectorised over triangles)


def _pack_bins(bins: np.ndarray) -> np.ndarray:
    """(F, 32) bool -> (F,) uint32 with bit b set where ``bins[:, b]``."""
    return (bins.astype(np.uint64) * _BIT_VALUES).sum(axis=1, dtype=np.uint64).astype(np.uint32)


def _wrap(d):
    """Hue difference in bins wrapped to [-16, 16)."""
    return (d + 16.0) % 32.0 - 16.0


@dataclass
class Clusters:
    """Per-triangle cluster statistics (F triangles), all in bins.

    known : (F,) bool; hue_known, sat_known : (F,) bool
    centre : (F, 3) float64, hue (0..32, circular), lightness, saturation
    cov : (F, 3, 3) float64, covariance of the deviations (hue wrapped)
    halfwidth : (F, 3) float64
    bits : (F, 3) uint32, the engine's ``tri_bits``
    """

    known: np.ndarray
    hue_known: np.ndarray
    sat_known: np.ndarray
    centre: np.ndarray
    cov: np.ndarray
    halfwidth: np.ndarray
    bits: np.ndarray


def _deviations(hls_vals, centre, use_h, use_s):
    """(M, 3) deviations from per-sample centres; meaningless channels contribute 0."""
    x = hls_vals.astype(np.float64) / 8.0
    lb, sb = hls_vals[:, 1] >> 3, hls_vals[:, 2] >> 3
    hue_ok, sat_ok = hls.significance(lb, sb)
    d = np.empty_like(x)
    d[:, 0] = np.where(hue_ok & use_h, _wrap(x[:, 0] - centre[:, 0]), 0.0)
    d[:, 1] = x[:, 1] - centre[:, 1]
    d[:, 2] = np.where(sat_ok & use_s, x[:, 2] - centre[:, 2], 0.0)
    return d


def build_clusters(tri: np.ndarray, hls_vals: np.ndarray, n_faces: int,
                   params: AppearanceParams = AppearanceParams()) -> Clusters:
    """Clusters of every triangle from its colour samples.

    Parameters
    ----------
    tri : (M,) int, triangle of each sample (0..F-1)
    hls_vals : (M, 3) uint8, raw HLS_FULL values (hue, lightness, saturation, each 0..255)
    n_faces : int, F
    params : AppearanceParams

    Returns
    -------
    Clusters
    """
    tri = np.asarray(tri, dtype=np.int64).reshape(-1)
    v = np.asarray(hls_vals)
    if v.shape != (len(tri), 3) or v.dtype != np.uint8:
        raise ValueError(f"hls_vals must be ({len(tri)}, 3) uint8, got {v.shape} {v.dtype}")
    if len(tri) and (tri.min() < 0 or tri.max() >= n_faces):
        raise ValueError(f"triangle ids must be in 0..{n_faces - 1}")
    F = int(n_faces)
    x = v.astype(np.float64) / 8.0
    hue_ok, sat_ok = hls.significance(v[:, 1] >> 3, v[:, 2] >> 3)

    def count(w=None):
        return np.bincount(tri, weights=w, minlength=F)

    n = count()
    nh, ns = count(hue_ok.astype(float)), count(sat_ok.astype(float))
    ang = x[:, 0] * (_TWO_PI / 32.0)
    mh = (np.arctan2(count(np.sin(ang) * hue_ok), count(np.cos(ang) * hue_ok)) * (32.0 / _TWO_PI)) % 32.0
    # The circular mean is not the least-squares centre of the wrapped deviations; shift onto it.
    dh = np.where(hue_ok, _wrap(x[:, 0] - mh[tri]), 0.0)
    mh = (mh + count(dh) / np.maximum(nh, 1)) % 32.0
    ml = count(x[:, 1]) / np.maximum(n, 1)
    ms = count(x[:, 2] * sat_ok) / np.maximum(ns, 1)
    centre = np.stack([mh, ml, ms], axis=1)

    known = n >= params.min_samples
    hue_known = known & (nh > 0) & (nh >= params.min_significant * n)
    sat_known = known & (ns > 0) & (ns >= params.min_significant * n)
    d = _deviations(v, centre[tri], hue_known[tri], sat_known[tri])
    cov = np.zeros((F, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = count(d[:, i] * d[:, j]) / np.maximum(n, 1)
    lam, vec = np.linalg.eigh(cov)
    lam = np.clip(lam, 0.0, None)
    # vec[:, j, i] is component j of eigenvector i
    half = params.k * np.max(np.sqrt(lam)[:, None, :] * np.abs(vec), axis=2)
    half = np.maximum(half, params.min_halfwidth)

    centres_b = np.arange(32) + 0.5
    dist = np.abs(centres_b[None, None, :] - centre[:, :, None])  # (F, 3, 32)
    dist[:, 0] = np.abs(_wrap(centres_b[None, :] - centre[:, 0, None]))
    bins = dist < half[:, :, None] + 0.5
    bits = np.stack([_pack_bins(bins[:, j]) for j in range(3)], axis=1)
    bits[~hue_known, 0] = hls.ALL_BITS
    bits[~sat_known, 2] = hls.ALL_BITS
    if known.any():
        l_union = np.bitwise_or.reduce(bits[known, 1])
    else:
        l_union = hls.ALL_BITS
    bits[~known] = (hls.ALL_BITS, l_union, hls.ALL_BITS)
    return Clusters(known, hue_known, sat_known, centre, cov, half, bits)


def human_lut_from_bits(tri_bits: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Bandouch's I_H table: which voxels match at least one known cluster.

    Uses that an observed mask is either one bin or all bits (:data:`hls.HLS_BITS_LUT`): with
    ``Hc, Lc, Sc`` the clusters' bin sets, voxel ``(h, l, s)`` is human iff some cluster has
    ``Lc[l] and (Hc[h] or hue meaningless at (l, s)) and (Sc[s] or saturation meaningless at l)``,
    which three small matrix products answer for all 32768 voxels at once.

    Parameters
    ----------
    tri_bits : (F, 3) uint32, cluster masks
    known : (F,) bool, clusters to include

    Returns
    -------
    (32768,) bool, indexed by :func:`gltrack.observe.hls.voxel_index`
    """
    tb = np.unique(np.asarray(tri_bits, dtype=np.uint32)[np.asarray(known, bool)], axis=0)
    if len(tb) == 0:
        return np.zeros(hls.N_VOXELS, bool)
    b = ((tb[:, :, None] >> np.arange(32, dtype=np.uint32)) & 1).astype(np.float64)  # (U, 3, 32)
    Hc, Lc, Sc = b[:, 0], b[:, 1], b[:, 2]
    LS = (Lc[:, :, None] * Sc[:, None, :]).reshape(len(tb), -1)  # (U, 32*32)
    full = (Hc.T @ LS).reshape(32, 32, 32) > 0  # [h, l, s]: every channel by its own bin
    no_hue = ((Lc.T @ Sc) > 0)[None, :, :]       # [l, s]: hue meaningless
    no_sat = (Lc.sum(axis=0) > 0)[None, :, None]  # [l]: hue and saturation meaningless
    grid = np.indices((32, 32, 32))
    hue_ok, sat_ok = hls.significance(grid[1], grid[2])
    out = np.where(hue_ok, full, np.where(sat_ok, no_hue, no_sat))
    return out.reshape(-1)


# ---------------------------------------------------------------------------------------------
# sampling colours under the posed mesh


def facing_triangles(mesh, skinning, centre, min_cos: float) -> np.ndarray:
    """Which triangles of the posed mesh face a camera.

    Parameters
    ----------
    mesh : BodyMesh (faces counter-clockwise seen from outside)
    skinning : (B, 3, 4) float, one pose
    centre : (3,) float, camera centre, metres (world)
    min_cos : float, threshold on the cosine between the outward normal and the direction to the camera

    Returns
    -------
    (F,) bool
    """
    P = reference.skin_vertices(mesh, np.asarray(skinning)[None])[0]
    tri = P[mesh.faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    to_cam = np.asarray(centre, dtype=np.float64)[None] - tri.mean(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.einsum("fi,fi->f", n, to_cam) / (np.linalg.norm(n, axis=1) * np.linalg.norm(to_cam, axis=1))
    return np.nan_to_num(cos, nan=-1.0) > min_cos


def _check_pose(skinning):
    S = np.asarray(skinning, dtype=np.float64)
    if S.ndim == 4 and S.shape[0] == 1:
        S = S[0]
    if S.ndim != 3 or S.shape[1:] != (3, 4):
        raise ValueError(f"skinning must be (B, 3, 4) or (1, B, 3, 4), got {S.shape}")
    return S


def sample_colours(mesh, skinning, cameras, images, masks, *, engine=None,
                   min_cos: float = AppearanceParams.min_cos) -> tuple[np.ndarray, np.ndarray]:
    """Colours seen on front-facing, visible triangles of one pose in every camera.

    Parameters
    ----------
    mesh : BodyMesh
    skinning : (B, 3, 4) float, the pose
    cameras : list of C gltrack.camera.Camera (undistorted)
    images : list of C (H, W, 3) uint8 BGR images at the cameras' resolutions
    masks : list of C (H, W) bool foreground masks (None = every pixel)
    engine : gltrack.render.engine.ScoringEngine, optional
        Render triangle ids on the GPU at the engine's tile resolution, the images and masks
        resampled exactly as the engine resamples observations (nearest neighbour), so the model
        sees the same pixels the engine scores. Without it the CPU reference rasteriser renders at
        full camera resolution. The engine's camera ``c`` must be ``cameras[c]``.
    min_cos : float, facing threshold (see :class:`AppearanceParams`)

    Returns
    -------
    tri : (M,) int64, triangle of each colour; hls_vals : (M, 3) uint8, raw HLS_FULL values
    """
    S = _check_pose(skinning)
    if not (len(cameras) == len(images) == len(masks)):
        raise ValueError(f"need one image and mask per camera: {len(cameras)} cameras, "
                         f"{len(images)} images, {len(masks)} masks")
    if engine is not None and len(engine.views) != len(cameras):
        raise ValueError(f"engine has {len(engine.views)} cameras, got {len(cameras)}")
    tris, vals = [], []
    for c, (cam, img, mask) in enumerate(zip(cameras, images, masks)):
        img = np.asarray(img)
        if img.shape != (cam.height, cam.width, 3) or img.dtype != np.uint8:
            raise ValueError(f"image of camera {cam.name!r} must be ({cam.height}, {cam.width}, 3) "
                             f"uint8, got {img.shape} {img.dtype}")
        m = np.ones(img.shape[:2], bool) if mask is None else np.asarray(mask).astype(bool)
        if m.shape != img.shape[:2]:
            raise ValueError(f"mask of camera {cam.name!r} must be {img.shape[:2]}, got {m.shape}")
        if engine is None:
            _, ids = reference.render_candidates(mesh, S[None], cam.K, cam.R, cam.t, cam.width, cam.height)
            ids = ids[0]
        else:
            T = engine.tile
            _, ids = engine.render_tiles(S[None].astype(np.float32), c)
            ids = ids[0]
            img = cv2.resize(img, (T, T), interpolation=cv2.INTER_NEAREST_EXACT)
            m = cv2.resize(m.astype(np.uint8), (T, T), interpolation=cv2.INTER_NEAREST_EXACT).astype(bool)
        facing = facing_triangles(mesh, S, cam.center, min_cos)
        sel = (ids >= 0) & m
        sel[sel] = facing[ids[sel]]
        h = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2HLS_FULL)
        tris.append(ids[sel].astype(np.int64))
        vals.append(h[sel])
    if not tris:
        return np.zeros(0, np.int64), np.zeros((0, 3), np.uint8)
    return np.concatenate(tris), np.concatenate(vals).astype(np.uint8)


# ---------------------------------------------------------------------------------------------
# the model


class AppearanceModel:
    """Per-triangle colour clusters, their bitmasks and the human-colour table.

    Build it with :meth:`from_first_frame`; feed :meth:`tri_bits` to
    ``ScoringEngine.set_appearance`` and :meth:`human_lut` to
    :class:`gltrack.observe.environment.EnvironmentLayers`.

    Parameters
    ----------
    mesh : BodyMesh
    params : AppearanceParams
    rng : numpy.random.Generator, optional
        Used only to choose which colours to drop when a triangle has more than ``max_samples``.
    """

    def __init__(self, mesh, params: AppearanceParams = AppearanceParams(), rng=None):
        self.mesh = mesh
        self.params = params
        self.rng = rng
        self._tri = np.zeros(0, np.int64)
        self._hls = np.zeros((0, 3), np.uint8)
        self.clusters = build_clusters(self._tri, self._hls, mesh.n_faces, params)
        self._lut = None
        #: Incremented whenever the masks are rebuilt (consumers can cache on it).
        self.version = 0

    @classmethod
    def from_first_frame(cls, mesh, skinning0, cameras, images, masks, *, engine=None,
                         params: AppearanceParams = AppearanceParams(), rng=None) -> "AppearanceModel":
        """Initialise the clusters from the first frame's (known) pose.

        Parameters
        ----------
        mesh : BodyMesh
        skinning0 : (B, 3, 4) or (1, B, 3, 4) float, the first pose's skinning matrices
        cameras, images, masks, engine : see :func:`sample_colours`
        params : AppearanceParams
        rng : numpy.random.Generator, optional

        Returns
        -------
        AppearanceModel
        """
        model = cls(mesh, params, rng)
        tri, vals = sample_colours(mesh, skinning0, cameras, images, masks, engine=engine,
                                   min_cos=params.min_cos)
        model._add(tri, vals)
        log.info("appearance model: %d colours, %d of %d triangles seen", len(tri),
                 int(model.clusters.known.sum()), mesh.n_faces)
        return model

    def get_state(self) -> dict:
        """The colours kept per triangle (the clusters follow from them), for a checkpoint."""
        return {"tri": self._tri.copy(), "hls": self._hls.copy(), "version": int(self.version)}

    @classmethod
    def from_state(cls, mesh, state: dict, params: AppearanceParams = AppearanceParams(),
                   rng=None) -> "AppearanceModel":
        """The model of :meth:`get_state` (same ``mesh``, ``params``; ``rng`` as the original's)."""
        model = cls(mesh, params, rng)
        model._tri = np.asarray(state["tri"], dtype=np.int64)
        model._hls = np.asarray(state["hls"], dtype=np.uint8).reshape(-1, 3)
        model.clusters = build_clusters(model._tri, model._hls, mesh.n_faces, params)
        model.version = int(state["version"])
        return model

    def refine(self, skinning, cameras, images, masks, *, engine=None) -> int:
        """Add colours seen at an estimated pose that fit their triangle's cluster; rebuild masks.

        A colour is added when its triangle faces the camera and its Mahalanobis distance to the
        cluster (covariance plus ``var_floor``) is below ``params.gate``; colours of unknown
        triangles are added when ``params.adopt_unseen``.

        Parameters
        ----------
        skinning, cameras, images, masks, engine : see :func:`sample_colours`

        Returns
        -------
        int, the number of colours added
        """
        tri, vals = sample_colours(self.mesh, skinning, cameras, images, masks, engine=engine,
                                   min_cos=self.params.min_cos)
        ok = self.mahalanobis(tri, vals) < self.params.gate
        if self.params.adopt_unseen:
            ok |= ~self.clusters.known[tri]
        n = int(ok.sum())
        if n:
            self._add(tri[ok], vals[ok])
        log.debug("appearance refine: %d of %d colours added", n, len(tri))
        return n

    def mahalanobis(self, tri, hls_vals) -> np.ndarray:
        """Distances of colours to their triangles' clusters (inf for unknown clusters).

        Parameters
        ----------
        tri : (M,) int; hls_vals : (M, 3) uint8 raw HLS_FULL values

        Returns
        -------
        (M,) float64, in standard deviations
        """
        tri = np.asarray(tri, dtype=np.int64)
        v = np.asarray(hls_vals, dtype=np.uint8).reshape(-1, 3)
        cl = self.clusters
        d = _deviations(v, cl.centre[tri], cl.hue_known[tri], cl.sat_known[tri])
        P = np.linalg.inv(cl.cov + self.params.var_floor * np.eye(3))
        d2 = np.einsum("mi,mij,mj->m", d, P[tri], d)
        return np.where(cl.known[tri], np.sqrt(np.maximum(d2, 0.0)), np.inf)

    def _add(self, tri, vals):
        self._tri = np.concatenate([self._tri, tri])
        self._hls = np.concatenate([self._hls, vals])
        self._cap()
        self.clusters = build_clusters(self._tri, self._hls, self.mesh.n_faces, self.params)
        self._lut = None
        self.version += 1

    def _cap(self):
        cap = self.params.max_samples
        counts = np.bincount(self._tri, minlength=self.mesh.n_faces)
        if counts.max(initial=0) <= cap:
            return
        # Rank each colour within its triangle: newest last, or randomly with an rng.
        key = np.arange(len(self._tri)) if self.rng is None else self.rng.permutation(len(self._tri))
        order = np.lexsort((key, self._tri))
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        rank = np.empty(len(order), np.int64)
        rank[order] = np.arange(len(order)) - first[self._tri[order]]
        keep = rank >= counts[self._tri] - cap
        self._tri, self._hls = self._tri[keep], self._hls[keep]

    def tri_bits(self) -> np.ndarray:
        """(F, 3) uint32, each triangle's hue / lightness / saturation cluster masks."""
        return self.clusters.bits.copy()

    def human_lut(self) -> np.ndarray:
        """(32768,) bool, I_H's table (cached until the model changes)."""
        if self._lut is None:
            self._lut = human_lut_from_bits(self.clusters.bits, self.clusters.known)
        return self._lut

    def human_mask(self, bgr) -> np.ndarray:
        """(H, W) bool, I_H of a BGR uint8 image: the pixel's colour occurs in the model."""
        return self.human_lut()[hls.voxel_index(bgr)]

    @property
    def n_colours(self) -> int:
        """Colours currently stored."""
        return len(self._tri)
