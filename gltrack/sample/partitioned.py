"""Partitioned sampling (MacCormick & Isard 2000), optionally with annealed partitions.

The state is split into ordered partitions (lists of DOF indices, e.g. torso, then each limb).
For each partition in turn only its DOFs are diffused, the particles are weighted with the
full-pose weight function and resampled ("weighted resampling") before the next partition, so
later partitions start from a set concentrated on good values of the earlier ones. With one
layer per partition this is plain PS; with more, each partition is an annealing run (Bandouch's
"annealed partitions": the bigger the partition, the more layers it needs).
"""
from __future__ import annotations

import logging

import numpy as np

from .annealed import AnnealOutput, anneal
from .base import SampleResult, finish, predict
from .diffusion import VARIANTS, StateSpace
from .resampling import get_resampler

log = logging.getLogger(__name__)


def _as_partitions(partitions) -> list[tuple[str, np.ndarray]]:
    items = partitions.items() if isinstance(partitions, dict) else \
        ((f"p{k}", p) for k, p in enumerate(partitions))
    out = [(str(name), np.asarray(p, dtype=np.int64).ravel()) for name, p in items]
    if not out or any(p.size == 0 for _, p in out):
        raise ValueError("partitions must be a non-empty sequence of non-empty index lists")
    return out


def _as_layers(layers, count: int) -> list[int]:
    ls = [int(layers)] * count if np.isscalar(layers) else [int(v) for v in layers]
    if len(ls) != count or min(ls) < 1:
        raise ValueError(f"layers must be an int >= 1 or {count} such ints, got {layers!r}")
    return ls


def run_partitions(particles, weight_fn, rng: np.random.Generator, space: StateSpace,
                   partitions, layers, *, alpha: float = 0.5, diffusion: str = "covariance",
                   resampler="systematic", stage: str = "", **anneal_kw) -> AnnealOutput:
    """Estimate ``partitions`` in order, resampling between them.

    Parameters
    ----------
    particles : (N, D) float, equally weighted input set
    weight_fn, rng, space : as for :func:`~gltrack.sample.annealed.anneal`
    partitions : dict name -> (K,) int, or sequence of (K,) int
    layers : int or sequence of int, annealing layers per partition; a partition with one
        layer weights with ``beta = 1`` (MacCormick & Isard's weighted resampling), one with
        more anneals towards survival rate ``alpha``
    stage : str, prefix of the diagnostics' stage names
    **anneal_kw : forwarded to :func:`~gltrack.sample.annealed.anneal`

    Returns
    -------
    AnnealOutput of the last partition (its weighted set, not resampled), with evaluations and
    layer diagnostics summed over all partitions.
    """
    parts = _as_partitions(partitions)
    ls = _as_layers(layers, len(parts))
    resample = get_resampler(resampler)
    x = particles
    evals, infos, out = 0, [], None
    for k, ((name, dims), nl) in enumerate(zip(parts, ls)):
        if out is not None:
            x = out.particles[resample(out.weights.W, rng, out.particles.shape[0])]
        out = anneal(x, weight_fn, rng, space, dims=dims, layers=nl,
                     alpha=alpha if nl > 1 else None, diffusion=diffusion,
                     resampler=resampler, stage=f"{stage}{name}", **anneal_kw)
        evals += out.evaluations
        infos.extend(out.layers)
    return AnnealOutput(out.particles, out.raw_lw, out.weights, evals, infos)


class PartitionedSampler:
    """Partitioned sampling over fixed ordered partitions.

    Parameters
    ----------
    space : StateSpace
    partitions : dict name -> (K,) int or sequence of (K,) int
        E.g. :func:`gltrack.sample.partitions.fine_partitions` (Bandouch's PS) or
        :func:`~gltrack.sample.partitions.default_partitions`. DOFs in no partition keep the
        values of the input particles.
    layers : int or sequence of int, default 1 (plain PS)
    alpha : float, target survival rate of annealed partitions
    diffusion : {"covariance", "layer_variance", "constant"}
    resampler : str or callable
    **anneal_kw : forwarded to :func:`~gltrack.sample.annealed.anneal` (factor, scale, floor)
    """

    def __init__(self, space: StateSpace, partitions, *, layers=1, alpha: float = 0.5,
                 diffusion: str = "covariance", resampler="systematic", **anneal_kw):
        if diffusion not in VARIANTS:
            raise ValueError(f"unknown diffusion variant {diffusion!r}; choose one of "
                             f"{', '.join(VARIANTS)}")
        self.space = space
        self.partitions = _as_partitions(partitions)
        for name, p in self.partitions:
            if p.min() < 0 or p.max() >= space.size:
                raise ValueError(f"partition {name!r} indexes outside 0..{space.size - 1}")
        self.layers = _as_layers(layers, len(self.partitions))
        self.alpha, self.diffusion, self.resampler = alpha, diffusion, resampler
        self.anneal_kw = anneal_kw

    def evaluations_per_step(self, n: int) -> int:
        return int(n) * sum(self.layers)

    def step(self, particles, weight_fn, rng: np.random.Generator,
             predict_fn=None, predict_scale: float = 0.0) -> SampleResult:
        """Advance one frame; ``particles`` (N, D) is the previous equally weighted set.

        ``predict_fn(particles (N, D), rng) -> (N, D)``, optional, moves the whole state once
        before the first partition and replaces every partition's first-layer diffusion (see
        :func:`~gltrack.sample.base.predict`).

        Returns a SampleResult with ``evaluations == N * sum(layers)``.
        """
        particles, scale = predict(particles, rng, self.space, predict_fn, predict_scale)
        kw = dict(self.anneal_kw)
        kw["first_scale"] = scale * kw.get("first_scale", 1.0)
        out = run_partitions(particles, weight_fn, rng, self.space, dict(self.partitions),
                             self.layers, alpha=self.alpha, diffusion=self.diffusion,
                             resampler=self.resampler, **kw)
        return finish(out.particles, out.weights, out.raw_lw, rng, out.particles.shape[0],
                      self.resampler, out.evaluations, out.layers)
