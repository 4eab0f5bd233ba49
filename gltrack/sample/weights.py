"""Importance weights: log-weights, normalised weights, ESS, annealing exponents.

Samplers receive raw weights ``w >= 0`` (larger is better) from a weight function and keep
them as log-weights, so tempering (``w ** beta``) is a multiplication and tiny weights do not
underflow. ``Weights`` follows ``particles.resampling.Weights``: it holds ``lw`` and derives
the normalised weights ``W`` and the effective sample size ``ess`` from it.
"""
from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger(__name__)


class Weights:
    """A set of N log-weights with derived normalised weights and ESS.

    Parameters
    ----------
    lw : (N,) float
        Log-weights; ``-inf`` marks a weight of zero. If every entry is ``-inf`` the set is
        treated as uniform (logged as a warning), so a filter degrades instead of crashing.

    Attributes
    ----------
    lw : (N,) float64, the log-weights as given
    W : (N,) float64, normalised weights (sum 1)
    ess : float, effective sample size ``1 / sum(W**2)``, in [1, N]
    """

    def __init__(self, lw):
        lw = np.asarray(lw, dtype=np.float64)
        if lw.ndim != 1 or lw.size == 0:
            raise ValueError(f"log-weights must be a non-empty 1-D array, got shape {lw.shape}")
        if np.any(np.isnan(lw)) or np.any(lw == np.inf):
            raise ValueError("log-weights must not be NaN or +inf")
        self.lw = lw
        m = lw.max()
        if m == -np.inf:
            log.warning("all %d weights are zero; using uniform weights", lw.size)
            self.W = np.full(lw.size, 1.0 / lw.size)
        else:
            e = np.exp(lw - m)
            self.W = e / e.sum()
        self.ess = float(1.0 / np.sum(self.W ** 2))

    @classmethod
    def from_weights(cls, w) -> "Weights":
        """From raw non-negative weights (N,); raises ``ValueError`` if any is negative/NaN."""
        return cls(log_weights(w))

    def __len__(self) -> int:
        return self.lw.size

    @property
    def survival(self) -> float:
        """Deutscher's particle survival rate ``ESS / N`` in (0, 1]."""
        return self.ess / self.lw.size

    def tempered(self, beta: float) -> "Weights":
        """The weights raised to the power ``beta`` (``beta * lw``); ``beta = 0`` is uniform
        over the particles whose weight is non-zero."""
        if beta == 0:
            return Weights(np.where(self.lw > -np.inf, 0.0, -np.inf))
        return Weights(beta * self.lw)

    def mean(self, x: np.ndarray) -> np.ndarray:
        """Weighted mean of ``x`` (N, ...) over its first axis."""
        return np.tensordot(self.W, np.asarray(x, dtype=np.float64), axes=1)

    def cov(self, x: np.ndarray) -> np.ndarray:
        """(D, D) weighted covariance of ``x`` (N, D) (biased, i.e. normalised by sum W)."""
        x = np.asarray(x, dtype=np.float64)
        d = x - self.mean(x)
        return (d * self.W[:, None]).T @ d

    def var(self, x: np.ndarray) -> np.ndarray:
        """(D,) weighted per-dimension variance of ``x`` (N, D)."""
        x = np.asarray(x, dtype=np.float64)
        return self.W @ (x - self.mean(x)) ** 2


def log_weights(w) -> np.ndarray:
    """Validate raw weights (N,) ``>= 0`` and return their logs (``-inf`` for zeros)."""
    w = np.asarray(w, dtype=np.float64)
    if w.ndim != 1:
        raise ValueError(f"weights must be 1-D, got shape {w.shape}")
    if np.any(~np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative")
    with np.errstate(divide="ignore"):
        return np.log(w)


def cost_weights(cost, scale: float = 1.0) -> Weights:
    """The one cost -> weight mapping of gltrack: ``w = exp(-(cost - min cost) / scale)``.

    Every tracker whose likelihood is a cost (KL divergence in nats, a scaled silhouette error)
    hands its particles' weights to a sampler through this function; the result is kept as
    log-weights, so no weight underflows however far a particle is from the best (a raw
    ``exp(-2000)`` would be 0 and drop out of the sampler's exponent search).

    Parameters
    ----------
    cost : (N,) float, lower is better (finite)
    scale : float > 0, cost units per nat (1: the cost is a negative log-likelihood)

    Returns
    -------
    Weights with ``lw = -(cost - cost.min()) / scale`` (the best particle has ``lw = 0``).
    A sampler that tempers (annealing layers, a target survival rate) rescales them anyway.
    """
    c = np.asarray(cost, dtype=np.float64)
    if c.ndim != 1 or c.size == 0 or not np.all(np.isfinite(c)):
        raise ValueError(f"costs must be a finite non-empty 1-D array, got shape {c.shape}")
    if not scale > 0:
        raise ValueError(f"scale must be > 0, got {scale}")
    return Weights(-(c - c.min()) / scale)


def ess(weights) -> float:
    """Effective sample size ``(sum w)^2 / sum w^2`` of raw non-negative weights (N,)."""
    w = np.asarray(weights, dtype=np.float64)
    s = w.sum()
    if not s > 0:
        raise ValueError("weights are all zero")
    return float(s * s / np.sum(w * w))


def minmax_norm(x) -> np.ndarray:
    """Scale (N,) values to [0, 1]: lowest encountered -> 0, highest -> 1 (all 0 if constant)."""
    x = np.asarray(x, dtype=np.float64)
    lo, hi = x.min(), x.max()
    if hi - lo <= 0:
        return np.zeros_like(x)
    return (x - lo) / (hi - lo)


def bandouch_weights(e_s, c_a, alpha: float = 0.7, beta: float = 0.3) -> np.ndarray:
    """Bandouch et al. (2009) eq. 2: ``w = alpha (1 - NORM(e_S)) + beta NORM(c_A)``.

    Parameters
    ----------
    e_s : (N,) float
        Shape error of each particle (e.g. silhouette XOR pixel count); lower is better.
    c_a : (N,) float or None
        Appearance correlation (consistent colour count); higher is better. ``None`` drops
        the appearance term (``w = alpha (1 - NORM(e_S))``).
    alpha, beta : float
        Balance of shape and appearance (the paper uses 0.7 and 0.3).

    Returns
    -------
    (N,) float64 weights in [0, alpha + beta]. NORM is a min-max scaling over this particle
    set, so the weights are relative: they only rank particles of one evaluation batch.
    """
    e_s = np.asarray(e_s, dtype=np.float64)
    if e_s.ndim != 1 or not np.all(np.isfinite(e_s)):
        raise ValueError(f"e_s must be a finite 1-D array, got shape {e_s.shape}")
    w = alpha * (1.0 - minmax_norm(e_s))
    if c_a is not None:
        c_a = np.asarray(c_a, dtype=np.float64)
        if c_a.shape != e_s.shape or not np.all(np.isfinite(c_a)):
            raise ValueError(f"c_a must be finite with the shape of e_s {e_s.shape}, "
                             f"got {c_a.shape}")
        w = w + beta * minmax_norm(c_a)
    return w


def annealing_exponent(lw, alpha: float = 0.5, *, tol: float = 1e-4,
                       beta_max: float = 1e6, max_iter: int = 200) -> float:
    """Deutscher's annealing exponent: the ``beta`` with ``ESS(w**beta) / N = alpha``.

    The survival rate ``ESS(w**beta) / N`` falls monotonically from its value at
    ``beta -> 0`` (the fraction of non-zero weights) as ``beta`` grows, so ``beta`` is found by
    bisection (on ``log beta``, because useful exponents span decades).

    Parameters
    ----------
    lw : (N,) float
        Log-weights (``-inf`` allowed).
    alpha : float in (0, 1)
        Target survival rate.

    Returns
    -------
    float ``beta > 0``. If even ``beta_max`` keeps the survival rate above ``alpha`` (a nearly
    flat weight function) ``beta_max`` is returned; if the target is unreachable because too
    few weights are non-zero, the smallest exponent tried (``beta_max * 1e-12``) is returned.
    """
    if not 0 < alpha < 1:
        raise ValueError(f"target survival rate alpha must be in (0, 1), got {alpha}")
    lw = np.asarray(lw, dtype=np.float64)
    n = lw.size
    finite = lw[np.isfinite(lw)]
    if finite.size == 0 or np.ptp(finite) == 0:
        return float(beta_max)
    finite = finite - finite.max()

    def survival(beta):
        e = np.exp(beta * finite)
        return e.sum() ** 2 / np.sum(e * e) / n

    lo, hi = np.log(beta_max) - np.log(1e12), np.log(beta_max)
    if survival(np.exp(hi)) >= alpha:
        return float(beta_max)
    if survival(np.exp(lo)) <= alpha:
        return float(np.exp(lo))
    for _ in range(max_iter):
        mid = 0.5 * (lo + hi)
        if survival(np.exp(mid)) > alpha:
            lo = mid
        else:
            hi = mid
        if hi - lo < tol:
            break
    return float(np.exp(0.5 * (lo + hi)))
