"""Single depth-camera tracker (Ganapathi et al. 2010): model-based coarse-to-fine hill climbing.

State and motion model: pose ``x_t`` and discrete velocity ``v_t = x_t - x_{t-1}`` with
``v_t ~ N(d * v_{t-1}, Sigma)``; ``Sigma`` is diagonal with the per-DOF inter-frame standard
deviations of :mod:`gltrack.body.dofs` at the dataset's frame rate (``d``, the velocity damping,
keeps a noisy estimate from running away; 1 would be the paper's pure constant velocity).

Objective per frame (lower is better): the engine's depth cost summed over pixels (the negative
log-likelihood of the smoothstep sensor model, pixel-wise or smoothed) plus the negative log of
the velocity prior, ``0.5 * prior_weight * sum(((x - x_pred) / sigma)^2)``.

Search: :func:`gltrack.sample.hillclimb.hill_climb` from the predicted pose, root of the chain
first, then the limbs (the i-th DOF of all four limbs in one GPU batch), each DOF on a grid of
``grid`` values over +-``search_sigmas`` sigmas, refined ``levels`` times.

Evidence propagation (``method="hc+ep"`` / ``"ep"``) is added by :mod:`gltrack.track.ep` when
available.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from gltrack.observe.depth import foreground_points, remove_background
from gltrack.render.engine import DepthCostParams, ScoringEngine
from gltrack.sample.hillclimb import hill_climb
from gltrack.sample.partitions import hill_climb_order

from .base import FrameEstimate, Tracker

log = logging.getLogger(__name__)


@dataclass
class DepthOptions:
    """Options of the depth tracker (``--config`` keys). Defaults are general, not per clip.

    tile : tile side in pixels (the observation is resampled to it); 64 or 128
    smooth : Ganapathi's smoothed likelihood (best 3x3 neighbour + penalty) instead of pixel-wise
    scale : smoothstep saturation distance, metres
    penalty : neighbour penalty of the smoothed likelihood
    levels, grid, shrink, passes : hill-climbing schedule (see ``hill_climb``)
    search_sigmas : half-width of the coarsest grid in inter-frame sigmas
    prior_weight : weight of the velocity prior relative to the depth cost
    velocity_damping : d in v_pred = d * v_prev
    batch_limbs : search corresponding DOFs of the four limbs in one batch
    bg_tolerance : metres; background-removal margin when an empty-scene frame exists
    """

    tile: int = 64
    smooth: bool = True
    scale: float = 0.15
    penalty: float = 0.02
    levels: int = 3
    grid: int = 5
    shrink: float = 0.4
    passes: int = 1
    search_sigmas: float = 2.0
    prior_weight: float = 1.0
    velocity_damping: float = 0.5
    batch_limbs: bool = True
    bg_tolerance: float = 0.08


class DepthObservation:
    """Reads, undistorts and background-subtracts the depth frames of a dataset's depth camera."""

    def __init__(self, dataset, options: DepthOptions):
        cams = [i for i, c in enumerate(dataset.cameras) if c.kind == "depth"]
        if not cams:
            raise ValueError(f"{dataset.path}: the depth tracker needs a depth camera")
        self.dataset, self.index = dataset, cams[0]
        self.camera = dataset.cameras[self.index]
        self.pinhole = self.camera.undistorted()
        self.distorted = bool(np.any(self.camera.dist != 0))
        bg = dataset.background(self.index)
        self.background = self._undistort(bg) if bg is not None else None
        self.tolerance = options.bg_tolerance
        if self.background is None:
            log.warning("%s: no empty-scene depth frame; only far pixels are removed", dataset.path)

    def _undistort(self, z):
        import cv2

        return self.camera.undistort_image(z, cv2.INTER_NEAREST) if self.distorted else z

    def __call__(self, frame: int) -> np.ndarray:
        z = self._undistort(self.dataset.depth(frame, self.index))
        return remove_background(z, self.background, tolerance=self.tolerance)


class HillClimbDepthTracker(Tracker):
    """Ganapathi's model-based hill climbing on the GPU depth likelihood."""

    method = "hc"

    def __init__(self, dataset, body, ctx, options: DepthOptions | None = None, rng=None):
        self.opt = options or DepthOptions()
        self.body = body
        self.obs = DepthObservation(dataset, self.opt)
        params = DepthCostParams(scale=self.opt.scale, penalty=self.opt.penalty, smooth=self.opt.smooth)
        self.engine = ScoringEngine(ctx, body.mesh, body.skeleton.n_joints, [self.obs.pinhole],
                                    tile=self.opt.tile, depth_params=params)
        self.sigma = body.dofs.sigma_at(dataset.fps)
        self.order = hill_climb_order(body.dofs, group_limbs=self.opt.batch_limbs)
        self.x = None
        self.v = None
        self.rng = rng

    # -- objective ------------------------------------------------------------------------
    def depth_cost(self, X: np.ndarray) -> np.ndarray:
        """(N,) summed depth cost of N poses against the current observation."""
        return self.engine.score(self.body.skinning(X), ["depth"])[:, 0, 0]

    def objective(self, x_pred):
        w = 0.5 * self.opt.prior_weight

        def cost(X):
            X = np.atleast_2d(X)
            prior = w * np.sum(((X - x_pred) / self.sigma) ** 2, axis=1)
            return self.depth_cost(X) + prior

        return cost

    def refine(self, x_start, x_pred, steps=None):
        """Hill-climb from ``x_start`` under the prior centred on ``x_pred``."""
        d = self.body.dofs
        return hill_climb(self.objective(x_pred), x_start, self.order,
                          self.opt.search_sigmas * self.sigma if steps is None else steps,
                          levels=self.opt.levels, grid=self.opt.grid, shrink=self.opt.shrink,
                          batch_independent=self.opt.batch_limbs, lower=d.lower, upper=d.upper,
                          passes=self.opt.passes)

    # -- tracking -------------------------------------------------------------------------
    def start(self, frame, params, velocity=None):
        self.x = self.body.dofs.validate(params)[0]
        self.v = np.zeros_like(self.x) if velocity is None else np.asarray(velocity, float).copy()

    def observe(self, frame):
        z = self.obs(frame)
        self.engine.set_depth(0, z)
        return z

    def predict(self):
        return self.body.dofs.validate(self.x + self.opt.velocity_damping * self.v)[0]

    def step(self, frame):
        if self.x is None:
            raise RuntimeError("start() the tracker first")
        self.observe(frame)
        x_pred = self.predict()
        res = self.refine(x_pred, x_pred)
        self._accept(res.x)
        return FrameEstimate(res.x, float(res.cost), int(res.evaluations), {"calls": res.calls})

    def _accept(self, x):
        self.v = x - self.x
        self.x = x

    def auto_init(self, frame):
        """A standing pose placed at the foreground's centroid, then refined by hill climbing.

        Arms are lowered to the sides (shoulders rotated by 75 degrees); the pelvis height comes
        from the body's rest pose, its heading faces the camera. Three coarse-to-fine passes with
        a wide grid let the torso and limbs settle.
        """
        z = self.observe(frame)
        pts = foreground_points(z, self.obs.pinhole)
        if len(pts) < 50:
            raise ValueError(f"frame {frame}: too few foreground depth pixels ({len(pts)}) to initialise")
        d, sk = self.body.dofs, self.body.skeleton
        x = d.zero(sk)
        c = np.median(pts, axis=0)
        x[0], x[2] = c[0], c[2]
        cam_c = self.obs.pinhole.center
        heading = np.arctan2(cam_c[0] - c[0], cam_c[2] - c[2])  # face the camera (+Z body front)
        x[d.index("pelvis_ry")] = heading
        for name, val in (("l_shoulder_rz", -1.3), ("r_shoulder_rz", 1.3)):
            if name in d.names:
                x[d.index(name)] = val
        x = d.validate(x)[0]
        wide = 6.0 * self.sigma
        wide[:3] = 0.3
        flat = self.opt.prior_weight
        self.opt.prior_weight = 0.0
        try:
            for _ in range(3):
                x = self.refine(x, x, steps=wide).x
                wide = wide * 0.5
        finally:
            self.opt.prior_weight = flat
        return x

    def close(self):
        self.engine.release()
