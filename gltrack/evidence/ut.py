"""The scaled unscented transform (Julier 2002; van der Merwe 2004), filterpy-style.

A sigma-point strategy is a small object with ``sigma_points(x, P)`` and the weight vectors
``Wm``/``Wc``; :func:`unscented_transform` turns propagated sigma points back into a mean and a
covariance. ``residual``/``mean_fn`` hooks let state spaces with angles wrap correctly.

Sigma points are the rows ``x``, ``x + L_k``, ``x - L_k`` (k = 0..n-1) where ``L`` is an upper
Cholesky factor of ``(n + lambda) P`` (``L.T @ L = (n + lambda) P``) and
``lambda = alpha^2 (n + kappa) - n``.
"""
from __future__ import annotations

import logging

import numpy as np
import scipy.linalg

log = logging.getLogger(__name__)


def _matrix_sqrt(A: np.ndarray) -> np.ndarray:
    """Upper factor ``U`` with ``U.T @ U = A``; symmetric eigen-root for semi-definite ``A``.

    Cholesky is the cheap, deterministic choice; it fails on the rank-deficient covariances that
    locked or converged DOFs produce, where the eigen-root still gives valid sigma points.
    """
    try:
        return scipy.linalg.cholesky(A, lower=False)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(0.5 * (A + A.T))
        if w.min() < -1e-9 * max(1.0, abs(w).max()):
            raise ValueError(f"covariance is not positive semi-definite (eigenvalue {w.min():.3g})")
        return (V * np.sqrt(np.clip(w, 0.0, None))).T


class MerweScaledSigmaPoints:
    """Van der Merwe's scaled sigma points, ``2n + 1`` of them.

    Parameters
    ----------
    n : int, state dimension
    alpha : float in (0, 1]
        Spread of the points about the mean (small alpha: local, Jacobian-like linearisation).
    beta : float
        Prior knowledge of the distribution; 2 is optimal for a Gaussian.
    kappa : float
        Secondary scaling; ``3 - n`` matches the fourth moment of a Gaussian.
    sqrt_method : callable, optional
        ``A -> U`` with ``U.T @ U = A`` (rows are the sigma offsets); default Cholesky with an
        eigen-decomposition fallback for singular ``A``.
    subtract : callable, optional
        ``(a, b) -> a - b`` for states that need wrapping (not used to build points; kept for
        filters that take the strategy object and want one place for the state's algebra).

    Attributes
    ----------
    Wm, Wc : (2n+1,) float64, mean and covariance weights; ``Wm`` sums to 1.
    """

    def __init__(self, n: int, alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0,
                 sqrt_method=None, subtract=None):
        n = int(n)
        if n < 1:
            raise ValueError(f"state dimension must be >= 1, got {n}")
        if not alpha > 0:
            raise ValueError(f"alpha must be positive, got {alpha}")
        self.n, self.alpha, self.beta, self.kappa = n, float(alpha), float(beta), float(kappa)
        # n + lambda straight from its definition: forming lambda first and adding n back
        # cancels catastrophically for small alpha
        self._scale = self.alpha ** 2 * (n + self.kappa)
        self.lambda_ = self._scale - n
        if not self._scale > 0:
            raise ValueError(f"n + lambda must be positive (n={n}, alpha={alpha}, kappa={kappa})")
        self.sqrt = sqrt_method or _matrix_sqrt
        self.subtract = subtract or np.subtract
        c = 0.5 / self._scale
        self.Wm = np.full(2 * n + 1, c)
        self.Wc = np.full(2 * n + 1, c)
        self.Wm[0] = 1.0 - n / self._scale
        self.Wc[0] = self.Wm[0] + (1.0 - self.alpha ** 2 + self.beta)

    def num_sigmas(self) -> int:
        return 2 * self.n + 1

    def sigma_points(self, x, P) -> np.ndarray:
        """Sigma points of ``N(x, P)``.

        Parameters
        ----------
        x : (n,) float, mean
        P : (n, n) float or scalar, covariance (a scalar means ``P * I``)

        Returns
        -------
        (2n+1, n) float64
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        if x.size != self.n:
            raise ValueError(f"expected a state of size {self.n}, got {x.size}")
        P = np.asarray(P, dtype=np.float64)
        if P.ndim == 0:
            P = np.eye(self.n) * P
        if P.shape != (self.n, self.n):
            raise ValueError(f"covariance must be ({self.n}, {self.n}), got {P.shape}")
        U = self.sqrt(self._scale * P)
        return np.concatenate([x[None], x[None] + U, x[None] - U])

    def __repr__(self) -> str:
        return (f"MerweScaledSigmaPoints(n={self.n}, alpha={self.alpha}, beta={self.beta}, "
                f"kappa={self.kappa})")


def unscented_transform(sigmas_f, Wm, Wc, noise_cov=None, mean_fn=None, residual=None):
    """Mean and covariance of propagated sigma points.

    Parameters
    ----------
    sigmas_f : (2n+1, m) float, sigma points after the non-linear map
    Wm, Wc : (2n+1,) float, weights of the strategy that made the points
    noise_cov : (m, m) float, optional, additive noise covariance
    mean_fn : callable, optional
        ``(sigmas, Wm) -> (m,)`` weighted mean, e.g. a circular mean for angles.
    residual : callable, optional
        ``(a, b) -> a - b`` for rows ``a`` (k, m) and a mean ``b`` (m,); e.g. wraps angles to
        (-pi, pi].

    Returns
    -------
    mean : (m,) float64
    cov : (m, m) float64
    """
    S = np.asarray(sigmas_f, dtype=np.float64)
    if S.ndim == 1:
        S = S[:, None]
    Wm = np.asarray(Wm, dtype=np.float64)
    Wc = np.asarray(Wc, dtype=np.float64)
    if S.shape[0] != Wm.size or Wm.size != Wc.size:
        raise ValueError(f"{S.shape[0]} sigma points but {Wm.size} mean / {Wc.size} "
                         "covariance weights")
    mean = np.asarray(mean_fn(S, Wm), dtype=np.float64) if mean_fn else Wm @ S
    d = residual(S, mean) if residual else S - mean[None]
    cov = (d * Wc[:, None]).T @ d
    if noise_cov is not None:
        cov = cov + noise_cov
    return mean, cov


def cross_covariance(sigmas_x, mean_x, sigmas_y, mean_y, Wc, residual_x=None, residual_y=None):
    """Weighted cross-covariance ``sum_k Wc_k (x_k - mean_x)(y_k - mean_y)^T``.

    Parameters
    ----------
    sigmas_x : (2n+1, n) float, sigma points before the map
    mean_x : (n,) float
    sigmas_y : (2n+1, m) float, the same points after the map
    mean_y : (m,) float
    Wc : (2n+1,) float
    residual_x, residual_y : callable, optional, as in :func:`unscented_transform`

    Returns
    -------
    (n, m) float64
    """
    X = np.asarray(sigmas_x, dtype=np.float64)
    Y = np.asarray(sigmas_y, dtype=np.float64)
    if Y.ndim == 1:
        Y = Y[:, None]
    dx = residual_x(X, mean_x) if residual_x else X - np.asarray(mean_x)[None]
    dy = residual_y(Y, mean_y) if residual_y else Y - np.asarray(mean_y)[None]
    return (dx * np.asarray(Wc, dtype=np.float64)[:, None]).T @ dy
