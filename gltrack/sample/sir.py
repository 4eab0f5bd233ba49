"""Sampling importance resampling (Condensation, Isard & Blake): predict, weight, resample."""
from __future__ import annotations

import logging

import numpy as np

from .base import LayerInfo, SampleResult, evaluate, finish, predict
from .diffusion import StateSpace, diffuse
from .weights import Weights

log = logging.getLogger(__name__)


class SIRFilter:
    """One-layer particle filter with Bandouch's motion model (last state + Gaussian noise).

    Parameters
    ----------
    space : StateSpace
        Limits and per-DOF diffusion standard deviations (``StateSpace.from_dofs(dofs, fps)``).
    resampler : str or callable, default ``"systematic"``
    """

    def __init__(self, space: StateSpace, *, resampler="systematic"):
        self.space = space
        self.resampler = resampler

    def evaluations_per_step(self, n: int) -> int:
        return int(n)

    def step(self, particles, weight_fn, rng: np.random.Generator,
             predict_fn=None, predict_scale: float = 0.0) -> SampleResult:
        """Advance one frame.

        Parameters
        ----------
        particles : (N, D) float, previous frame's equally weighted set (a single start pose
            repeated N times is fine)
        weight_fn : callable, (N, D) -> (N,) non-negative weights, larger = better
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
        w = Weights(lw)
        info = LayerInfo("sir", 0, x.shape[0], x.shape[1], 1.0, w.ess, w.survival)
        return finish(x, w, lw, rng, x.shape[0], self.resampler, x.shape[0], [info])
