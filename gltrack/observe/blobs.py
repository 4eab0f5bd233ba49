"""Gaussian blobs: body parts and voxel data as mixtures of 3-D Gaussians (Caillette 2008, sec. 6).

* :class:`BlobModel` turns candidate poses into one Gaussian per body part (``PARTS`` of
  :mod:`gltrack.body.mesh`): the first two moments of the part's *solid* volume, posed by the
  mesh's own linear blend skinning.
* :func:`fit_blobs` summarises reconstructed voxels by EM on a mixture initialised from the
  blobs of a predicted pose, so fitted blob ``i`` stays the observation of part ``i``;
  :func:`fit_blobs_from` runs it from several starts at once.
* :func:`mixture_kl` is the paper's fast evaluation, eq. 9: with the correspondence ``i <-> i``
  kept, ``D(F||G) ~ sum_i a_i (KL(f_i||g_i) + ln(a_i / b_i))`` with the closed-form KL between
  Gaussians (:func:`gaussian_kl`).

Solid moments from a surface mesh. Voxels fill the body, vertices only cover its skin, and a
tube's surface spreads twice as far from its axis (variance ``r^2/2``) as its volume (``r^2/4``).
Each vertex ``v`` gets an anchor ``a``, the nearest point on the segment of its main bone, and
stands for the radial line ``a + s (v - a)``, ``s`` in [0, 1] with density ``2 s`` (uniform over a
cross-section). Skinning is affine per vertex, so the posed line joins the posed anchor and the
posed vertex and the part's moments follow exactly from ``E[s] = 2/3`` and ``E[s^2] = 1/2``.
Vertices are weighted by their share of the adjacent triangles' area times their distance to
the anchor (the volume their radial line sweeps).

The paper's eq. 10 writes the divergence with ``Sigma_f^-1``, which is ``KL(g||f)`` in the usual
notation; :func:`gaussian_kl` is the standard ``KL(f||g)`` (checked against Monte Carlo).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from gltrack.body.mesh import PARTS

log = logging.getLogger(__name__)

_E_S, _E_S2 = 2.0 / 3.0, 0.5


@dataclass
class Blobs:
    """A mixture of P Gaussian blobs, possibly for a batch of N candidates.

    Attributes
    ----------
    means : (..., P, 3) float64, metres
    covs : (..., P, 3, 3) float64, square metres
    weights : (..., P) float64, mixture weights summing to 1 over P
    """

    means: np.ndarray
    covs: np.ndarray
    weights: np.ndarray

    def __getitem__(self, i) -> "Blobs":
        return Blobs(self.means[i], self.covs[i], self.weights[i])

    @property
    def n_blobs(self) -> int:
        return self.means.shape[-2]


def _bone_segments(skeleton) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3) start and end of each bone's rest segment (joint to tip / mean child)."""
    pos = skeleton.rest_positions()
    end = pos.copy()
    for j in range(skeleton.n_joints):
        kids = skeleton.children(j)
        if np.any(skeleton.ends[j] != 0):
            end[j] = pos[j] + skeleton.ends[j]
        elif kids:
            end[j] = pos[kids].mean(axis=0)
    return pos, end


def _closest_on_segments(p, a, b):
    ab = b - a
    L2 = np.sum(ab * ab, axis=1)
    t = np.where(L2 > 1e-12, np.sum((p - a) * ab, axis=1) / np.maximum(L2, 1e-12), 0.0)
    return a + np.clip(t, 0.0, 1.0)[:, None] * ab


class BlobModel:
    """One Gaussian blob per body part of a skinned mesh.

    Parameters
    ----------
    mesh : gltrack.body.mesh.BodyMesh
    skeleton : gltrack.body.skeleton.Skeleton, the one the skinning matrices come from
    interior : bool, moments of the solid volume (default) or of the surface vertices only

    Attributes
    ----------
    parts : tuple of str, names of the P blobs (the parts present in the mesh)
    weights : (P,) float64, mixture weights: each part's share of the body volume
    """

    def __init__(self, mesh, skeleton, *, interior: bool = True):
        self.mesh, self.interior = mesh, bool(interior)
        present = np.unique(mesh.part)
        self.parts = tuple(PARTS[i] for i in present)
        part_idx = np.searchsorted(present, mesh.part)
        v = mesh.vertices.astype(np.float64)
        main = mesh.joints[np.arange(mesh.n_vertices), np.argmax(mesh.weights, axis=1)]
        a, b = _bone_segments(skeleton)
        anchor = _closest_on_segments(v, a[main], b[main])
        tri = v[mesh.faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        varea = np.zeros(mesh.n_vertices)
        np.add.at(varea, mesh.faces.ravel(), np.repeat(area / 3.0, 3))
        reach = np.linalg.norm(v - anchor, axis=1)
        w = varea * reach if interior else varea
        P = len(present)
        self._part_w = np.zeros((P, mesh.n_vertices))
        self._part_w[part_idx, np.arange(mesh.n_vertices)] = w
        vol = self._part_w.sum(axis=1)
        if np.any(vol <= 0):
            raise ValueError("mesh has a body part without area")
        self._part_w /= vol[:, None]
        self.weights = vol / vol.sum()
        self._n_bones = int(skeleton.n_joints)
        if mesh.joints.max() >= self._n_bones:
            raise ValueError(f"mesh uses joint {mesh.joints.max()}, the skeleton has "
                             f"{self._n_bones}")
        self._anchor = anchor
        # Skinning is affine in the skinning matrices, so a part's moments are linear and
        # quadratic forms of the matrices of the few bones its vertices hang on: with s_p the
        # (3, 4 b) matrices of those b bones side by side and u the vertex's blend weights
        # times its homogeneous rest position (4 b,), x = s_p u, and
        #   E[x] = s_p E[u],   E[x x^T] = s_p E[u u^T] s_p^T.
        # Precomputing E[u] and E[u u^T] per part makes a pose's blobs a few small products,
        # five times faster than skinning every vertex (1000 poses: 5.8 against 29 ms).
        if interior:
            # E[x x^T] over x = a + s d with E[s] = 2/3, E[s^2] = 1/2 is
            # m m^T + (E[s^2] - E[s]^2) d d^T with m = a + E[s] d
            m = np.concatenate([anchor + _E_S * (v - anchor), np.ones((len(v), 1))], axis=1)
            d = np.concatenate([v - anchor, np.zeros((len(v), 1))], axis=1)
        else:
            m, d = np.concatenate([v, np.ones((len(v), 1))], axis=1), None
        self._bones, self._mu, self._G = [], [], []
        wts = mesh.weights.astype(np.float64)
        for p in range(P):
            rows = np.nonzero(self._part_w[p])[0]
            bones = np.unique(mesh.joints[rows][wts[rows] > 0])
            blend = np.zeros((len(rows), len(bones)))
            for k in range(mesh.joints.shape[1]):
                # (a zero weight may name any joint: clipped onto a used bone, it adds nothing)
                col = np.minimum(np.searchsorted(bones, mesh.joints[rows, k]), len(bones) - 1)
                blend[np.arange(len(rows)), col] += np.maximum(wts[rows, k], 0.0)
            wv = self._part_w[p, rows]
            u = (blend[:, :, None] * m[rows, None, :]).reshape(len(rows), -1)  # (Vp, 4 b)
            G = (u * wv[:, None]).T @ u
            if d is not None:
                e = (blend[:, :, None] * d[rows, None, :]).reshape(len(rows), -1)
                G += (_E_S2 - _E_S ** 2) * (e * wv[:, None]).T @ e
            self._bones.append(bones)
            self._mu.append(wv @ u)
            self._G.append(G)

    @property
    def n_blobs(self) -> int:
        return len(self.parts)

    def blobs(self, skinning, chunk: int = 4096) -> Blobs:
        """Blobs of N posed candidates.

        Parameters
        ----------
        skinning : (N, B, 3, 4) float, ``Kinematics.skinning_matrices``
        chunk : int, poses processed at once (bounds the (chunk, 3, 3, 4 b) temporaries)

        Returns
        -------
        Blobs with means (N, P, 3), covs (N, P, 3, 3), weights (N, P) (the same for every pose).
        """
        S = np.asarray(skinning, dtype=np.float64)
        if S.ndim != 4 or S.shape[1:] != (self._n_bones, 3, 4):
            raise ValueError(f"skinning must have shape (N, {self._n_bones}, 3, 4), got "
                             f"{S.shape}")
        n = S.shape[0]
        mean = np.empty((n, self.n_blobs, 3))
        cov = np.empty((n, self.n_blobs, 3, 3))
        for a in range(0, n, chunk):
            mean[a:a + chunk], cov[a:a + chunk] = self._moments(S[a:a + chunk])
        return Blobs(mean, cov, np.broadcast_to(self.weights, (n, self.n_blobs)).copy())

    def _moments(self, S):
        n = len(S)
        mean = np.empty((n, self.n_blobs, 3))
        second = np.empty((n, self.n_blobs, 3, 3))
        # the rows of every bone's matrix side by side once, (n, 3, 4 B): a part's bones are
        # then a column selection (a gather per part of S[:, bones] cost three times as much)
        rows = np.ascontiguousarray(np.transpose(S, (0, 2, 1, 3))).reshape(n, 3, -1)
        for p, (bones, mu, G) in enumerate(zip(self._bones, self._mu, self._G)):
            cols = (4 * np.asarray(bones)[:, None] + np.arange(4)).reshape(-1)
            sp = rows[:, :, cols]  # (n, 3, 4 b)
            mean[:, p] = sp @ mu
            sG = (sp.reshape(-1, sp.shape[2]) @ G).reshape(sp.shape)
            second[:, p] = sG @ np.transpose(sp, (0, 2, 1))
        return mean, second - mean[..., :, None] * mean[..., None, :]

    def centroid(self, skinning) -> np.ndarray:
        """(N, 3) volume-weighted centre of the body, metres."""
        b = self.blobs(skinning)
        return np.einsum("np,npi->ni", b.weights, b.means)


def place_on_centroid(body, model: BlobModel, prototypes, headings: int, centroid) -> np.ndarray:
    """Prototype poses at ``headings`` headings, each moved so its volume centroid is ``centroid``.

    Parameters
    ----------
    body : gltrack.body.model.BodyModel
    model : BlobModel of ``body`` (its volume centroid)
    prototypes : (K, D) float, poses whose root translation and heading are replaced
    headings : int >= 1, headings spread evenly over a full turn (heading 0 = facing +Z)
    centroid : (3,) float, metres, e.g. the centroid of a visual hull

    Returns
    -------
    (K * H, D) float64, prototype k at heading h in row ``k * H + h``.
    """
    d = body.dofs
    H = max(int(headings), 1)
    P = np.repeat(d.validate(prototypes), H, axis=0)
    P[:, d.index("pelvis_ry")] = np.tile(2 * np.pi * np.arange(H) / H, len(prototypes))
    P = d.validate(P)
    P[:, :3] += np.asarray(centroid, dtype=np.float64) - model.centroid(body.skinning(P))
    return d.validate(P)


def gaussian_kl(mu_f, cov_f, mu_g, cov_g) -> np.ndarray:
    """Closed-form ``KL(f || g)`` between Gaussians, nats, broadcast over leading axes.

    ``0.5 (ln(|S_g| / |S_f|) - d + tr(S_g^-1 S_f) + (mu_g - mu_f)^T S_g^-1 (mu_g - mu_f))``

    Parameters
    ----------
    mu_f, mu_g : (..., d) float
    cov_f, cov_g : (..., d, d) float, symmetric positive definite

    Returns
    -------
    (...,) float64, >= 0
    """
    mu_f, mu_g = np.asarray(mu_f, np.float64), np.asarray(mu_g, np.float64)
    cov_f, cov_g = np.asarray(cov_f, np.float64), np.asarray(cov_g, np.float64)
    d = mu_f.shape[-1]
    # invert g before broadcasting: one evidence blob is compared with thousands of particles'
    inv_g = np.linalg.inv(cov_g)
    tr = np.sum(inv_g * np.swapaxes(cov_f, -1, -2), axis=(-2, -1))
    diff = mu_g - mu_f
    maha = np.einsum("...i,...ij,...j->...", diff, inv_g, diff)
    return np.maximum(0.5 * (_logdet(cov_g) - _logdet(cov_f) - d + tr + maha), 0.0)


def _logdet(S):
    """(...,) log-determinant of symmetric positive definite (..., d, d) matrices (closed form
    for 3x3, which avoids one LAPACK call per matrix)."""
    if S.shape[-2:] != (3, 3):
        return np.linalg.slogdet(S)[1]
    a, b, c = S[..., 0, 0], S[..., 0, 1], S[..., 0, 2]
    e, f, i = S[..., 1, 1], S[..., 1, 2], S[..., 2, 2]
    det = a * (e * i - f * f) - b * (b * i - f * c) + c * (b * f - e * c)
    return np.log(np.maximum(det, 1e-300))


def kl_translation(model: Blobs, observed: Blobs) -> np.ndarray:
    """(N, 3) translation of each candidate's blobs that minimises :func:`mixture_kl`.

    Moving every blob of a candidate by ``t`` changes only the Mahalanobis terms of eq. 9, so
    the KL is quadratic in ``t``: ``sum_i a_i / 2 (d_i - t)^T S_i^-1 (d_i - t)`` with
    ``d_i = mu_g,i - mu_f,i`` and ``S_i`` the observed blob's covariance, least at
    ``t = (sum_i a_i S_i^-1)^-1 sum_i a_i S_i^-1 d_i``.

    Parameters
    ----------
    model : Blobs (N, P) of N candidate poses (``F``)
    observed : Blobs (P,) fitted to the observation (``G``)

    Returns
    -------
    (N, 3) float64, metres
    """
    inv_g = np.linalg.inv(np.asarray(observed.covs, np.float64))   # (P, 3, 3) S_i^-1
    a = np.asarray(model.weights, np.float64)                      # (N, P)
    n, p = a.shape
    # both sums as (N, P) x (P, ...) matrix products: einsum over the small axes is 5x slower
    H = (a @ inv_g.reshape(p, 9)).reshape(n, 3, 3)
    g = (a @ np.einsum("pij,pj->pi", inv_g, observed.means)
         - (a[..., None] * model.means).reshape(n, 3 * p)
         @ np.swapaxes(inv_g, -1, -2).reshape(3 * p, 3))
    return np.linalg.solve(H, g[..., None])[..., 0]


def mixture_kl(model: Blobs, observed: Blobs) -> np.ndarray:
    """Eq. 9: ``sum_i a_i (KL(f_i || g_i) + ln(a_i / b_i))`` with blob i <-> blob i.

    Parameters
    ----------
    model : Blobs (N, P) of N candidate poses (``F``)
    observed : Blobs (P,) fitted to the observation (``G``)

    Returns
    -------
    (N,) float64, nats; 0 for identical mixtures.
    """
    if model.n_blobs != observed.n_blobs:
        raise ValueError(f"{model.n_blobs} model blobs vs {observed.n_blobs} observed blobs")
    kl = gaussian_kl(model.means, model.covs, observed.means, observed.covs)
    a = model.weights
    b = np.maximum(observed.weights, 1e-12)
    return np.sum(a * (kl + np.log(np.maximum(a, 1e-12) / b)), axis=-1)


def logsumexp(a, axis: int, keepdims: bool = False) -> np.ndarray:
    """``log(sum(exp(a), axis))`` computed stably; scipy's version costs more in call overhead
    than the small arrays here take to reduce (a third of a blob fit)."""
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):  # log(0) = -inf where every term is -inf, as scipy
        out = np.log(np.sum(np.exp(a - m), axis=axis, keepdims=True)) + m
    return out if keepdims else np.squeeze(out, axis=axis)


def _log_gauss(X, mean, cov):
    """(M, P) log N(x_m | mean_p, cov_p) for X (M, d), mean (P, d), cov (P, d, d)."""
    inv = np.linalg.inv(cov)  # P small inversions instead of P * M triangular solves
    d = X.shape[1]
    if d == 3:
        # the quadratic form written out over the inverse's six distinct entries: a
        # three-operand einsum runs unoptimised loops and took half of a vlmm frame
        dx = X[None, :, 0] - mean[:, 0, None]  # (P, M)
        dy = X[None, :, 1] - mean[:, 1, None]
        dz = X[None, :, 2] - mean[:, 2, None]
        q = inv[:, :, :, None]  # (P, 3, 3, 1) broadcasts over M
        maha = (q[:, 0, 0] * dx * dx + q[:, 1, 1] * dy * dy + q[:, 2, 2] * dz * dz
                + 2.0 * (q[:, 0, 1] * dx * dy + q[:, 0, 2] * dx * dz + q[:, 1, 2] * dy * dz))
    else:
        diff = X[None, :, :] - mean[:, None, :]  # (P, M, d)
        maha = np.sum(np.matmul(diff, inv) * diff, axis=-1)
    return (-0.5 * (maha + _logdet(cov)[:, None] + d * np.log(2 * np.pi))).T


#: BGR -> YUV (rows Y, U, V), grey levels; U and V centred on 0
_YUV = np.array([[0.114, 0.587, 0.299], [0.436, -0.289, -0.147], [-0.100, -0.515, 0.615]])
#: grey levels^2 added to each part's colour variance (Y, U, V): lighting changes shift the
#: luminance far more than the chromaticity
COLOUR_REG = np.array([400.0, 25.0, 25.0])


def bgr_to_yuv(bgr) -> np.ndarray:
    """(..., 3) float64 YUV of (..., 3) BGR colours (0..255)."""
    return np.asarray(bgr, dtype=np.float64) @ _YUV.T


@dataclass
class PartColours:
    """The colour of each blob: a Gaussian in YUV (Caillette's blobs carry colour).

    Attributes
    ----------
    means : (P, 3) float64, grey levels
    covs : (P, 3, 3) float64, grey levels^2 (with :data:`COLOUR_REG` added)
    """

    means: np.ndarray
    covs: np.ndarray

    def blend(self, other: "PartColours", rate: float) -> "PartColours":
        """Running average: ``(1 - rate) * self + rate * other``."""
        return PartColours((1 - rate) * self.means + rate * other.means,
                           (1 - rate) * self.covs + rate * other.covs)


def _responsibilities(X, blobs: Blobs):
    lp = _log_gauss(X, blobs.means, blobs.covs) + np.log(np.maximum(blobs.weights, 1e-300))
    return np.exp(lp - logsumexp(lp, axis=1, keepdims=True))


def part_colours(points, colours, blobs: Blobs, *, point_weights=None) -> PartColours:
    """Acquire each blob's colour from coloured voxel points owned softly by ``blobs``.

    Parameters
    ----------
    points : (M, 3) float, metres
    colours : (M, 3) float, YUV grey levels of the points (:func:`bgr_to_yuv`)
    blobs : Blobs (P,), e.g. the fit from a known pose
    point_weights : (M,) float or None, voxel volumes

    Returns
    -------
    PartColours; a part owning no points gets the mean colour and a wide covariance.
    """
    X = np.asarray(points, dtype=np.float64)
    C = np.asarray(colours, dtype=np.float64)
    w = np.ones(len(X)) if point_weights is None else np.asarray(point_weights, np.float64)
    r = _responsibilities(X, blobs) * w[:, None]
    nk = r.sum(axis=0)
    overall = (w @ C) / w.sum()
    mean = np.where(nk[:, None] > 1e-12, (r.T @ C) / np.maximum(nk, 1e-300)[:, None], overall)
    d = C[None] - mean[:, None]
    cov = np.einsum("mp,pmi,pmj->pij", r, d, d) / np.maximum(nk, 1e-300)[:, None, None]
    wide = np.diag(np.var(C, axis=0) + COLOUR_REG)
    cov = np.where((nk > 1e-12)[:, None, None], cov + np.diag(COLOUR_REG), wide)
    return PartColours(mean, cov)


def fit_blobs(points, init: Blobs, *, point_weights=None, iterations: int = 5,
              reg: float = 1e-4, min_support: float = 1e-3, hard: bool = False,
              colours=None, part_colour: PartColours | None = None) -> tuple[Blobs, float]:
    """EM fit of a Gaussian mixture to voxel centres, starting from predicted blobs.

    Parameters
    ----------
    points : (M, 3) float, voxel centres, metres
    init : Blobs (P,), the blobs of a predicted pose (sets the correspondence)
    point_weights : (M,) float or None, voxel volumes (None: equal)
    iterations : int, EM iterations
    reg : float, square metres added to every covariance diagonal (voxel quantisation, and
        so that a blob on a thin limb stays invertible)
    min_support : float, a blob with less than this share of the weight keeps its initial
        shape (an occluded or missing part must not collapse)
    hard : bool, assign each voxel to its most likely blob (the paper's K-means variant)
    colours : (M, 3) float or None, YUV colour of each point
    part_colour : PartColours or None; with ``colours``, a point's ownership also weighs how
        well its colour matches each blob's (fixed) colour Gaussian: the Mahalanobis distance
        on position and colour of the paper's fit, which keeps blobs on their own parts

    Returns
    -------
    blobs : Blobs (P,)
    loglik : float, mean log-likelihood per unit weight of the voxels under the fitted mixture
    """
    one = Blobs(init.means[None], init.covs[None], init.weights[None])
    fitted, ll = fit_blobs_from(points, one, point_weights=point_weights,
                                iterations=iterations, reg=reg, min_support=min_support,
                                hard=hard, colours=colours, part_colour=part_colour)
    return fitted[0], float(ll[0])


#: Log-densities more than this far (nats) below a point's most likely blob are raised to it
#: before they are exponentiated: exp(-50) = 2e-22 vanishes beside the 1 of the most likely
#: blob in a float64 sum, while far points' exponentials would otherwise fall into the
#: subnormal range (exp(-708) and below), which the CPU computes many times slower.
LOG_FLOOR = -50.0


def _quadratic_features(X) -> np.ndarray:
    """(10, M) features ``(x^2, y^2, z^2, xy, xz, yz, x, y, z, 1)`` of points X (M, 3): every
    Gaussian's quadratic form over the points is one dot product with them."""
    x, y, z = np.asarray(X, dtype=np.float64).T
    return np.stack([x * x, y * y, z * z, x * y, x * z, y * z, x, y, z, np.ones_like(x)])


def _log_gauss_coefficients(means, covs, log_weights) -> np.ndarray:
    """(..., P, 10) coefficients of ``log w + log N(x | m, S)`` on :func:`_quadratic_features`
    (means and points in the same, centred, frame)."""
    A = np.linalg.inv(covs)
    Am = np.einsum("...ij,...j->...i", A, means)
    coef = -0.5 * np.stack([A[..., 0, 0], A[..., 1, 1], A[..., 2, 2], 2 * A[..., 0, 1],
                            2 * A[..., 0, 2], 2 * A[..., 1, 2], -2 * Am[..., 0],
                            -2 * Am[..., 1], -2 * Am[..., 2], np.sum(means * Am, axis=-1)],
                           axis=-1)
    coef[..., 9] += log_weights - 0.5 * (_logdet(covs) + 3 * np.log(2 * np.pi))
    return coef


def fit_blobs_from(points, inits: Blobs, *, point_weights=None, iterations: int = 5,
                   reg: float = 1e-4, min_support: float = 1e-3, hard: bool = False,
                   colours=None, part_colour: PartColours | None = None
                   ) -> tuple[Blobs, np.ndarray]:
    """:func:`fit_blobs` from each of K starts at once (the K EM runs are independent).

    Both EM steps go through the points' ten quadratic features (:func:`_quadratic_features`,
    on points centred on their mean): the E step's log-densities of all K * P blobs are one
    matrix product of their coefficients with the features, and the M step's weighted counts,
    sums and second moments are one product of the responsibilities with them. The per-blob
    loops over the points this replaces were a third of a ``vlmm`` frame.

    Parameters
    ----------
    points : (M, 3) float, metres
    inits : Blobs (K, P), the starts
    point_weights, iterations, reg, min_support, hard, colours, part_colour : as
        :func:`fit_blobs` (the colour term is computed once for all starts)

    Returns
    -------
    blobs : Blobs (K, P)
    loglik : (K,) float64, mean log-likelihood per unit weight of each fitted mixture
    """
    X = np.asarray(points, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or len(X) == 0:
        raise ValueError(f"points must be a non-empty (M, 3) array, got shape {X.shape}")
    w = np.ones(len(X)) if point_weights is None else np.asarray(point_weights, np.float64)
    if w.shape != (len(X),) or np.any(w < 0) or not w.sum() > 0:
        raise ValueError("point_weights must be (M,) non-negative with a positive sum")
    if inits.means.ndim != 3:
        raise ValueError(f"inits must be a (K, P) batch of blobs, got means of shape "
                         f"{inits.means.shape}")
    w = w / w.sum()
    # centred, so that the expanded quadratic forms and second moments do not cancel large
    # room coordinates
    c = X.mean(axis=0)
    phi = _quadratic_features(X - c)  # (10, M)
    phi_w = (phi * w).T  # (M, 10): the M step's sums weigh every point by its volume
    mean = inits.means.astype(np.float64) - c
    cov = inits.covs.astype(np.float64) + np.eye(3) * reg
    pi = np.maximum(inits.weights.astype(np.float64), 1e-12)
    pi = pi / pi.sum(axis=-1, keepdims=True)
    K, P = mean.shape[:2]
    col_lp = 0.0
    if colours is not None and part_colour is not None:
        C = np.asarray(colours, dtype=np.float64)
        if C.shape != X.shape:
            raise ValueError(f"colours must be (M, 3) like points, got {C.shape}")
        col_lp = _log_gauss(C, part_colour.means, part_colour.covs).T  # (P, M)
    ll = np.full(K, -np.inf)
    for it in range(int(iterations) + 1):
        lp = _log_gauss_coefficients(mean, cov, np.log(pi)) @ phi + col_lp  # (K, P, M)
        if hard and it < iterations:  # before lp is overwritten below
            r = np.zeros_like(lp)
            np.put_along_axis(r, np.argmax(lp, axis=1)[:, None], 1.0, axis=1)
        # the log-sum-exp over the blobs and the responsibilities from one exponential, in
        # place (the exponentials are most of an iteration)
        top = np.max(lp, axis=1, keepdims=True)
        top = np.where(np.isfinite(top), top, 0.0)
        e = np.exp(np.maximum(np.subtract(lp, top, out=lp), LOG_FLOOR, out=lp), out=lp)
        total = np.sum(e, axis=1, keepdims=True)  # (K, 1, M)
        with np.errstate(divide="ignore"):
            ll = (np.log(total) + top)[:, 0] @ w
        if it == iterations:
            break
        if not hard:
            with np.errstate(invalid="ignore", divide="ignore"):
                r = np.divide(e, total, out=e)
        S = r @ phi_w  # (K, P, 10): weighted second moments, sums and counts
        nk = S[..., 9]
        ok = nk > min_support
        safe = np.maximum(nk, 1e-300)[..., None]
        m_new = S[..., 6:9] / safe
        second = S[..., [0, 3, 4, 3, 1, 5, 4, 5, 2]].reshape(K, P, 3, 3) / safe[..., None]
        c_new = second - m_new[..., :, None] * m_new[..., None, :]
        mean = np.where(ok[..., None], m_new, mean)
        cov = np.where(ok[..., None, None], c_new + np.eye(3) * reg, cov)
        # a start with no supported blob keeps its mixture (EM has nothing to move it by)
        moved = ok.any(axis=1, keepdims=True)
        pi_new = np.where(ok, nk, min_support)
        pi = np.where(moved, pi_new / pi_new.sum(axis=1, keepdims=True), pi)
    return Blobs(mean + c, cov, pi), ll


#: (mixture, blob, point) log-densities :func:`mixture_loglik` holds at once (64 MB in
#: float32, 128 in float64): the ranking's 108 prototypes x 15 blobs x 2000 voxel points in
#: one go
CHUNK_ELEMENTS = 1 << 24


def mixture_loglik(points, blobs: Blobs, *, point_weights=None, chunk: int | None = None,
                   dtype=np.float64) -> np.ndarray:
    """Mean log-likelihood of voxel centres under each of N blob mixtures (no fitting).

    Parameters
    ----------
    points : (M, 3) float, metres
    blobs : Blobs (N, P) (or (P,) for one mixture)
    point_weights : (M,) float or None, voxel volumes
    chunk : int, mixtures evaluated at once (bounds the (chunk, P, M) temporaries); default:
        as many as :data:`CHUNK_ELEMENTS` allows
    dtype : float type of the quadratic forms and the mixture sums: ``np.float32`` is 2x
        faster (the float64 product's output, cast, was half the ranking's time) and accurate
        to about 1e-5 nats (the forms' constant terms reach a few hundred nats on thin blobs,
        where a float32 carries 3e-5), enough to rank candidates

    Returns
    -------
    (N,) float64 (a float array of shape () for a single mixture)
    """
    X = np.asarray(points, dtype=np.float64)
    w = np.ones(len(X)) if point_weights is None else np.asarray(point_weights, np.float64)
    w = w / w.sum()
    single = blobs.means.ndim == 2
    b = Blobs(blobs.means[None], blobs.covs[None], blobs.weights[None]) if single else blobs
    N, P = b.means.shape[:2]
    # Every (mixture, blob) quadratic form (x - m)^T A (x - m) is a dot product of the same ten
    # point features (x_i x_j, x_i, 1) with ten coefficients, so all N * P of them are one
    # matrix product. The points are centred first: on room coordinates the expanded form
    # would cancel large terms.
    c = X.mean(axis=0)
    phi = _quadratic_features(X - c).astype(dtype, copy=False)
    coef_all = _log_gauss_coefficients(b.means - c, b.covs,
                                       np.log(np.maximum(b.weights, 1e-300)))
    coef_all = coef_all.reshape(N * P, 10).astype(dtype, copy=False)
    if chunk is None:  # as many as fit the budget: each chunk's set-up costs as much as its work
        chunk = max(1, CHUNK_ELEMENTS // max(P * len(X), 1))
    out = np.empty(N)
    for a in range(0, N, chunk):
        n = min(chunk, N - a)
        lp = (coef_all[a * P:(a + n) * P] @ phi).reshape(n, P, -1)
        # the log-sum-exp in place, far blobs floored as in the fit (LOG_FLOOR)
        top = np.max(lp, axis=1, keepdims=True)
        top = np.where(np.isfinite(top), top, 0.0)
        e = np.exp(np.maximum(np.subtract(lp, top, out=lp), LOG_FLOOR, out=lp), out=lp)
        with np.errstate(divide="ignore"):
            out[a:a + n] = (np.log(np.sum(e, axis=1)) + top[:, 0]) @ w
    return out[0] if single else out
