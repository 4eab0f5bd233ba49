"""Particle filters with the voxel/blob/KL likelihood: methods ``condensation`` and ``apf-blobs``.

The baselines of Caillette, Galata & Howard (2008, sec. 7): the same evaluation as the
behaviour-model tracker (``vlmm``, :mod:`gltrack.track.blob_evidence`: voxels, blob fit, KL per
particle), with a motion model that knows nothing of behaviour:

* ``condensation`` (Isard & Blake): every particle diffuses with the DOF preset's inter-frame
  Gaussian sigmas (:meth:`gltrack.body.dofs.DofSet.sigma_at` the data's frame rate, times
  ``sigma_scale``), is weighted once and resampled;
* ``apf-blobs`` (Deutscher et al.): the same first diffusion, then ``layers`` annealing layers,
  each resampling and diffusing with the shrinking spread of the set
  (:func:`gltrack.sample.annealed.anneal`).

Weights are ``exp(-beta * KL)``: Condensation (and ``vlmm``) choose ``beta`` per frame so that the
effective sample size is ``survival * N``; the annealing layers choose it for a survival of
``alpha``. The blob evidence of a frame is fitted from the previous estimate and from the mean of
the predicted particles (these methods have no motion clusters to take prototypes from).

A frame whose best particle is worse than ``lost_threshold`` KL nats is reported
(``info["lost"]``); these baselines have no recovery (the paper's point). ``perturb_frame``
injects a failure for the recovery benchmark: the whole particle set is turned by
``perturb_rad`` about the vertical and moved by ``perturb_shift`` metres along x.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from gltrack.sample.annealed import anneal
from gltrack.sample.diffusion import StateSpace
from gltrack.sample.resampling import systematic_resample

from .base import FrameEstimate, Tracker
from .blob_evidence import (BlobEvidenceOptions, ColourAcquisition, placed_candidates,
                            stage_seconds)
from .runner import register

log = logging.getLogger(__name__)

#: a best-particle KL above this (nats) flags a lost frame by default
LOST_KL = 25.0


def kl_weights(cost) -> np.ndarray:
    """Monotone, underflow-free raw weights of (N,) KL costs for a sampler that tempers them.

    ``exp(-(c - c_min) / s)`` with ``s`` a fiftieth of the cost range: every weight stays above
    ``exp(-50)``, so the sampler's exponent search (``annealing_exponent``) sees all particles.
    """
    c = np.asarray(cost, dtype=np.float64)
    spread = float(np.ptp(c))
    if not spread > 0:
        return np.ones_like(c)
    return np.exp(-(c - c.min()) * (50.0 / spread))


def inject_failure(particles, dofs, rad: float, shift: float) -> np.ndarray:
    """(N, D) particles turned by ``rad`` about the vertical and moved ``shift`` m along x."""
    P = np.array(particles, dtype=np.float64)
    P[:, dofs.index("pelvis_ry")] += rad
    P[:, 0] += shift
    return dofs.validate(P)


@dataclass
class CondensationOptions(BlobEvidenceOptions):
    """Options of ``condensation`` (``--config`` keys): those of the likelihood
    (:class:`~gltrack.track.blob_evidence.BlobEvidenceOptions`) plus

    particles : particles per frame (= KL evaluations per frame)
    sigma_scale : multiplier of the DOF preset's inter-frame sigmas (the diffusion)
    survival : target effective sample size / N that sets the weight exponent
    estimate : weighted "mean" (default: steadier under a noisy likelihood; salsa, condensation
        1000: 47 mm against 80 mm) or "best" particle (the paper's maximum of the posterior)
    headings : headings tried by ``--init auto``
    lost_threshold : best-particle KL (nats) above which a frame is reported lost
    """

    particles: int = 1000
    sigma_scale: float = 1.0
    survival: float = 0.3
    estimate: str = "mean"
    headings: int = 12
    lost_threshold: float = LOST_KL

    def check(self, method):
        bad = []
        if self.particles < 2:
            bad.append(f"particles = {self.particles} (at least 2)")
        if not 0 < self.survival < 1:
            bad.append(f"survival = {self.survival} (in (0, 1))")
        if not self.sigma_scale > 0:
            bad.append(f"sigma_scale = {self.sigma_scale} (> 0)")
        if self.estimate not in ("best", "mean"):
            bad.append(f"estimate = {self.estimate!r} (best or mean)")
        if bad:
            raise ValueError(f"options for {method}: " + "; ".join(bad))


@dataclass
class ApfBlobsOptions(CondensationOptions):
    """Options of ``apf-blobs``: those of :class:`CondensationOptions` plus

    layers : annealing layers per frame (evaluations per frame = particles * layers)
    alpha : target survival rate of each annealing layer (Deutscher's 0.5)
    """

    layers: int = 5
    alpha: float = 0.5

    def check(self, method):
        super().check(method)
        if self.layers < 1:
            raise ValueError(f"options for {method}: layers = {self.layers} (at least 1)")
        if not 0 < self.alpha < 1:
            raise ValueError(f"options for {method}: alpha = {self.alpha} (in (0, 1))")


class CondensationTracker(Tracker):
    """Gaussian-diffusion particle filter on the blob likelihood (see module docstring)."""

    method = "condensation"

    def __init__(self, dataset, body, ctx=None, options: CondensationOptions | None = None,
                 rng=None):
        opt = self.opt = options or self._default_options()
        opt.check(self.method)
        self.ds, self.body = dataset, body
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.evidence = opt.evidence(dataset, body)
        self.space = StateSpace.from_dofs(body.dofs, dataset.fps)
        self.first_sigma = self.space.sigma * opt.sigma_scale
        self.P = None
        self.est = None

    def _default_options(self):
        return CondensationOptions()

    @property
    def layers(self) -> int:
        return 1

    @property
    def alpha(self) -> float:
        return self.opt.survival

    # -- initialisation -----------------------------------------------------------------------
    def auto_init(self, frame):
        """A standing pose at ``headings`` headings on the voxels' centroid; best KL wins."""
        ev = self.evidence
        ev.set_frame(frame)
        P = placed_candidates(ev, self.body, self.body.dofs.zero(self.body.skeleton)[None],
                              self.opt.headings)
        ev.fit(P[ev.rank(P, 3)])
        c = ev.costs(P)
        log.info("auto init: best of %d headings, KL %.3g", len(P), c.min())
        return P[int(np.argmin(c))]

    def start(self, frame, params, velocity=None):
        p = self.body.dofs.validate(params)[0]
        self.P = np.repeat(p[None], self.opt.particles, axis=0)
        self.est = p
        self.colours = ColourAcquisition(self.evidence, frame, p, self.opt.colour_frames)

    # -- tracking -----------------------------------------------------------------------------
    def step(self, frame):
        if self.P is None:
            raise RuntimeError("start() the tracker first")
        t0 = time.perf_counter()
        ev = self.evidence
        ev.set_frame(frame)
        if frame == self.opt.perturb_frame:
            self.P = inject_failure(self.P, self.body.dofs, self.opt.perturb_rad,
                                    self.opt.perturb_shift)
            log.info("frame %d: failure injected", frame)
        if ev.empty:
            # nothing to weigh against: keep the particles, report the frame
            return FrameEstimate(self.est.copy(), float("nan"), 0,
                                 {"empty": True, "stage_seconds": stage_seconds(
                                     ev, time.perf_counter() - t0)})
        # the diffusion is zero-mean, so the set's mean is the mean prediction
        ev.fit(np.stack([self.est, self.P.mean(axis=0)]))
        out = anneal(self.P, lambda x: kl_weights(ev.costs(x)), self.rng, self.space,
                     layers=self.layers, alpha=self.alpha, first_sigma=self.first_sigma,
                     stage=self.method)
        x, w = out.particles, out.weights
        best = int(np.argmax(out.raw_lw))
        est = x[best].copy() if self.opt.estimate == "best" else w.mean(x)
        score = float(ev.costs(est[None])[0])
        self.est = est
        self.colours.update(frame, est)
        self.P = x[systematic_resample(w.W, self.rng, self.opt.particles)]
        info = {"fit_loglik": ev.fit_loglik, "lost": score > self.opt.lost_threshold,
                "stage_seconds": stage_seconds(ev, time.perf_counter() - t0)}
        return FrameEstimate(est, score, out.evaluations + 1, info)


class ApfBlobsTracker(CondensationTracker):
    """Annealed particle filter on the blob likelihood (see module docstring)."""

    method = "apf-blobs"

    def _default_options(self):
        return ApfBlobsOptions()

    @property
    def layers(self) -> int:
        return self.opt.layers

    @property
    def alpha(self) -> float:
        return self.opt.alpha


register("condensation", "multiview", "gltrack.track.blobfilter:CondensationTracker",
         "gltrack.track.blobfilter:CondensationOptions")
register("apf-blobs", "multiview", "gltrack.track.blobfilter:ApfBlobsTracker",
         "gltrack.track.blobfilter:ApfBlobsOptions")
