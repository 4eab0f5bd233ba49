"""Single depth-camera tracker (Ganapathi et al. 2010): model-based coarse-to-fine hill climbing.

State and motion model: pose ``x_t`` and discrete velocity ``v_t = x_t - x_{t-1}`` with
``v_t ~ N(d * v_{t-1}, Sigma)``; ``Sigma`` is diagonal with the per-DOF inter-frame standard
deviations of :mod:`gltrack.body.dofs` at the dataset's frame rate (``d``, the velocity damping,
keeps a noisy estimate from running away; 1 would be the paper's pure constant velocity).

Objective per frame (lower is better): the engine's depth cost summed over pixels (the negative
log-likelihood of the smoothstep sensor model, pixel-wise or smoothed) plus the negative log of
the velocity prior, ``0.5 * prior_weight * sum(((x - x_pred) / sigma)^2)``.

Search: :func:`gltrack.sample.hillclimb.stage_climb` from the predicted pose, one stage after
another down the kinematic chain (the root's translation, its turn, the rest of the torso, all
four limbs); each DOF of a stage on a grid of ``grid`` values over +-``search_sigmas`` sigmas,
refined ``levels`` times, all of a stage level in one engine call (option ``stages``; "chain"
searches the DOFs one after another, :func:`gltrack.sample.hillclimb.hill_climb`).

Heading hypotheses (why): a subject who turns faster than the prior expects (the hop clip spins
5.6 rad in 2 s, up to 5.5 inter-frame sigmas of the pelvis yaw per frame) leaves the true
heading outside the coarsest grid, and a body seen side-on fits about as well turned a little
either way, so a single climb falls behind the turn and never catches up (hop, seed 1: 4 rad
behind after 40 frames). The root stage is therefore climbed from ``heading_hypotheses``
headings a grid width apart and the best root pose starts the full climb; 3 hypotheses cost
270 more evaluations per frame (721 -> 991) and took the hop clip from 0.10 / 0.22 / 0.21 m
(noise seeds 0 / 1 / 2, 60 frames) to 0.077 / 0.084 / 0.089 m mean marker error; salsa stayed
at 0.069 m (mean of 3 seeds) and walk lost 3 mm (0.044 -> 0.047 m). Widening the grid instead
(``velocity_search`` 1, or ``root_sigma_scale`` 2) made hop seed 0 worse (0.22 m): a wider grid
also accepts wrong headings; climbing the whole torso per hypothesis did not help either.

Observation (why it looks the way it does): with ``crop`` the tile shows a square window around
the predicted body instead of the whole 176x144 sensor image (the paper's 128x128 crop). Without
it a subject 5 m away covers ~100 pixels of a 64-pixel tile, limbs are under a pixel wide and the
depth cost can hardly tell a lost leg from a tracked one (walk clip: 0.14 m -> 0.04 m mean marker
error). The depth cost is multiplied by the area of a tile pixel at the subject's depth over
``area_unit``, so its balance against the prior is the same for every tile size, crop and
distance (the raw pixel sum grows 4x from tile 64 to 128, which weakened the prior 4x). The
background margin grows with the ToF noise (``bg_sigmas``): a fixed 8 cm left speckle all over a
far wall, which feeds the part detector false extrema.

Evidence propagation (``method="hc+ep"`` / ``"ep"``) is added by :mod:`gltrack.track.ep` when
available.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from gltrack.body.mesh import MESH_LODS
from gltrack.body.poses import canonical_poses
from gltrack.gl.programs import ProgramCache
from gltrack.observe.blobs import BlobModel, place_on_centroid
from gltrack.observe.people import pick_person
from gltrack.observe.depth import foreground_points
from gltrack.observe.depth_view import DepthLikelihood, DepthObservation
from gltrack.render.engine import DepthCostParams
from gltrack.sample.hillclimb import hill_climb, hill_climb_lanes, stage_climb
from gltrack.sample.partitions import (default_partitions, exchange_limbs, hill_climb_order,
                                      limb_pairs)
from gltrack.sample.sweep import LEGS, arm_grid, limb_grid, sweep_limbs

from .base import FrameEstimate, NoPersonError, Tracker, rng_state, set_rng_state, two_modes
from .options import Options, at_least, choice, positive, within

log = logging.getLogger(__name__)

#: The limb partitions, in the order the limb stage of the climb falls back to.
LIMBS = ("l_arm", "r_arm", "l_leg", "r_leg")


@dataclass
class DepthOptions(Options):
    """Options of the depth tracker (``--config`` keys). Defaults are general, not per clip.

    tile : tile side in pixels (the observation is resampled to it); 64 or 128
    fine_levels : when > 0, only the last ``fine_levels`` levels of every stage climb
        (``stages = "parts"``: the per-frame climb, its refinement passes and the evidence
        proposals' climbs) score the default view; the levels before them score a coarse view,
        ``coarse_mesh_lod``'s mesh in a ``coarse_tile`` tile
        (:func:`gltrack.sample.hillclimb.stage_climb`'s ``coarse_fn``). 0 (default) = off: every
        level on the default view. Measured (hc+ep, true body and start, 60 frames, walk / hop /
        salsa with noise seeds 0-4, llvmpipe, paired against 0): with 1, the 1008-triangle mesh
        in the same 64-pixel tile runs 1.15x the frames/s (median; 1.01-1.33) and its mean
        marker error is 5.3 +- 4.7 mm higher over the 15 (walk +0.8 +- 2.7, hop +6.6 +- 13.7,
        salsa +8.5 +- 5.0, worse in 4 of 5), the cost of the coarse mesh's shape that the last
        level's small steps (0.16 of the first's) cannot take back; in a 32-pixel tile it lost
        the walk (seed 0: 0.157 m against 0.049), the limbs then under a pixel wide. Hence off:
        an option where frames/s matter more than the last millimetres
    coarse_tile : tile side in pixels of the coarse view (``fine_levels``)
    coarse_mesh_lod : mesh level of detail of the coarse view (``fine_levels``; see ``mesh_lod``)
    smooth : Ganapathi's smoothed likelihood (best 3x3 neighbour + penalty) instead of pixel-wise
    scale : smoothstep saturation distance, metres
    penalty : neighbour penalty of the smoothed likelihood
    levels, grid, shrink, passes : hill-climbing schedule (see ``hill_climb``)
    search_sigmas : half-width of the coarsest grid in inter-frame sigmas
    prior_weight : weight of the velocity prior relative to the depth cost
    velocity_damping : d in v_pred = d * v_prev
    batch_limbs : search corresponding DOFs of the four limbs in one batch
    bg_tolerance : metres; background-removal margin when an empty-scene frame exists
    bg_sigmas : the margin grows by this many range-noise deviations of the difference of two
        noisy frames (ToF noise grows with depth squared: 8 cm is below one sigma on a far wall)
    range_noise_2m : metres, the sensor's range-noise deviation at 2 m (SR4000 data sheet: 1 cm)
    crop : score a square window around the predicted body instead of the whole sensor image
        (the paper's 128x128 crop); the tile then resolves limbs whatever the subject's distance
    crop_margin : metres added on every side of the predicted joints' bounding box
    area_unit : m^2; the depth cost is expressed in units of this surface area at the subject's
        depth (a pixel's footprint times its cost), so the prior balance does not change with
        tile size, crop or distance. 0 = raw pixel sums (tile pixels).
    refine_passes : extra hill-climbing sweeps restricted to the limbs, then one over the torso
    velocity_search : the coarsest grid's half-width grows by this times the DOF's speed in the
        previous frame (radians or metres per frame): a fast DOF's prediction is the least
        certain (a spinning hop turns the pelvis by 5 inter-frame sigmas per frame, beyond a
        fixed +-2 sigma grid, and the tracker falls behind the turn)
    root_sigma_scale : multiplies the inter-frame sigmas of the pelvis rotation (prior and search
        grid). :mod:`gltrack.body.dofs` is tuned for the multi-view trackers; a spinning or
        turning subject seen by one depth camera turns faster than its 0.05 rad/frame at 30 fps
        (hop clip: up to 5.5 sigmas per frame)
    heading_hypotheses : the root stage is climbed from this many pelvis headings (yaw) about
        the prediction, spaced by one coarse grid width (2 x ``search_sigmas`` sigmas) so their
        grids tile a wider interval; the best root pose starts the full climb. 1 = off
        (default 3: see the module docstring)
    heading_margin : another heading replaces the one nearest the prediction only when its root
        climb ends lower by more than this (cost units: ``area_unit`` patches). 0 (default)
        takes the lowest. Measured (hc+ep, one noise seed, mean marker error m, margin 0 / 1 /
        3): walk .045 / .040 / .039, salsa .068 / .058 / .060, demo (15 fps) .098 / .083 /
        .066, but hop .063 / .079 / .233: a margin trades fast turns for steadier slow ones
    init_headings, init_keep : ``--init auto``: headings at which each library pose is placed
        and scored, and how many of the best are hill-climbed, each also turned round (see
        :meth:`auto_init`)
    init_exchange : ``--init auto`` also climbs each heading's best pose with its legs and arms
        exchanged (mirrored): a stride with the other leg forward fits one depth surface about
        as well, and a climb seldom crosses from one to the other (tests/test_track_depth.py:
        a library holding only the mirror-image stride). On the three honest bench clips
        (`bench depth --quick --protocol honest`) no start changed: the same figures to the
        digit. The body estimate switches it off: its own settle already tries the legs both
        ways (:meth:`gltrack.track.body_estimate._Search.settle`), and starting it from the
        exchanged pose moved its stature by 20-60 mm on three of five rendered subjects
        (1.55-1.92 m), each time further from the truth (the MakeHuman hop's came nearer)
    init_depth_offset : metres; ``--init auto`` places the body's volume centroid this far
        behind the centroid of the seen (front) surface, about half a torso's depth
    stages : how the per-frame climb batches its candidates. "parts" (default): one engine
        call per level of each stage (the root's translation, its turn, the rest of the torso,
        all four limbs; the heading hypotheses share the root stages' calls, the evidence
        proposals of a pass share one climb), see :func:`gltrack.sample.hillclimb.stage_climb`.
        "chain": the DOFs one after another (:func:`gltrack.sample.hillclimb.hill_climb`, the
        limbs' i-th DOFs batched with ``batch_limbs``; the heading hypotheses and the evidence
        proposals climb as lanes of the same calls, ``hill_climb_lanes``). Measured (hc+ep,
        true body and start, 60 frames, walk / hop / salsa with noise seeds 0-4, llvmpipe;
        mean marker error, paired difference parts - chain over the five seeds): walk 52.9
        against 48.3 mm (+4.6 +- 2.6), hop 73.3 against 77.5 (-4.3 +- 7.5), salsa 61.3 against
        65.3 (-4.0 +- 4.3), all 15 62.5 against 63.7 (-1.2 +- 3.0); failed markers 1.2 against
        1.7 %; 16-23 engine calls a frame against 116-158, and 1.37-1.42x the frames/s (the
        per-call work and forward kinematics go). hc alone over the same 15: 71.3 against
        67.9 mm (+3.4 +- 4.3), 13 calls a frame against 99. Before the root was split in two
        stages and a rejected combined move kept the best candidate scored around it
        (:func:`~gltrack.sample.hillclimb.stage_climb`), "parts" lost the hop: 122.5 mm over
        the same five seeds
    arm_sweep : 0 (off) or points per swing axis of a grid sweep of each arm after the frame's
        search (:mod:`gltrack.sample.sweep`: the shoulder's two swing angles between their
        limits, the elbow's flexion at 4 points, one engine call of ``arm_sweep**2 * 4 + 1``
        poses an arm, scored by the depth cost alone, :meth:`HillClimbDepthTracker.sweep`); an
        arm the grid improves is climbed once more (the limb stage at half the step). For an
        arm the climb has left over the background: there the depth cost is flat (each of its
        pixels costs the same wherever it is) and no step of the climb's grid leads back to the
        body. Measured (hc+ep, honest: MakeHuman subject, estimated body, automatic start; walk,
        hop and salsa at noise seeds 0-2, 30 frames, llvmpipe, two runs at a time): mean marker
        error over the nine 0.130 m off, 0.103 with 8 (default), 0.108 with 10; never worse
        (the walks to the digit, the salsas 3-6 mm better, the hops at seeds 1 and 2 0.176 /
        0.168 -> 0.098 / 0.119 m, failed markers 17 / 20 % -> 3 / 9 %), at 0.64-0.76x the
        frames/s (8)
    leg_sweep : as ``arm_sweep``, for each leg's hip flexion and abduction and the knee's
        flexion. 0 (default, off): on the same nine datasets, with ``arm_sweep`` 8, 8 made the
        walk at seed 0 0.118 m against 0.089 and the hop at seed 0 0.097 against 0.083 (a leg
        swapped for the other's place), mean 0.105; a leg is seldom left over the background
    sweep_margin : a grid point replaces a limb when its depth cost is lower than the frame's
        pose's by more than this (cost units: ``area_unit`` patches, 2 = 32 cm^2 at the default
        unit, a fifth of a forearm's area). Without a margin the sweep moved an arm
        on 26 of 30 frames of the hop at seed 1 (the grid's best point wins by noise wherever a
        hand lies before the torso) and the start went to the turned twin (0.436 m); with 2 it
        moved one on 5 frames
    mesh_lod : level of detail of the procedural mesh the engine scores with
        (:func:`gltrack.body.mesh.make_body_mesh`: 0 = 1008 triangles, 1 = 1968, 2 = 7872);
        the run's body record keeps its own. 1 by default: measured (hc+ep, true body and
        start, 60 frames, three datasets per clip, llvmpipe) lod 0 runs 1.2-1.45x the frames/s
        and its mean marker error is 3 mm lower on the walk, the same on the hops, but 7 mm
        higher on the salsa in all three (0.078 against 0.071 m)
    """

    tile: int = 64
    fine_levels: int = 0
    coarse_tile: int = 64
    coarse_mesh_lod: int = 0
    smooth: bool = True
    scale: float = 0.15
    penalty: float = 0.02
    levels: int = 3
    grid: int = 5
    shrink: float = 0.4
    passes: int = 1
    search_sigmas: float = 2.0
    prior_weight: float = 0.2
    velocity_damping: float = 0.5
    batch_limbs: bool = True
    bg_tolerance: float = 0.08
    bg_sigmas: float = 3.0
    range_noise_2m: float = 0.01
    crop: bool = True
    crop_margin: float = 0.25
    area_unit: float = 0.0016
    refine_passes: int = 0
    velocity_search: float = 0.0
    root_sigma_scale: float = 1.0
    heading_hypotheses: int = 3
    heading_margin: float = 0.0
    init_headings: int = 12
    init_keep: int = 2
    init_exchange: bool = True
    init_depth_offset: float = 0.1
    stages: str = "parts"
    arm_sweep: int = 8
    leg_sweep: int = 0
    sweep_margin: float = 2.0
    mesh_lod: int = 1

    def problems(self):
        return super().problems() + [
            *choice(self, "tile", (16, 32, 64, 128, 256)),
            *choice(self, "coarse_tile", (16, 32, 64, 128, 256)),
            *choice(self, "coarse_mesh_lod", MESH_LODS),
            *choice(self, "stages", ("parts", "chain")),
            *choice(self, "mesh_lod", MESH_LODS),
            *positive(self, "scale", "search_sigmas", "root_sigma_scale"),
            *within(self, "shrink", 0, 1, open_lo=True, open_hi=True),
            *at_least(self, 1, "levels", "passes", "heading_hypotheses", "init_headings",
                      "init_keep"),
            *at_least(self, 2, "grid"),
            *at_least(self, 0, "fine_levels", "penalty", "prior_weight", "bg_tolerance",
                      "bg_sigmas", "range_noise_2m", "crop_margin", "area_unit", "refine_passes",
                      "velocity_search", "heading_margin", "init_depth_offset", "arm_sweep",
                      "leg_sweep", "sweep_margin"),
            *within(self, "velocity_damping", 0, 1)]


def root_rotation_dofs(dofs) -> list[int]:
    """Indices of the rotation DOFs of the kinematic root (the pelvis), in DOF order."""
    root = int(dofs.joint[3]) if dofs.size > 3 else -1
    return [i for i in range(3, dofs.size) if int(dofs.joint[i]) == root]


class HillClimbDepthTracker(Tracker):
    """Ganapathi's model-based hill climbing on the GPU depth likelihood."""

    method = "hc"

    def __init__(self, dataset, body, ctx, options: DepthOptions | None = None, rng=None):
        self.opt = (options or DepthOptions()).validate()
        self.body = body.with_lod(self.opt.mesh_lod)
        self.ctx = ctx
        o = self.opt
        self.obs = DepthObservation(dataset, bg_tolerance=o.bg_tolerance, bg_sigmas=o.bg_sigmas,
                                    range_noise_2m=o.range_noise_2m)
        self.programs = ProgramCache(ctx)
        params = DepthCostParams(scale=o.scale, penalty=o.penalty, smooth=o.smooth)
        self.likelihood = DepthLikelihood(
            ctx, self.body, self.obs.pinhole, tile=o.tile, crop=o.crop, area_unit=o.area_unit,
            params=params, programs=self.programs)
        # the coarse view the early levels of every stage climb score (``fine_levels``)
        self.coarse_likelihood = None
        if o.fine_levels > 0 and (o.coarse_tile, o.coarse_mesh_lod) != (o.tile, o.mesh_lod):
            self.coarse_likelihood = DepthLikelihood(
                ctx, body.with_lod(o.coarse_mesh_lod), self.obs.pinhole, tile=o.coarse_tile,
                crop=o.crop, area_unit=o.area_unit, params=params, programs=self.programs)
        self.sigma = body.dofs.sigma_at(dataset.fps).copy()
        self._root_rot = root_rotation_dofs(body.dofs)
        self.sigma[self._root_rot] *= o.root_sigma_scale
        self.order = hill_climb_order(body.dofs, group_limbs=o.batch_limbs)
        parts = default_partitions(body.dofs)
        self.torso_dofs = [i for i in self.order if isinstance(i, int)]
        self.limb_order = [g for g in self.order if not isinstance(g, int)] or \
            [int(i) for k in LIMBS if k in parts for i in parts[k]]
        self.parts = parts
        self.root_dofs = [i for i in self.torso_dofs if i < 3 or i in self._root_rot]
        rest = [i for i in self.torso_dofs if i not in self.root_dofs]
        limbs = [int(i) for g in self.limb_order for i in np.atleast_1d(g)]
        # the root in two stages, its translation then its turn (the chain's order): climbed as
        # one Jacobi step the two overshoot together (a turn about the pelvis moves the whole
        # body, which a translation also does)
        self.root_stages = [s for s in ([i for i in self.root_dofs if i < 3],
                                        [i for i in self.root_dofs if i >= 3]) if s]
        self.stage_dofs = [s for s in (*self.root_stages, rest, limbs) if s]
        #: the per-frame sweep's grids (``arm_sweep``, ``leg_sweep``); a sweep of 1 point an
        #: axis would only try the limits
        self._limb_grids = ((arm_grid(self.body.dofs, o.arm_sweep) if o.arm_sweep > 1 else [])
                            + (limb_grid(self.body.dofs, o.leg_sweep, limbs=LEGS)
                               if o.leg_sweep > 1 else []))
        self.x = None
        self.v = None
        self.rng = rng

    # -- objective ------------------------------------------------------------------------
    def depth_cost(self, X: np.ndarray, coarse: bool = False) -> np.ndarray:
        """(N,) depth cost of N poses against the current observation, in ``area_unit``s
        (tile pixels when ``area_unit`` is 0); ``coarse``: on the coarse view (``coarse_tile``,
        ``coarse_mesh_lod``) when the tracker has one."""
        lk = self.coarse_likelihood if coarse and self.coarse_likelihood else self.likelihood
        return lk.cost(X)

    def objective(self, x_pred, prior_weight: float | None = None, coarse: bool = False):
        """The frame's cost function ``X (N, D) -> (N,)``: depth cost plus the velocity prior
        centred on ``x_pred`` with ``prior_weight`` (default: the option); ``coarse``: the
        depth cost on the coarse view."""
        def cost(X):
            X = np.atleast_2d(X)
            return self.depth_cost(X, coarse) + self.prior(X, x_pred, prior_weight)

        return cost

    def coarse_objective(self, x_pred, prior_weight: float | None = None):
        """:meth:`objective` on the coarse view, for the early levels of the stage climbs
        (``fine_levels``); None when the tracker has no coarse view."""
        if self.coarse_likelihood is None:
            return None
        return self.objective(x_pred, prior_weight, coarse=True)

    def prior(self, X, x_pred, prior_weight: float | None = None) -> np.ndarray:
        """(N,) the velocity prior's term of :meth:`objective` for poses ``X`` (N, D)."""
        w = 0.5 * (self.opt.prior_weight if prior_weight is None else prior_weight)
        return w * np.sum(((np.atleast_2d(X) - x_pred) / self.sigma) ** 2, axis=1)

    def quality_of(self, x, cost: float, x_pred) -> float:
        """:meth:`quality` of ``x`` from its known :meth:`objective` ``cost`` (prior centred on
        ``x_pred``, default weight), without another engine call."""
        depth = float(cost) - float(self.prior(x, x_pred)[0])
        return max(depth, 0.0) / max(self.likelihood.area, 1e-9)

    def _climb(self, cost, x, order, steps, levels, cost0=None, rescore_centre=False):
        d = self.body.dofs
        return hill_climb(cost, x, order, steps, levels=levels, grid=self.opt.grid,
                          shrink=self.opt.shrink, batch_independent=self.opt.batch_limbs,
                          lower=d.lower, upper=d.upper, passes=self.opt.passes,
                          cost0=None if rescore_centre else cost0,
                          rescore_centre=rescore_centre)

    def refine(self, x_start, x_pred, steps=None, levels=None, extra=None, prior_weight=None,
               stages=None, rescore_centre=False):
        """Hill-climb from ``x_start`` under the prior centred on ``x_pred`` (weighted by
        ``prior_weight``, default the option).

        One coarse-to-fine sweep down the kinematic chain, then ``refine_passes`` (or ``extra``)
        sweeps over the limbs only at half the step (the limbs were searched while the torso
        was still moving), each followed by a torso re-check at a quarter of the step.
        ``stages`` ("parts" or "chain") overrides the option of that name; ``rescore_centre``
        ("chain" only): every grid point is scored, the centre included
        (:func:`gltrack.sample.hillclimb.hill_climb_lanes`).

        Returns
        -------
        HillClimbResult with the evaluations of all sweeps.
        """
        cost = self.objective(x_pred, prior_weight)
        steps = self.search_steps() if steps is None else np.asarray(steps)
        levels = self.opt.levels if levels is None else levels
        if (stages or self.opt.stages) == "parts":
            return self._refine_stages(cost, x_start, steps, levels,
                                       self.opt.refine_passes if extra is None else extra,
                                       self.coarse_objective(x_pred, prior_weight))
        evals = calls = 0
        c0 = None
        if self.opt.heading_hypotheses > 1:
            x_start, c0, evals, calls = self._best_heading(cost, x_start, steps, levels,
                                                           rescore_centre)
        res = self._climb(cost, x_start, self.order, steps, levels, c0, rescore_centre)
        evals, calls = evals + res.evaluations, calls + res.calls
        for _ in range(self.opt.refine_passes if extra is None else extra):
            for order, h in ((self.limb_order, 0.5), (self.torso_dofs, 0.25)):
                if not order:
                    continue
                r = self._climb(cost, res.x, order, h * steps, max(1, levels - 1),
                                res.cost, rescore_centre)
                evals, calls = evals + r.evaluations, calls + r.calls
                if r.cost <= res.cost:
                    res = r
        return type(res)(res.x, res.cost, evals, calls)

    def sweep(self, x, c, x_pred):
        """The per-frame limb sweep (``arm_sweep``, ``leg_sweep``) of the frame's result ``x``
        (D,) with objective ``c``, the prior centred on ``x_pred``.

        The grid is scored by the depth cost alone: it is there to find a limb the track has
        lost, and the prior, centred on the lost limb, is what holds it there. A grid point
        that explains the frame better by more than ``sweep_margin`` replaces the limb, whose
        prediction is then dropped: the limb is climbed once more (the limb stage at half the
        step) under the prior centred on the swept pose.

        Returns
        -------
        x : (D,) the pose (``x`` itself when no grid point of any limb won)
        cost : its objective, the prior centred on ``x_pred`` as for any frame
        evaluations, calls : int, of the sweep and its climb
        swept : tuple of str, the swing joints whose grid won
        moved : (D,) bool, the DOFs the sweep replaced (their velocity is void)
        """
        none = np.zeros(len(x), dtype=bool)
        if not self._limb_grids:
            return x, c, 0, 0, (), none
        sw = sweep_limbs(x, lambda X: -self.depth_cost(X), self._limb_grids,
                         margin=self.opt.sweep_margin)
        calls = len(self._limb_grids)
        if not sw.improved:
            return x, c, sw.evaluations, calls, (), none
        moved = sw.delta != 0
        centre = np.where(moved, sw.estimate, x_pred)
        cost = self.objective(centre)
        steps = 0.5 * self.search_steps()
        levels = max(1, self.opt.levels - 1)
        if self.opt.stages == "parts":
            r = self._stage_climb(cost, sw.estimate[None], self.stage_dofs[-1:], steps, levels)
            x_new, c_new = r.X[0], float(r.cost[0])
        else:
            r = self._climb(cost, sw.estimate, self.limb_order, steps, levels)
            x_new, c_new = r.x, float(r.cost)
        # the same objective as every other frame's: depth plus the prior about x_pred
        c_new += float(self.prior(x_new, x_pred)[0] - self.prior(x_new, centre)[0])
        return x_new, c_new, sw.evaluations + int(r.evaluations), calls + int(r.calls), \
            sw.improved, moved

    def _stage_climb(self, cost, X, stages, steps, levels, cost0=None, coarse=None):
        """:func:`stage_climb` with the options; ``coarse``: the coarse view's cost function,
        scoring every stage's levels before its last ``fine_levels``."""
        d = self.body.dofs
        return stage_climb(cost, X, stages, steps, levels=levels, grid=self.opt.grid,
                           shrink=self.opt.shrink, lower=d.lower, upper=d.upper, cost0=cost0,
                           coarse_fn=coarse, fine_levels=max(self.opt.fine_levels, 1))

    def heading_starts(self, x, steps) -> np.ndarray:
        """(H, D) copies of ``x`` turned to the ``heading_hypotheses`` pelvis headings, one coarse
        grid width (2 ``steps`` of the yaw) apart, the middle one ``x`` itself."""
        d = self.body.dofs
        yaw = d.index("pelvis_ry") if "pelvis_ry" in d.names else 3
        h = self.opt.heading_hypotheses
        X = np.repeat(np.asarray(x, dtype=np.float64)[None], h, axis=0)
        X[:, yaw] = np.clip(X[:, yaw] + (np.arange(h) - (h - 1) / 2) * 2.0 * steps[yaw],
                            d.lower[yaw], d.upper[yaw])
        return X

    def pick_heading(self, costs) -> int:
        """Index of the heading kept: the one nearest the prediction unless another's cost is
        lower by more than ``heading_margin`` (then the lowest)."""
        costs = np.asarray(costs, dtype=np.float64)
        mid = (len(costs) - 1) // 2
        clear = np.nonzero(costs < costs[mid] - self.opt.heading_margin)[0]
        return int(clear[np.argmin(costs[clear])]) if clear.size else mid

    def _refine_stages(self, cost, x_start, steps, levels, extra, coarse=None):
        """:meth:`refine` with ``stages="parts"``: the root stages climbed from every heading
        hypothesis in the same calls, the best one then climbs the torso and limb stages
        (``coarse``: the coarse view's cost, see :meth:`_stage_climb`)."""
        from gltrack.sample.hillclimb import HillClimbResult

        stages = self.stage_dofs
        evals = calls = 0
        X = np.asarray(x_start, dtype=np.float64)[None]
        if self.opt.heading_hypotheses > 1 and self.root_dofs:
            r = self._stage_climb(cost, self.heading_starts(x_start, steps), self.root_stages,
                                  steps, levels, coarse=coarse)
            evals, calls = r.evaluations, r.calls
            k = self.pick_heading(r.cost)
            X, c0 = r.X[k][None], r.cost[k:k + 1]
            stages = stages[len(self.root_stages):]
        else:
            c0 = None
        r = self._stage_climb(cost, X, stages, steps, levels, cost0=c0, coarse=coarse)
        evals, calls = evals + r.evaluations, calls + r.calls
        x, c = r.X[0], float(r.cost[0])
        limbs, torso = stages[-1:], stages[:-1]
        for _ in range(int(extra)):
            for st, h in ((limbs, 0.5), (torso, 0.25)):
                if not st:
                    continue
                r = self._stage_climb(cost, x[None], st, h * steps, max(1, levels - 1),
                                      cost0=[c], coarse=coarse)
                evals, calls = evals + r.evaluations, calls + r.calls
                x, c = r.X[0], float(r.cost[0])
        return HillClimbResult(x, c, evals, calls)

    def _best_heading(self, cost, x, steps, levels, rescore_centre=False):
        """Climb the root DOFs from ``heading_hypotheses`` pelvis headings; the best root pose.

        Why: a subject turning faster than the prediction allows leaves the true heading
        outside the coarse grid, and a wrong heading is a deep local minimum of the depth cost
        (a side view fits either way round), which hill climbing from one start cannot leave.
        The hypotheses climb side by side (:func:`hill_climb_lanes`: each exactly as alone, all
        in the calls of one); the one nearest the prediction keeps the root unless another
        explains the depth clearly better (:meth:`pick_heading`): a side view fits about as
        well turned either way.

        Returns
        -------
        x : (D,) float64, cost : float (``cost`` of ``x``), evaluations : int, calls : int
        """
        d = self.body.dofs
        root = [i for i in self.order if isinstance(i, int) and (i < 3 or i in self._root_rot)]
        r = hill_climb_lanes(cost, self.heading_starts(x, steps), root, steps, levels=levels,
                             grid=self.opt.grid, shrink=self.opt.shrink,
                             batch_independent=self.opt.batch_limbs, lower=d.lower,
                             upper=d.upper, passes=self.opt.passes,
                             rescore_centre=rescore_centre)
        k = self.pick_heading(r.cost)
        return r.X[k], float(r.cost[k]), r.evaluations, r.calls

    def search_steps(self) -> np.ndarray:
        """(D,) half-widths of the coarsest hill-climbing grid: ``search_sigmas`` inter-frame
        sigmas plus ``velocity_search`` times the last frame's speed of each DOF."""
        steps = self.opt.search_sigmas * self.sigma
        if self.v is not None and self.opt.velocity_search > 0:
            steps = steps + self.opt.velocity_search * np.abs(self.v)
        return steps

    # -- tracking -------------------------------------------------------------------------
    def start(self, frame, params, velocity=None):
        self.x = self.body.dofs.validate(params)[0]
        self.v = np.zeros_like(self.x) if velocity is None else np.asarray(velocity, float).copy()

    def get_state(self):
        """The pose, its velocity and the generator (the crop window follows from them)."""
        if self.x is None:
            return None
        return {"x": self.x.copy(), "v": self.v.copy(),
                "rng": None if self.rng is None else rng_state(self.rng)}

    def set_state(self, state):
        self.x = np.array(state["x"], dtype=np.float64)
        self.v = np.array(state["v"], dtype=np.float64)
        if state.get("rng") is not None and self.rng is not None:
            set_rng_state(self.rng, state["rng"])

    def set_view(self, z, pose=None, margin=None):
        """Upload the observation ``z`` for scoring, cropped around ``pose`` when ``crop`` is on.

        Also sets the area weight of the depth cost (see ``area_unit``).
        """
        margin = self.opt.crop_margin if margin is None else margin
        pts = self.body.joints(np.asarray(pose)[None])[0] if pose is not None else None
        self.likelihood.set_view(z, pts, margin)
        if self.coarse_likelihood is not None:
            self.coarse_likelihood.set_view(z, pts, margin)

    def observe(self, frame, pose=None):
        """Read frame ``frame``, upload it around ``pose`` (default: the prediction) and return
        the full background-subtracted (H, W) depth image, metres."""
        z = self.obs(frame)
        if pose is None and self.x is not None:
            pose = self.predict()
        self.set_view(z, pose)
        return z

    def predict(self):
        return self.body.dofs.validate(self.x + self.opt.velocity_damping * self.v)[0]

    def transform_state(self, fn):
        if self.x is None:
            raise RuntimeError("start() the tracker first")
        self.x = self.body.dofs.validate(fn(self.x[None]))[0]

    def step(self, frame):
        if self.x is None:
            raise RuntimeError("start() the tracker first")
        self.observe(frame)
        x_pred = self.predict()
        res = self.refine(x_pred, x_pred)
        x, c, evals, calls, swept, moved = self.sweep(res.x, float(res.cost), x_pred)
        self._accept(x, void=moved)
        info = {"calls": res.calls + calls, "quality": self.quality_of(x, c, x_pred)}
        if self._limb_grids:
            info["swept"] = list(swept)
        return FrameEstimate(x, c, int(res.evaluations) + evals, info)

    #: a frame is lost when the pose leaves more than this share of the seen person unexplained
    #: (:meth:`quality`; the multi-view trackers use the same figure on silhouettes). Measured
    #: on the CMU walk drawn with the MakeHuman mesh (20 frames, true body; hc / hc+ep):
    #: 0.25-0.35 while tracked (model mismatch and noise), 0.50-0.61 in the first frames after
    #: the state was turned 90 degrees, 0.41-0.52 once the climb settled in the wrong basin. A
    #: false alarm costs time only: the runner then tracks the current pose and the automatic
    #: start side by side and keeps the better.
    lost_quality = 0.45

    def quality(self, x) -> float:
        """Depth cost of pose ``x`` (D,) per unit of the seen person's area (one evaluation):
        about the share of the person's pixels the pose does not explain (0 = all; model pixels
        where nothing was seen add to it)."""
        return float(self.depth_cost(np.asarray(x)[None])[0]) / max(self.likelihood.area, 1e-9)

    def _accept(self, x, void=None):
        """Take ``x`` as the frame's pose; the velocity of the DOFs ``void`` ((D,) bool, e.g. a
        limb the sweep re-placed) is zero rather than the jump."""
        self.v = x - self.x
        if void is not None:
            self.v[void] = 0.0
        self.x = x

    def start_hypotheses(self, frame):
        """Find the body in ``frame`` without any pose given.

        A global search, then the tracker's own search: every pose of the library
        (:func:`gltrack.body.poses.canonical_poses`) is placed at ``init_headings`` headings
        with its volume centroid ``init_depth_offset`` behind the centroid of the foreground
        points (the camera sees the front surface) and scored by the depth cost; each of the
        ``init_keep`` best, and each turned round by 180 degrees, is hill-climbed on its own
        without the motion prior (three
        coarse-to-fine passes with a grid of 6 sigmas, halved each pass, the root +-0.3 m, each
        with two extra limb sweeps); each heading's best is climbed once more with its legs and
        arms exchanged (mirrored), and the lowest cost starts the tracker.

        Why the extra limb sweeps: seen side-on, the body at the right heading got stuck with an
        arm behind the torso (cost 9.5 against 4.7 for the mirror-image heading, 290 mm off);
        with the sweeps it reached 4.3 and won (34 mm).

        Seen face-on by one camera, a body turned round fits about as well (only the feet and
        the bent knees tell them apart): on the test walk the best 3 placed poses all faced
        away, and the start was mirrored until the turned-round twins were climbed too.

        Raises
        ------
        NoPersonError
            Too few foreground pixels in the frame (no person, or nothing valid).
        """
        o, d = self.opt, self.body.dofs
        z = self.obs(frame)
        pts = foreground_points(z, self.obs.pinhole)
        if len(pts) < 50:
            raise NoPersonError(f"frame {frame}: too few foreground depth pixels ({len(pts)}) to "
                                "initialise: no person in front of the camera?")
        # the largest connected surface: a second person is not averaged in
        c = pick_person(pts, where=f"frame {frame}").centroid
        ray = c - self.obs.pinhole.center
        c = c + o.init_depth_offset * ray / np.linalg.norm(ray)
        _, library = canonical_poses(d, self.body.skeleton)
        P = place_on_centroid(self.body, BlobModel(self.body.mesh, self.body.skeleton), library,
                              o.init_headings, c)
        self.set_view(z, None, margin=max(o.crop_margin, 0.5))  # framed on the foreground
        cost = self.objective(P[0], prior_weight=0.0)
        seeds = P[np.argsort(cost(P))[:o.init_keep]]
        # each seed also turned round: seen face-on, the placed poses' ranking hardly tells a
        # body from its turned-round twin (on the test walk all of the best 3 faced away)
        twins = seeds.copy()
        twins[:, d.index("pelvis_ry")] += np.pi
        seeds = np.concatenate([seeds, d.validate(twins)])
        # The full grid, the centres re-scored (``rescore_centre``), as before the per-frame
        # climb skipped them: the start is one frame, so its candidates do not matter, and the
        # body estimate that starts from it was measured worse with the centres skipped (four
        # simulated depth subjects, 1.62-1.92 m: 6-47 mm off in height, mean 23, against 5-27,
        # mean 13)
        def climb(x):
            wide = 6.0 * self.sigma
            wide[:3] = 0.3
            for _ in range(3):  # no prior: there is no motion to predict from yet
                # DOF by DOF: a global search from a library pose moves far, and there the
                # stages' Jacobi steps fell short (a side-on body turned 90 degrees: 0.29 m
                # mean joint error against 0.01 m); one frame, so its calls do not matter
                res = self.refine(x, x, steps=wide, extra=2, prior_weight=0.0, stages="chain",
                                  rescore_centre=True)
                x, wide = res.x, wide * 0.5
            return x, float(res.cost)

        X, costs = map(list, zip(*[climb(x) for x in seeds]))
        # each heading's best climbed pose also with the legs and arms exchanged (mirrored) and
        # climbed again: a stride with the other leg forward fits a depth surface about as well
        # and a climb seldom goes from one to the other (as the multi-view start)
        pairs = limb_pairs(d) if self.opt.init_exchange else []
        if pairs:
            for m in two_modes(X, costs, d.index("pelvis_ry")):
                x, c = climb(d.validate(exchange_limbs(m, pairs))[0])
                X.append(x)
                costs.append(c)
        log.info("auto init: %d placed poses, %d refined, cost %.3g", len(P), len(X),
                 min(costs))
        return two_modes(X, costs, d.index("pelvis_ry"))

    def close(self):
        self.likelihood.release()
        if self.coarse_likelihood is not None:
            self.coarse_likelihood.release()
        self.programs.release()
