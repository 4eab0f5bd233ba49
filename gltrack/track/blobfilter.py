"""Particle filters with the voxel/blob/KL likelihood: methods ``condensation`` and ``apf-blobs``.

The baselines of Caillette, Galata & Howard (2008, sec. 7): the same evaluation as the
behaviour-model tracker (``vlmm``, :mod:`gltrack.observe.blob_evidence`: voxels, blob fit, KL per
particle), with a motion model that knows nothing of behaviour:

* ``condensation`` (Isard & Blake): every particle diffuses with the DOF preset's inter-frame
  Gaussian sigmas (:meth:`gltrack.body.dofs.DofSet.sigma_at` the data's frame rate, times
  ``sigma_scale``), is weighted once and resampled: :class:`gltrack.sample.AnnealedParticleFilter`
  with one layer;
* ``apf-blobs`` (Deutscher et al.): the same first diffusion, then ``layers`` annealing layers,
  each resampling and diffusing with the shrinking spread of the set (the same sampler).

Weights are ``exp(-beta * KL)`` (:func:`gltrack.sample.weights.cost_weights`): Condensation (and
``vlmm``) choose ``beta`` per frame so that the effective sample size is ``survival * N``; the
annealing layers choose it for a survival of ``alpha``. The blob evidence of a frame is fitted from the previous estimate and from the mean of
the predicted particles (these methods have no motion clusters to take prototypes from).

A frame whose best particle is worse than ``lost_threshold`` KL nats is reported
(``info["lost"]``); these baselines have no recovery (the paper's point).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from gltrack.observe.blob_evidence import (FIT_FROM, LOST_KL, SEGMENTATIONS, BlobEvidence,
                                           ColourAcquisition, placed_candidates, stage_seconds)
from gltrack.sample import AnnealedParticleFilter, StateSpace, cost_weights

from .base import FrameEstimate, NoPersonError, Tracker, rng_state, set_rng_state
from .options import Options, at_least, choice, positive, within

log = logging.getLogger(__name__)


@dataclass
class BlobEvidenceOptions(Options):
    """The likelihood's options, shared by ``vlmm``, ``condensation`` and ``apf-blobs``
    (``--config`` keys; see :class:`~gltrack.observe.blob_evidence.BlobEvidence`).

    volume : tracking volume [xmin, ymin, zmin, xmax, ymax, zmax], metres; empty = 3 m x 3 m
        around the point the cameras look at, floor to 2.5 m
    base, max_depth, tolerance : voxel reconstruction (max_depth 3 = the paper's depth 7)
    segmentation : "masks" (the dataset's foreground masks) or "colour" (chi-square test of
        pixel samples against the background frames, the paper's own)
    fit_iterations : EM iterations of the blob fit
    colour : coloured blobs (the fit weighs the voxels' colours; false: shape only)
    colour_frames : first frames over which the blobs' colours are acquired from the estimates
    fit_from : "predictions" (default: the blob fit starts from predicted poses) or
        "groundtruth" (an oracle for comparing motion models only, the paper's Fig. 12
        protocol: the fit of every frame starts from the dataset's true pose; never a
        headline figure of the tracker)
    root_align : before it is weighted, every particle's root translation moves to where its
        KL is least (closed form, :func:`~gltrack.observe.blobs.kl_translation`): the filter
        then searches the pose, not where the body is, which the fitted blobs already say
        (cmu_60_10, protocol 1: vlmm 200 77.3 -> 59.8 mm, condensation 5000 75.0 -> 55.4,
        apf 1000 x 5 29.5 -> 23.0; protocol 2: vlmm 1000 85.4 -> 70.3). Off by default (the
        paper's filters, which sample the translation like any other DOF): aligned, a set
        that is lost (bench vlmm's, turned 2.5 rad and moved 0.5 m) keeps a low KL once it
        stands on the evidence, the vlmm tracker's loss test no longer fires, and recovery
        took 69 frames instead of 3. The loss test only ever saw the shift: a set turned
        2.5 rad or pi and not moved goes unseen without alignment too (60 / 82 frames)
    """

    volume: list = field(default_factory=list)
    base: int = 16
    max_depth: int = 3
    tolerance: int = 0
    segmentation: str = "masks"
    fit_iterations: int = 4
    colour: bool = True
    colour_frames: int = 5
    fit_from: str = "predictions"
    root_align: bool = False

    def problems(self):
        bad = super().problems() + [*choice(self, "segmentation", SEGMENTATIONS),
                                    *choice(self, "fit_from", FIT_FROM),
                                    *at_least(self, 1, "base", "fit_iterations"),
                                    *at_least(self, 0, "max_depth", "tolerance", "colour_frames")]
        v = np.asarray(self.volume, dtype=np.float64)
        if len(v) and (v.shape != (6,) or np.any(v[3:] <= v[:3])):
            bad.append(f"volume = {list(self.volume)} (must be [xmin, ymin, zmin, xmax, ymax, "
                       "zmax] with max > min)")
        return bad

    def evidence(self, dataset, body) -> BlobEvidence:
        """The :class:`BlobEvidence` these options describe."""
        return BlobEvidence(dataset, body, volume=self.volume, base=self.base,
                            max_depth=self.max_depth, tolerance=self.tolerance,
                            segmentation=self.segmentation, fit_iterations=self.fit_iterations,
                            colour=self.colour, fit_from=self.fit_from)


@dataclass
class CondensationOptions(BlobEvidenceOptions):
    """Options of ``condensation`` (``--config`` keys): those of the likelihood
    (:class:`BlobEvidenceOptions`) plus

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

    def problems(self):
        return super().problems() + [*at_least(self, 2, "particles"),
                                     *within(self, "survival", 0, 1, open_lo=True, open_hi=True),
                                     *positive(self, "sigma_scale"),
                                     *choice(self, "estimate", ("best", "mean")),
                                     *at_least(self, 1, "headings")]


@dataclass
class ApfBlobsOptions(CondensationOptions):
    """Options of ``apf-blobs``: those of :class:`CondensationOptions` plus

    layers : annealing layers per frame (evaluations per frame = particles * layers)
    alpha : target survival rate of each annealing layer (Deutscher's 0.5)
    """

    layers: int = 5
    alpha: float = 0.5

    def problems(self):
        return super().problems() + [*at_least(self, 1, "layers"),
                                     *within(self, "alpha", 0, 1, open_lo=True, open_hi=True)]


class CondensationTracker(Tracker):
    """Gaussian-diffusion particle filter on the blob likelihood (see module docstring).

    The composition: :class:`~gltrack.observe.blob_evidence.BlobEvidence` (observation and
    likelihood), Gaussian diffusion (motion prior) and
    :class:`~gltrack.sample.AnnealedParticleFilter` (one layer for Condensation).
    """

    method = "condensation"
    options_class = CondensationOptions

    def __init__(self, dataset, body, ctx=None, options: CondensationOptions | None = None,
                 rng=None):
        opt = self.opt = (options or self.options_class()).validate()
        self.ds, self.body = dataset, body
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.evidence = opt.evidence(dataset, body)
        base = StateSpace.from_dofs(body.dofs, dataset.fps)
        self.space = StateSpace(base.lower, base.upper, base.sigma * opt.sigma_scale)
        layers, alpha = (opt.layers, opt.alpha) if isinstance(opt, ApfBlobsOptions) else \
            (1, opt.survival)
        self.sampler = AnnealedParticleFilter(self.space, layers=layers, alpha=alpha)
        self.P = None
        self.est = None

    # -- initialisation -----------------------------------------------------------------------
    #: KL nats are no share of the person: only the absolute ``lost_threshold`` applies
    relative_loss = False

    def lost_threshold(self):
        return self.opt.lost_threshold  # best-particle KL, nats

    def start_hypotheses(self, frame):
        return [self.auto_init(frame)]

    def auto_init(self, frame):
        """A standing pose at ``headings`` headings on the voxels' centroid; best KL wins."""
        ev = self.evidence
        ev.set_frame(frame)
        if ev.empty:
            raise NoPersonError(f"frame {frame}: no voxels reconstructed inside the tracking "
                                f"volume {ev.volume.round(2).tolist()}: no person to start from")
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

    def transform_state(self, fn):
        if self.P is None:
            raise RuntimeError("start() the tracker first")
        self.P = self.body.dofs.validate(fn(self.P))

    def get_state(self):
        """Particles, estimate, blob colours and the generator."""
        if self.P is None:
            return None
        return {"P": self.P.copy(), "est": np.array(self.est, dtype=np.float64),
                "colours": self.colours.get_state(), "rng": rng_state(self.rng)}

    def set_state(self, state):
        self.P = np.array(state["P"], dtype=np.float64)
        self.est = np.array(state["est"], dtype=np.float64)
        self.colours = ColourAcquisition.from_state(self.evidence, state["colours"])
        set_rng_state(self.rng, state["rng"])

    # -- tracking -----------------------------------------------------------------------------
    def step(self, frame):
        if self.P is None:
            raise RuntimeError("start() the tracker first")
        t0 = time.perf_counter()
        ev = self.evidence
        ev.set_frame(frame)
        if ev.empty:
            # nothing to weigh against: keep the particles, report the frame
            return FrameEstimate(self.est.copy(), float("nan"), 0,
                                 {"empty": True, "stage_seconds": stage_seconds(
                                     ev, time.perf_counter() - t0)})
        # the diffusion is zero-mean, so the set's mean is the mean prediction
        ev.fit(np.stack([self.est, self.P.mean(axis=0)]))
        res = self.sampler.step(
            self.P, lambda x: cost_weights(ev.costs(x, align_root=self.opt.root_align)),
            self.rng)
        est = res.best if self.opt.estimate == "best" else res.estimate
        score = float(ev.costs(est[None])[0])
        self.est = est
        self.colours.update(frame, est)
        self.P = res.particles
        info = {"fit_loglik": ev.fit_loglik, "lost": score > self.opt.lost_threshold,
                "quality": score,
                "stage_seconds": stage_seconds(ev, time.perf_counter() - t0)}
        return FrameEstimate(est, score, res.evaluations + 1, info)


class ApfBlobsTracker(CondensationTracker):
    """Annealed particle filter on the blob likelihood (see module docstring)."""

    method = "apf-blobs"
    options_class = ApfBlobsOptions
