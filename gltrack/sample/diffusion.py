"""Gaussian diffusion of particle sets inside joint limits.

The motion model of every sampler here is Bandouch's: propagate the last state and add zero-mean
Gaussian noise with the body-part dependent inter-frame standard deviations, then project onto
the joint limits (clamping, the policy of ``DofSet.validate``). Annealing layers shrink that noise
in one of three ways (Bandouch 2009, sec. 3.1):

* ``"constant"``: ``sigma * factor**m`` (Deutscher's original);
* ``"layer_variance"``: per-dimension standard deviation of the previous layer's particle set;
* ``"covariance"``: the full covariance of the previous layer's particle set (the best variant
  in Bandouch's experiments, and the default), so correlated DOFs are explored along their
  ridge instead of across it.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .weights import Weights

log = logging.getLogger(__name__)

VARIANTS = ("constant", "layer_variance", "covariance")


@dataclass(frozen=True)
class StateSpace:
    """Limits and motion-model noise of a D-dimensional pose space.

    Attributes
    ----------
    lower, upper : (D,) float64, limits (radians or metres; +-inf for unbounded)
    sigma : (D,) float64, per-frame diffusion standard deviation (same units)
    """

    lower: np.ndarray
    upper: np.ndarray
    sigma: np.ndarray

    def __post_init__(self):
        lo, hi, sg = (np.asarray(a, dtype=np.float64).ravel()
                      for a in (self.lower, self.upper, self.sigma))
        if not (lo.shape == hi.shape == sg.shape):
            raise ValueError(f"lower {lo.shape}, upper {hi.shape} and sigma {sg.shape} "
                             "must have the same length")
        if np.any(lo > hi) or np.any(np.isnan(lo)) or np.any(np.isnan(hi)):
            raise ValueError("state-space limits must satisfy lower <= upper")
        if not np.all(np.isfinite(sg)) or np.any(sg < 0):
            raise ValueError("diffusion sigma must be finite and non-negative")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)
        object.__setattr__(self, "sigma", sg)

    @classmethod
    def from_dofs(cls, dofs, fps: float = 30.0) -> "StateSpace":
        """From a ``gltrack.body.dofs.DofSet``: its limits and ``sigma_at(fps)``."""
        return cls(dofs.lower, dofs.upper, dofs.sigma_at(fps))

    @property
    def size(self) -> int:
        return self.sigma.size

    def clamp(self, x: np.ndarray) -> np.ndarray:
        """Project particles (N, D) onto the limits (a new array)."""
        return np.clip(x, self.lower, self.upper)

    def check(self, particles, name: str = "particles") -> np.ndarray:
        """Validate a (N, D) particle set (copy, float64); raises ``ValueError``."""
        x = np.array(particles, dtype=np.float64, copy=True)
        if x.ndim != 2 or x.shape[1] != self.size or x.shape[0] < 1:
            raise ValueError(f"{name} must have shape (N, {self.size}), got {np.shape(particles)}")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"{name} contains non-finite values")
        return x


def _sqrtm_psd(cov: np.ndarray) -> np.ndarray:
    """A matrix square root L with L L^T = cov for a symmetric PSD (possibly singular) cov.

    Eigen-decomposition rather than Cholesky: a particle-set covariance is often rank-deficient
    after resampling (fewer distinct particles than dimensions).
    """
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    return vecs * np.sqrt(np.clip(vals, 0.0, None))


def diffuse(particles: np.ndarray, rng: np.random.Generator, space: StateSpace, *,
            dims=None, sigma=None, cov=None) -> np.ndarray:
    """Add Gaussian noise to the ``dims`` columns of ``particles`` and clamp to the limits.

    Parameters
    ----------
    particles : (N, D) float64
    rng : numpy.random.Generator
    space : StateSpace
    dims : (K,) int, optional
        Columns to diffuse (default all); the others are copied unchanged.
    sigma : (K,) float, optional
        Per-dimension standard deviations (default ``space.sigma[dims]``).
    cov : (K, K) float, optional
        Full noise covariance; overrides ``sigma``.

    Returns
    -------
    (N, D) float64, a new array within ``[space.lower, space.upper]``.
    """
    x = np.array(particles, dtype=np.float64, copy=True)
    dims = np.arange(x.shape[1]) if dims is None else np.asarray(dims, dtype=np.int64)
    z = rng.standard_normal((x.shape[0], dims.size))
    if cov is not None:
        x[:, dims] += z @ _sqrtm_psd(np.asarray(cov, dtype=np.float64)).T
    else:
        s = space.sigma[dims] if sigma is None else np.asarray(sigma, dtype=np.float64)
        x[:, dims] += z * s
    x[:, dims] = np.clip(x[:, dims], space.lower[dims], space.upper[dims])
    return x


def layer_noise(variant: str, layer: int, weights: Weights, particles: np.ndarray,
                base_sigma: np.ndarray, *, factor: float = 0.5, scale: float = 0.5,
                floor: float = 0.02) -> dict:
    """Noise for annealing layer ``layer >= 1`` from the previous layer's weighted set.

    Parameters
    ----------
    variant : {"constant", "layer_variance", "covariance"}
    layer : int, index of the layer about to be diffused (1 = first after the prediction)
    weights : Weights of the previous layer (tempered)
    particles : (N, K) float64, the previous layer's particles restricted to the diffused dims
    base_sigma : (K,) float64, the motion-model standard deviations of those dims
    factor : float, per-layer shrink of ``"constant"``
    scale : float, multiplier of the particle-set standard deviation / covariance square root
    floor : float, minimum standard deviation as a fraction of ``base_sigma``, so a collapsed
        particle set can still move

    Returns
    -------
    dict with either ``sigma`` (K,) or ``cov`` (K, K): keyword arguments for :func:`diffuse`.
    """
    base_sigma = np.asarray(base_sigma, dtype=np.float64)
    if variant == "constant":
        return {"sigma": base_sigma * factor ** layer}
    lo = floor * base_sigma
    if variant == "layer_variance":
        sd = scale * np.sqrt(weights.var(particles))
        return {"sigma": np.maximum(sd, lo)}
    if variant == "covariance":
        return {"cov": scale ** 2 * weights.cov(particles) + np.diag(lo ** 2)}
    raise ValueError(f"unknown diffusion variant {variant!r}; choose one of {', '.join(VARIANTS)}")
