"""Annealed particle filtering (Deutscher, Blake & Reid 2000; Deutscher & Reid 2005).

M layers per frame. Layer m weights the particles with ``w ** beta_m``; ``beta_m`` is chosen so
that the survival rate ``ESS / N`` hits a target ``alpha`` (0.5 by default), which blurs the
weight function in early layers so particles can leave local maxima, and sharpens it as the set
concentrates. Between layers the set is resampled and diffused with shrinking noise (see
:mod:`gltrack.sample.diffusion` for the three variants).

:func:`anneal` is the layer loop on a subset of dimensions; partitioned and hierarchical
sampling reuse it for each partition.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .base import LayerInfo, SampleResult, evaluate, finish, predict
from .diffusion import VARIANTS, StateSpace, diffuse, layer_noise
from .resampling import get_resampler
from .weights import Weights, annealing_exponent

log = logging.getLogger(__name__)


@dataclass
class AnnealOutput:
    """Final weighted set of :func:`anneal`.

    Attributes
    ----------
    particles : (N, D) float64, the last layer's particles (not resampled)
    raw_lw : (N,) float64, their untempered log-weights
    weights : Weights, tempered with the last layer's exponent
    evaluations : int
    layers : list of LayerInfo
    """

    particles: np.ndarray
    raw_lw: np.ndarray
    weights: Weights
    evaluations: int
    layers: list


def anneal(particles, weight_fn, rng: np.random.Generator, space: StateSpace, *, dims=None,
           layers: int = 5, alpha: float | None = 0.5, diffusion: str = "covariance",
           factor: float = 0.5, scale: float = 0.5, floor: float = 0.02,
           first_sigma=None, min_spread: float | None = None, resampler="systematic",
           stage: str = "anneal", first_scale: float = 1.0, coarse_fn=None,
           fine_layers: int = 1) -> AnnealOutput:
    """Run annealing layers that diffuse only ``dims``.

    Layer 0 diffuses with the motion-model noise (``first_sigma``, default ``space.sigma``);
    each later layer resamples the previous weighted set and diffuses with
    :func:`~gltrack.sample.diffusion.layer_noise`.

    Parameters
    ----------
    particles : (N, D) float, equally weighted input set
    weight_fn : callable, (N, D) -> (N,) non-negative, larger = better (or a ``Weights``)
    rng : numpy.random.Generator
    space : StateSpace
    dims : (K,) int, optional, the dimensions this stage estimates (default all)
    layers : int >= 1, maximum number of layers (= weight_fn calls)
    alpha : float in (0, 1) or None
        Target survival rate per layer; ``None`` weights with ``beta = 1`` (plain SIR).
    diffusion : {"constant", "layer_variance", "covariance"}
    factor, scale, floor : see :func:`~gltrack.sample.diffusion.layer_noise`
    first_sigma : (K,) float, optional, layer-0 standard deviations
    first_scale : float, multiplier of the default layer-0 noise ``space.sigma[dims]`` (ignored
        with ``first_sigma``); 0 when a separate motion model already predicted the particles
    min_spread : float, optional
        Stop early once the weighted standard deviation of every dim in ``dims`` is below
        ``min_spread * space.sigma[dims]`` (Bandouch's variance threshold).
    resampler : str or callable
    stage : str, label for the diagnostics
    coarse_fn : callable like ``weight_fn``, optional, a cheaper approximation of it (e.g. a
        coarser mesh) that weights the layers before the last ``fine_layers``; those, and so
        the returned weights, are ``weight_fn``'s. Early layers are flattened by small
        exponents and only have to move the set towards the mode; the last ones place it.
        (With ``min_spread`` a run that stops early may end on a coarse layer.)
    fine_layers : int >= 1, the last layers weighted with ``weight_fn`` when ``coarse_fn`` is
        given

    Returns
    -------
    AnnealOutput
    """
    if diffusion not in VARIANTS:
        raise ValueError(f"unknown diffusion variant {diffusion!r}; choose one of "
                         f"{', '.join(VARIANTS)}")
    if int(layers) < 1:
        raise ValueError(f"layers must be >= 1, got {layers}")
    if int(fine_layers) < 1:
        raise ValueError(f"fine_layers must be >= 1, got {fine_layers}")
    n_coarse = int(layers) - int(fine_layers) if coarse_fn is not None else 0
    resample = get_resampler(resampler)
    x = space.check(particles)
    n = x.shape[0]
    dims = np.arange(x.shape[1]) if dims is None else np.asarray(dims, dtype=np.int64)
    base = space.sigma[dims]
    infos, evals = [], 0
    w = lw = None
    for m in range(int(layers)):
        if m == 0:
            x = diffuse(x, rng, space, dims=dims,
                        sigma=first_scale * base if first_sigma is None else first_sigma)
        else:
            noise = layer_noise(diffusion, m, w, x[:, dims], base,
                                factor=factor, scale=scale, floor=floor)
            x = diffuse(x[resample(w.W, rng, n)], rng, space, dims=dims, **noise)
        lw = evaluate(coarse_fn if m < n_coarse else weight_fn, x)
        evals += n
        raw = Weights(lw)
        beta = 1.0 if alpha is None else annealing_exponent(lw, alpha)
        w = raw if beta == 1.0 else raw.tempered(beta)
        infos.append(LayerInfo(stage, m, n, dims.size, beta, w.ess, w.survival))
        log.debug("%s layer %d: beta %.4g, survival %.3f", stage, m, beta, w.survival)
        if min_spread is not None and m + 1 < layers:
            spread = np.sqrt(w.var(x[:, dims]))
            if np.all(spread < min_spread * base):
                log.debug("%s: spread below threshold after %d layers", stage, m + 1)
                break
    return AnnealOutput(x, lw, w, evals, infos)


class AnnealedParticleFilter:
    """Deutscher's APF over all dimensions at once.

    Parameters
    ----------
    space : StateSpace
    layers : int, annealing layers per frame (Bandouch compares 10 layers of 800 particles)
    alpha : float, target survival rate per layer
    diffusion : {"covariance", "layer_variance", "constant"}, default ``"covariance"``
    factor, scale, floor : see :func:`~gltrack.sample.diffusion.layer_noise`
    resampler : str or callable
    fine_layers : int >= 1, with a ``coarse_fn`` given to :meth:`step`, the last layers of a
        frame weighted with ``weight_fn``; the ones before them use ``coarse_fn`` (see
        :func:`anneal`)
    """

    def __init__(self, space: StateSpace, *, layers: int = 10, alpha: float = 0.5,
                 diffusion: str = "covariance", factor: float = 0.5, scale: float = 0.5,
                 floor: float = 0.02, resampler="systematic", fine_layers: int = 1):
        if diffusion not in VARIANTS:
            raise ValueError(f"unknown diffusion variant {diffusion!r}; choose one of "
                             f"{', '.join(VARIANTS)}")
        self.space, self.layers, self.alpha = space, int(layers), alpha
        self.diffusion, self.factor, self.scale, self.floor = diffusion, factor, scale, floor
        self.resampler = resampler
        if int(fine_layers) < 1:
            raise ValueError(f"fine_layers must be >= 1 (the last layer weights with the full "
                             f"function), got {fine_layers}")
        self.fine_layers = int(fine_layers)

    def evaluations_per_step(self, n: int) -> int:
        return int(n) * self.layers

    def step(self, particles, weight_fn, rng: np.random.Generator,
             predict_fn=None, predict_scale: float = 0.0, coarse_fn=None) -> SampleResult:
        """Advance one frame; ``particles`` (N, D) is the previous equally weighted set.

        ``predict_fn(particles (N, D), rng) -> (N, D)``, optional, replaces the first layer's
        Gaussian diffusion as the motion model
        (see :func:`~gltrack.sample.base.predict`, also for ``predict_scale``).
        ``coarse_fn``, optional, weights the layers before the last :attr:`fine_layers`
        instead of ``weight_fn``.

        Returns a SampleResult with ``evaluations == N * layers``.
        """
        particles, scale = predict(particles, rng, self.space, predict_fn, predict_scale)
        out = anneal(particles, weight_fn, rng, self.space, layers=self.layers, first_scale=scale,
                     alpha=self.alpha, diffusion=self.diffusion, factor=self.factor,
                     scale=self.scale, floor=self.floor, resampler=self.resampler, stage="apf",
                     coarse_fn=coarse_fn, fine_layers=self.fine_layers)
        return finish(out.particles, out.weights, out.raw_lw, rng, out.particles.shape[0],
                      self.resampler, out.evaluations, out.layers)
