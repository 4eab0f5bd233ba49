"""Resampling schemes: pure functions from normalised weights to ancestor indices.

In the style of ``filterpy.monte_carlo``: every function takes ``weights`` (N,) (non-negative,
not necessarily normalised), a ``numpy.random.Generator`` and an optional output count ``n``
(default N), and returns ``(n,) int64`` indices into the weighted set. All four are unbiased:
the expected number of copies of particle i is ``n * W_i``. They differ in variance
(multinomial > stratified, residual > systematic in practice) and in cost (all O(N log N) or
better here).
"""
from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger(__name__)


def normalise(weights) -> np.ndarray:
    """Validate ``weights`` and return them as a (N,) float64 array summing to 1.

    Raises ``ValueError`` for an empty, non-1-D, negative, non-finite or all-zero input.
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1 or w.size == 0:
        raise ValueError(f"weights must be a non-empty 1-D array, got shape {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative")
    total = w.sum()
    if not total > 0:
        raise ValueError("weights are all zero")
    return w / total


def _count(n, w) -> int:
    n = len(w) if n is None else int(n)
    if n < 1:
        raise ValueError(f"number of resampled particles must be >= 1, got {n}")
    return n


def _search(W: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Indices i with cumsum(W)[i-1] <= u < cumsum(W)[i] (u sorted or not)."""
    c = np.cumsum(W)
    c[-1] = 1.0  # rounding must not let u fall off the end
    return np.minimum(np.searchsorted(c, u, side="right"), len(W) - 1).astype(np.int64)


def multinomial_resample(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """n independent draws from the categorical distribution ``W``."""
    W = normalise(weights)
    return _search(W, rng.random(_count(n, W)))


def stratified_resample(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """One uniform draw in each of n equal strata of [0, 1)."""
    W = normalise(weights)
    n = _count(n, W)
    return _search(W, (np.arange(n) + rng.random(n)) / n)


def systematic_resample(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """One uniform offset shared by n equally spaced points (lowest variance, the default)."""
    W = normalise(weights)
    n = _count(n, W)
    return _search(W, (np.arange(n) + rng.random()) / n)


def residual_resample(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """floor(n W_i) deterministic copies, the remainder drawn multinomially from the residuals."""
    W = normalise(weights)
    n = _count(n, W)
    copies = np.floor(n * W).astype(np.int64)
    idx = np.repeat(np.arange(len(W), dtype=np.int64), copies)
    rest = n - int(copies.sum())
    if rest > 0:
        resid = n * W - copies
        idx = np.concatenate([idx, _search(resid / resid.sum(), rng.random(rest))])
    return idx


RESAMPLERS = {
    "multinomial": multinomial_resample,
    "stratified": stratified_resample,
    "systematic": systematic_resample,
    "residual": residual_resample,
}


def get_resampler(name_or_fn):
    """A resampling function from its name (see ``RESAMPLERS``) or the function itself."""
    if callable(name_or_fn):
        return name_or_fn
    try:
        return RESAMPLERS[name_or_fn]
    except KeyError:
        raise ValueError(f"unknown resampler {name_or_fn!r}; choose one of "
                         f"{', '.join(RESAMPLERS)}") from None
