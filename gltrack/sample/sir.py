"""Sampling importance resampling (Condensation, Isard & Blake): predict, weight, resample."""
from __future__ import annotations

import logging

import numpy as np

from .base import LayerInfo, SampleResult, evaluate, finish, predict
from .diffusion import StateSpace, diffuse
from .weights import Weights, annealing_exponent

log = logging.getLogger(__name__)


class SIRFilter:
    """One-layer particle filter with Bandouch's motion model (last state + Gaussian noise).

    Parameters
    ----------
    space : StateSpace
        Limits and per-DOF diffusion standard deviations (``StateSpace.from_dofs(dofs, fps)``).
    resampler : str or callable, default ``"systematic"``
    alpha : float in (0, 1) or None
        Target survival rate ``ESS / N``: the weights are tempered (``w ** beta``) to reach it,
        for likelihoods whose scale is arbitrary (a KL divergence, a pixel count); ``None``
        (default) weights with ``beta = 1``, the textbook filter.
    """

    def __init__(self, space: StateSpace, *, resampler="systematic", alpha: float | None = None):
        if alpha is not None and not 0 < alpha < 1:
            raise ValueError(f"target survival rate alpha must be in (0, 1), got {alpha}")
        self.space = space
        self.resampler = resampler
        self.alpha = alpha

    def evaluations_per_step(self, n: int) -> int:
        return int(n)

    def step(self, particles, weight_fn, rng: np.random.Generator,
             predict_fn=None, predict_scale: float = 0.0) -> SampleResult:
        """Advance one frame.

        Parameters
        ----------
        particles : (N, D) float, previous frame's equally weighted set (a single start pose
            repeated N times is fine)
        weight_fn : callable, (N, D) -> (N,) non-negative weights, larger = better, or a
            :class:`~gltrack.sample.weights.Weights` of log-weights
        rng : numpy.random.Generator
        predict_fn : callable ``(particles (N, D), rng) -> (N, D)``, optional
            Motion model replacing the Gaussian diffusion (e.g. a learnt behaviour prior).
        predict_scale : float, Gaussian diffusion (in sigmas) still added after ``predict_fn``

        Returns
        -------
        SampleResult with ``evaluations == N``.
        """
        if predict_fn is None:
            x = diffuse(self.space.check(particles), rng, self.space)
        else:
            x, scale = predict(particles, rng, self.space, predict_fn, predict_scale)
            if scale > 0:
                x = diffuse(x, rng, self.space, sigma=scale * self.space.sigma)
        lw = evaluate(weight_fn, x)
        beta = 1.0 if self.alpha is None else annealing_exponent(lw, self.alpha)
        w = Weights(lw) if beta == 1.0 else Weights(lw).tempered(beta)
        info = LayerInfo("sir", 0, x.shape[0], x.shape[1], beta, w.ess, w.survival)
        return finish(x, w, lw, rng, x.shape[0], self.resampler, x.shape[0], [info])
