"""Types and helpers shared by the samplers: weight evaluation, per-layer diagnostics, results.

A sampler never knows how particles are scored: it calls ``weight_fn(particles (N, D)) -> (N,)``
with non-negative weights, larger = better (a tracker builds it from GPU scores, e.g. with
:func:`gltrack.sample.weights.bandouch_weights`). Weights may be *relative to the batch* (min-max
normalised), so a sampler only ever compares weights that came back from the same call.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from .resampling import get_resampler
from .weights import Weights, log_weights

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LayerInfo:
    """Diagnostics of one weighting step.

    Attributes
    ----------
    stage : str, e.g. ``"torso"``, ``"l_arm"``, ``"pipeline1/l_arm"``, ``"sir"``
    layer : int, annealing layer within the stage (0 = first)
    n : int, particles weighted (= weight evaluations of this step)
    n_dims : int, dimensions diffused before this weighting
    beta : float, exponent applied to the weights (1 = untempered)
    ess : float, effective sample size after tempering
    survival : float, ``ess / n``
    """

    stage: str
    layer: int
    n: int
    n_dims: int
    beta: float
    ess: float
    survival: float


@dataclass
class SampleResult:
    """What one sampler step returns.

    Attributes
    ----------
    estimate : (D,) float64, weighted mean of the final weighted particle set
    best : (D,) float64, the particle of highest weight in the final set
    particles : (N, D) float64, the final set resampled to equal weights (next frame's prior)
    final_particles : (M, D) float64, the final weighted set before resampling
    weights : Weights of ``final_particles`` (tempered as used for the estimate)
    evaluations : int, particles passed to ``weight_fn`` in this step
    layers : list of LayerInfo, one per call of ``weight_fn`` in order
    info : dict, sampler-specific extras (e.g. the final weight share of each HPS pipeline)
    ancestors : (N,) int64, row of ``final_particles`` each row of ``particles`` was drawn from
        (a motion model with per-particle state, e.g. the VLMM prior, follows it)
    """

    estimate: np.ndarray
    best: np.ndarray
    particles: np.ndarray
    final_particles: np.ndarray
    weights: Weights
    evaluations: int
    layers: list = field(default_factory=list)
    info: dict = field(default_factory=dict)
    ancestors: np.ndarray | None = None


def predict(particles, rng: np.random.Generator, space, predict_fn=None,
            predict_scale: float = 0.0):
    """Apply an optional motion model before a sampler's first weighting.

    Parameters
    ----------
    particles : (N, D) float, the previous frame's equally weighted set
    rng : numpy.random.Generator
    space : StateSpace, validates the input and the prediction
    predict_fn : callable ``(particles (N, D), rng) -> (N, D)`` or None
        A learnt motion model (e.g. ``gltrack.motion.vlmm_prior.VlmmPrior.predict``). None keeps the
        default motion model, the Gaussian diffusion of each stage's first layer.
    predict_scale : float >= 0, the first layers' diffusion (in units of the motion-model
        sigmas) that remains after a prediction: 0 trusts the prediction's own noise; a learnt
        model's noise is often too narrow for the later annealing layers, which diffuse with
        the spread of the set, to explore

    Returns
    -------
    particles : (N, D) float64, predicted and clamped to the limits (validated copy without
        ``predict_fn``)
    first_scale : float, multiplier of the first layers' diffusion: 1 without ``predict_fn``,
        ``predict_scale`` with it (the prediction already is the motion step)
    """
    x = space.check(particles)
    if predict_fn is None:
        return x, 1.0
    if not predict_scale >= 0:
        raise ValueError(f"predict_scale must be >= 0, got {predict_scale}")
    y = space.check(predict_fn(x, rng), "predicted particles")
    if y.shape != x.shape:
        raise ValueError(f"predict_fn must return shape {x.shape}, got {y.shape}")
    return space.clamp(y), float(predict_scale)


def evaluate(weight_fn, x: np.ndarray) -> np.ndarray:
    """Call ``weight_fn`` on (N, D) particles and return validated (N,) log-weights.

    ``weight_fn`` returns raw non-negative weights (N,) or a :class:`Weights` (log-weights, e.g.
    from :func:`~gltrack.sample.weights.cost_weights`), which cannot underflow.
    """
    w = weight_fn(x)
    lw = w.lw if isinstance(w, Weights) else log_weights(np.asarray(w, dtype=np.float64))
    if lw.shape != (x.shape[0],):
        raise ValueError(f"weight_fn must return shape ({x.shape[0]},), got {lw.shape}")
    return lw


def finish(x: np.ndarray, weights: Weights, raw_lw: np.ndarray, rng: np.random.Generator,
           n_out: int, resampler, evaluations: int, layers: list) -> SampleResult:
    """Build a :class:`SampleResult` from the final weighted set (resampling to ``n_out``)."""
    idx = np.asarray(get_resampler(resampler)(weights.W, rng, n_out), dtype=np.int64)
    return SampleResult(estimate=weights.mean(x), best=x[int(np.argmax(raw_lw))].copy(),
                        particles=x[idx].copy(), final_particles=x, weights=weights,
                        evaluations=int(evaluations), layers=list(layers), ancestors=idx)
