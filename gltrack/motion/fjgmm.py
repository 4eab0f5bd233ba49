"""Gaussian mixtures learnt with the Figueiredo-Jain algorithm.

Figueiredo & Jain, "Unsupervised learning of finite mixture models", IEEE PAMI 24(3), 2002.
The fit starts from many components (``k_max``) placed on random data points and runs
component-wise EM (CEM^2): each component's responsibilities, weight, mean and covariance are
updated in turn, with the minimum-message-length (MML) weight update

    alpha_m = max(0, sum_i w_im - N/2) / sum_j max(0, sum_i w_ij - N/2)

(N = free parameters of one component), so a component whose support falls below N/2 points
is annihilated at once. When CEM^2 converges, the MML cost

    L = N/2 sum_m log(n alpha_m / 12) + k/2 log(n / 12) + k (N + 1) / 2 - log p(X | theta)

is recorded for that number of components k, the weakest component is removed and CEM^2
restarts, down to ``k_min``. The mixture with the lowest cost is returned. This is how
Caillette et al. (2008, section 4.1) cluster the motion feature space.

By default the cost is the one of the authors' reference implementation (mixtures4.m),

    L = N/2 sum_m log(alpha_m) + (N + 1)/2 k log(n) - log p(X | theta),

which drops the O(1) terms of the paper's formula above; those terms are negative, so the
default penalises each component by (N + 1)/2 (log 12 - 1) nats more. Without it, small
spurious components (a few more than N/2 points fitted tightly) often survive in low
dimensions. ``paper_cost=True`` selects the formula printed in the paper.

Covariance regularisation: after every covariance update ``reg * s`` is added to the diagonal,
where ``s`` is the mean per-dimension variance of the data (so ``reg`` is scale free; a tiny
absolute floor keeps constant data valid). This keeps components from collapsing onto a few
points or onto a subspace (e.g. a joint that never moves in the training clip).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import cho_factor, solve_triangular
from scipy.special import logsumexp

log = logging.getLogger(__name__)

_LOG_2PI = np.log(2.0 * np.pi)
_ABS_FLOOR = 1e-12


def _component_logpdf(X: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """log N(X | mean, cov) for (T, d) X; raises numpy.linalg.LinAlgError if not PD."""
    d = X.shape[1]
    diff = X - mean
    if np.count_nonzero(cov - np.diag(np.diagonal(cov))) == 0:
        var = np.diagonal(cov)
        if np.any(var <= 0):
            raise np.linalg.LinAlgError("non-positive variance")
        maha = np.sum(diff * diff / var, axis=1)
        logdet = np.sum(np.log(var))
    else:
        c, lower = cho_factor(cov, lower=True, check_finite=False)
        z = solve_triangular(c, diff.T, lower=True, check_finite=False)
        maha = np.sum(z * z, axis=0)
        logdet = 2.0 * np.sum(np.log(np.diagonal(c)))
    return -0.5 * (d * _LOG_2PI + logdet + maha)


def sqrtm_psd(cov: np.ndarray) -> np.ndarray:
    """Symmetric square root ``V sqrt(D) V^T`` of PSD matrices (..., d, d) by eigendecomposition.

    Negative eigenvalues from round-off are clipped to zero.
    """
    w, v = np.linalg.eigh(np.asarray(cov, dtype=np.float64))
    return (v * np.sqrt(np.clip(w, 0.0, None))[..., None, :]) @ np.swapaxes(v, -1, -2)


@dataclass(frozen=True)
class GaussianMixture:
    """A Gaussian mixture model.

    Attributes
    ----------
    weights : (K,) float64, mixing weights summing to 1.
    means : (K, d) float64.
    covs : (K, d, d) float64, symmetric positive definite (diagonal when fitted with
        ``covariance="diag"``).
    cost_path : (M, 2) float64, rows ``(k, MML cost)`` recorded by :func:`fit_fj_gmm` for each
        number of components it converged at, in the order visited (empty if not fitted).
    """

    weights: np.ndarray
    means: np.ndarray
    covs: np.ndarray
    cost_path: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    def __post_init__(self):
        w = np.asarray(self.weights, dtype=np.float64)
        m = np.asarray(self.means, dtype=np.float64)
        c = np.asarray(self.covs, dtype=np.float64)
        p = np.asarray(self.cost_path, dtype=np.float64).reshape(-1, 2)
        if w.ndim != 1 or w.size < 1:
            raise ValueError(f"weights must have shape (K,) with K >= 1, got {w.shape}")
        k = w.size
        if m.ndim != 2 or m.shape[0] != k:
            raise ValueError(f"means must have shape ({k}, d), got {m.shape}")
        d = m.shape[1]
        if c.shape != (k, d, d):
            raise ValueError(f"covs must have shape ({k}, {d}, {d}), got {c.shape}")
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(m)) and np.all(np.isfinite(c))):
            raise ValueError("weights, means and covs must be finite")
        if np.any(w < 0) or abs(w.sum() - 1.0) > 1e-6:
            raise ValueError(f"weights must be non-negative and sum to 1 (sum {w.sum():.6g})")
        if not np.allclose(c, np.swapaxes(c, 1, 2), rtol=1e-8, atol=1e-12):
            raise ValueError("covs must be symmetric")
        for j in range(k):
            try:
                np.linalg.cholesky(c[j])
            except np.linalg.LinAlgError:
                raise ValueError(f"covs[{j}] is not positive definite") from None
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "means", m)
        object.__setattr__(self, "covs", c)
        object.__setattr__(self, "cost_path", p)

    @property
    def n_components(self) -> int:
        return int(self.weights.size)

    @property
    def dim(self) -> int:
        return int(self.means.shape[1])

    def _check_X(self, X) -> np.ndarray:
        a = np.asarray(X, dtype=np.float64)
        if a.ndim == 1:
            a = a[None]
        if a.ndim != 2 or a.shape[1] != self.dim:
            raise ValueError(f"X must have shape (T, {self.dim}), got {np.shape(X)}")
        return a

    def logpdf_components(self, X) -> np.ndarray:
        """Per-component log densities ``log N(x_t | mean_k, cov_k)`` (weights not included).

        Parameters
        ----------
        X : (T, d) float array.

        Returns
        -------
        (T, K) float64.
        """
        a = self._check_X(X)
        return np.stack([_component_logpdf(a, self.means[k], self.covs[k])
                         for k in range(self.n_components)], axis=1)

    def log_responsibilities(self, X) -> np.ndarray:
        """(T, K) float64 log posterior ``log P(k | x_t)``."""
        lw = self.logpdf_components(X) + np.log(np.maximum(self.weights, 1e-300))
        return lw - logsumexp(lw, axis=1, keepdims=True)

    def score_samples(self, X) -> np.ndarray:
        """(T,) float64 mixture log density ``log p(x_t)``."""
        lw = self.logpdf_components(X) + np.log(np.maximum(self.weights, 1e-300))
        return logsumexp(lw, axis=1)

    def predict(self, X) -> np.ndarray:
        """(T,) int64 most probable component of each row of ``X`` (T, d)."""
        return np.argmax(self.log_responsibilities(X), axis=1).astype(np.int64)

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Draw ``n`` points; returns ``(X (n, d) float64, labels (n,) int64)``."""
        labels = rng.choice(self.n_components, size=int(n), p=self.weights).astype(np.int64)
        z = rng.standard_normal((int(n), self.dim))
        roots = sqrtm_psd(self.covs)
        return self.means[labels] + np.einsum("nij,nj->ni", roots[labels], z), labels


def _n_free_params(d: int, covariance: str) -> int:
    return d + (d * (d + 1) // 2 if covariance == "full" else d)


def fit_fj_gmm(X, rng: np.random.Generator, k_max: int = 30, k_min: int = 1,
               tol: float = 1e-5, reg: float = 1e-6, max_iter: int = 500,
               covariance: str = "full", init_scale: float = 0.1,
               paper_cost: bool = False) -> GaussianMixture:
    """Fit a Gaussian mixture with the Figueiredo-Jain MML algorithm (see module docstring).

    Parameters
    ----------
    X : (T, d) float array of samples.
    rng : numpy.random.Generator, picks the ``k_max`` initial means among the samples.
    k_max : int, initial (and largest possible) number of components; capped at T.
    k_min : int, smallest number of components tried.
    tol : float, CEM^2 stops for a given k when the relative change of the MML cost between
        two sweeps is below ``tol``.
    reg : float, covariance regularisation relative to the mean data variance (module docstring).
    max_iter : int, maximum CEM^2 sweeps for each number of components.
    covariance : ``"full"`` or ``"diag"``. Diagonal components need d + d instead of
        d + d(d+1)/2 parameters, hence far fewer samples per component (N/2 each).
    init_scale : float, initial covariances are ``init_scale * max_j var(X[:, j]) * I``
        (Figueiredo & Jain use 1/10).
    paper_cost : bool, use the MML cost as printed in the paper instead of the reference
        implementation's (module docstring).

    Returns
    -------
    GaussianMixture with at most ``k_max`` components and ``cost_path`` filled.
    """
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] < 2 or X.shape[1] < 1:
        raise ValueError(f"X must have shape (T, d) with T >= 2, got {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError("X contains non-finite values")
    if covariance not in ("full", "diag"):
        raise ValueError(f"covariance must be 'full' or 'diag', got {covariance!r}")
    if not 1 <= k_min <= k_max:
        raise ValueError(f"need 1 <= k_min <= k_max, got k_min={k_min}, k_max={k_max}")
    n, d = X.shape
    k = min(int(k_max), n)
    k_min = min(int(k_min), k)
    var = X.var(axis=0)
    floor = reg * float(var.mean()) + _ABS_FLOOR
    half = 0.5 * _n_free_params(d, covariance)
    if n < half:
        log.warning("%d samples cannot support even one %s-covariance component in %d-D "
                    "(needs %.0f); the single-component fallback is returned", n, covariance,
                    d, half)

    means = X[rng.choice(n, size=k, replace=False)].copy()
    covs = np.repeat((init_scale * float(var.max()) + floor) * np.eye(d)[None], k, axis=0)
    weights = np.full(k, 1.0 / k)
    logpdf = np.stack([_component_logpdf(X, means[m], covs[m]) for m in range(k)], axis=1)
    eye = np.eye(d)

    def update(m: int, resp: np.ndarray, support: float) -> None:
        mu = resp @ X / support
        diff = X - mu
        if covariance == "full":
            c = (diff * resp[:, None]).T @ diff / support
            c = 0.5 * (c + c.T) + floor * eye
        else:
            c = np.diag(resp @ (diff * diff) / support + floor)
        means[m], covs[m] = mu, c
        logpdf[:, m] = _component_logpdf(X, mu, c)

    def cost() -> tuple[float, float]:
        loglik = float(np.sum(logsumexp(logpdf + np.log(weights), axis=1)))
        kk = weights.size
        if paper_cost:
            mml = (half * float(np.sum(np.log(n * weights / 12.0))) + 0.5 * kk * np.log(n / 12.0)
                   + 0.5 * kk * (2.0 * half + 1.0) - loglik)
        else:
            mml = half * float(np.sum(np.log(weights))) + (half + 0.5) * kk * np.log(n) - loglik

        return mml, loglik

    best = None
    path = []
    while True:
        prev = None
        for it in range(max_iter):
            m = 0
            while m < weights.size:
                lw = logpdf + np.log(np.maximum(weights, 1e-300))
                resp = np.exp(lw[:, m] - logsumexp(lw, axis=1))
                support = float(resp.sum())
                weights[m] = max(support - half, 0.0) / n
                if weights[m] == 0.0 and weights.size > 1:
                    # MML annihilation: too few points to pay for this component's parameters
                    keep = np.arange(weights.size) != m
                    means, covs, logpdf = means[keep], covs[keep], logpdf[:, keep]
                    weights = weights[keep]
                    weights /= weights.sum()
                    continue
                if weights.size == 1:
                    weights[:] = 1.0
                else:
                    weights /= weights.sum()
                if support > 1e-10:
                    update(m, resp, support)
                m += 1
            c, _ = cost()
            if prev is not None and abs(prev - c) <= tol * abs(prev):
                break
            prev = c
        else:
            log.debug("CEM2 did not converge in %d sweeps at k=%d", max_iter, weights.size)
        c, loglik = cost()
        path.append((weights.size, c))
        log.debug("k=%d converged: MML cost %.6g, log-likelihood %.6g", weights.size, c, loglik)
        if best is None or c < best[0]:
            best = (c, weights.copy(), means.copy(), covs.copy())
        if weights.size <= k_min:
            break
        # drop the weakest component and let CEM2 redistribute its points
        keep = np.arange(weights.size) != int(np.argmin(weights))
        means, covs, logpdf, weights = means[keep], covs[keep], logpdf[:, keep], weights[keep]
        weights /= weights.sum()

    _, w, mu, cv = best
    log.info("FJ-GMM: %d components chosen (started from %d, %d-D, %d samples)", w.size, k, d, n)
    return GaussianMixture(w, mu, cv, np.asarray(path, dtype=np.float64))
