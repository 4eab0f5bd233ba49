"""Sampling and optimisation over pose space: pure numpy, no GL.

Samplers call ``weight_fn(particles (N, D)) -> (N,)`` (non-negative, larger = better) and the
hill climber calls ``cost_fn(candidates (M, D)) -> (M,)`` (lower = better); a tracker builds
these from GPU scores. Every stochastic function takes a ``numpy.random.Generator``.
The particle samplers' ``step(particles, weight_fn, rng, predict_fn=None)`` accept a motion model
``predict_fn(particles, rng) -> particles`` that replaces their default Gaussian diffusion.
"""
from .annealed import AnnealedParticleFilter, AnnealOutput, anneal
from .base import LayerInfo, SampleResult, predict
from .diffusion import StateSpace, diffuse, layer_noise
from .hierarchical import HierarchicalSampler, Pipeline, default_pipelines
from .hillclimb import HillClimbResult, hill_climb
from .partitioned import PartitionedSampler, run_partitions
from .partitions import default_partitions, fine_partitions, hill_climb_order
from .resampling import (RESAMPLERS, get_resampler, multinomial_resample, residual_resample,
                         stratified_resample, systematic_resample)
from .sir import SIRFilter
from .weights import (Weights, annealing_exponent, bandouch_weights, cost_weights, ess,
                      minmax_norm)

__all__ = [
    "AnnealedParticleFilter", "AnnealOutput", "anneal", "LayerInfo", "SampleResult", "predict",
    "StateSpace", "diffuse", "layer_noise", "HierarchicalSampler", "Pipeline",
    "default_pipelines", "HillClimbResult", "hill_climb", "PartitionedSampler",
    "run_partitions", "default_partitions", "fine_partitions", "hill_climb_order", "RESAMPLERS",
    "get_resampler", "multinomial_resample", "residual_resample", "stratified_resample",
    "systematic_resample", "SIRFilter", "Weights", "annealing_exponent", "bandouch_weights",
    "cost_weights", "ess", "minmax_norm",
]
