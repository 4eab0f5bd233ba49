"""Coarse-to-fine hill climbing along the kinematic chain (Ganapathi et al. 2010, sec. 4).

Deterministic local search: starting at the base of the chain (root, torso) and moving out to
the limbs, each dimension is set to the best of a grid of values about its current value,
then the grid is shrunk about the winner and evaluated again (``levels`` times). Every grid is
one batched call of ``cost_fn``, which suits a GPU that scores a tile of candidates at once.

Batching independent limbs
--------------------------
With ``batch_independent=True``, an entry of ``dims_order`` that is a tuple, e.g. the i-th DOF
of the left arm, right arm, left leg and right leg, is searched in ONE batch: the candidates
vary one of those dims at a time (all others at their current values) and each dim then takes
its own best value. This is valid because the cost decomposes approximately into a sum of
per-part terms, ``c(x) ~ c_torso(x_t) + sum_limb c_limb(x_t, x_limb)``: changing the left-arm
dim only changes ``c_l_arm``, so its best value does not depend on the right-arm dim and
searching them separately in one batch gives the same answer as searching them one after the
other, in a quarter of the ``cost_fn`` calls. Where limbs interact (touching hands, one limb
occluding another) the decomposition is only approximate; the combined step is then checked
by the next grid, whose centre is the combined pose.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)


@dataclass
class HillClimbResult:
    """Outcome of :func:`hill_climb`.

    Attributes
    ----------
    x : (D,) float64, best pose found
    cost : float, ``cost_fn`` of ``x``
    evaluations : int, candidates passed to ``cost_fn`` (rows over all calls)
    calls : int, calls of ``cost_fn`` (batches)
    """

    x: np.ndarray
    cost: float
    evaluations: int
    calls: int


class _CountedCost:
    """``cost_fn`` checked and counted: ``(M, D) -> (M,)`` non-NaN costs, with the candidates
    (``evaluations``) and batches (``calls``) it was given."""

    def __init__(self, cost_fn):
        self.cost_fn = cost_fn
        self.evaluations = 0
        self.calls = 0

    def __call__(self, cand: np.ndarray) -> np.ndarray:
        c = np.asarray(self.cost_fn(cand), dtype=np.float64).ravel()
        if c.shape != (cand.shape[0],) or np.any(np.isnan(c)):
            raise ValueError(f"cost_fn must return ({cand.shape[0]},) non-NaN costs, "
                             f"got shape {c.shape}")
        self.evaluations += cand.shape[0]
        self.calls += 1
        return c


def _groups(dims_order, batch_independent: bool, d: int) -> list[tuple[int, ...]]:
    groups = []
    for entry in dims_order:
        g = tuple(int(i) for i in np.atleast_1d(entry))
        if not g or min(g) < 0 or max(g) >= d:
            raise ValueError(f"dims_order entry {entry!r} is empty or outside 0..{d - 1}")
        if batch_independent:
            groups.append(g)
        else:
            groups.extend((i,) for i in g)
    return groups


def hill_climb(cost_fn, x0, dims_order, steps, *, levels: int = 3, grid: int = 5,
               shrink: float = 0.4, batch_independent: bool = False, lower=None, upper=None,
               passes: int = 1, cost0: float | None = None,
               rescore_centre: bool = False) -> HillClimbResult:
    """Coarse-to-fine coordinate search; lower cost is better.

    Parameters
    ----------
    cost_fn : callable, (M, D) float64 -> (M,) float
    x0 : (D,) float, start pose
    dims_order : sequence of int or tuple of int
        Dimensions in kinematic order (base first). A tuple groups dims of independent limbs;
        with ``batch_independent`` they share one batch per level (see module docstring),
        otherwise they are searched one after another.
    steps : float or (D,) float
        Half-width of the coarsest grid per dimension (e.g. 2 inter-frame sigmas).
    levels : int >= 1, grid refinements per dimension
    grid : int >= 2, grid points per level; an odd count puts one point on the current value
    shrink : float in (0, 1), half-width factor from one level to the next
    batch_independent : bool
    lower, upper : (D,) float, optional, limits; candidates are clamped into them
    passes : int >= 1, sweeps over ``dims_order``
    cost0 : float, optional, ``cost_fn(x0)`` when known
    rescore_centre : bool, see :func:`hill_climb_lanes`

    Returns
    -------
    HillClimbResult. ``evaluations == passes * levels * (grid - 1) * (number of dims)`` for an
    odd grid (the centre, the current pose, has a known cost; ``grid`` per dim for an even one),
    plus one for each centre not yet scored: the start's (without ``cost0``), and the pose after
    a combined move of a batched group, whose cost is scored once, at the next step or at the end.
    """
    x = np.array(x0, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"x0 must be one pose (D,), got shape {x.shape}; see hill_climb_lanes")
    r = hill_climb_lanes(cost_fn, x[None], dims_order, steps, levels=levels, grid=grid,
                         shrink=shrink, batch_independent=batch_independent, lower=lower,
                         upper=upper, passes=passes,
                         cost0=None if cost0 is None else [float(cost0)],
                         rescore_centre=rescore_centre)
    return HillClimbResult(r.X[0], float(r.cost[0]), r.evaluations, r.calls)


def hill_climb_lanes(cost_fn, X0, dims_order, steps, *, levels: int = 3, grid: int = 5,
                     shrink: float = 0.4, batch_independent: bool = False, lower=None,
                     upper=None, passes: int = 1, active=None, cost0=None,
                     rescore_centre: bool = False) -> "StageClimbResult":
    """:func:`hill_climb` of K start poses (lanes) at once: one ``cost_fn`` call per step.

    Every lane walks exactly the search :func:`hill_climb` would walk from its start (the lanes
    never mix), but the candidates of all lanes for the same dim (or group) and level go into
    one call. Why: a GPU scores a tile of candidates in about the time of one, so K climbs
    (heading hypotheses, evidence proposals) cost the calls of one.

    A grid's centre (with an odd ``grid``) is the lane's current pose, whose cost is usually
    known from the step before: it is then not scored again, and a batched group scores it once,
    not once per dim. Why: on a software renderer the time goes into the candidates, and the
    centres were a fifth of them (a quarter in the limb groups); the search is the same.

    Parameters
    ----------
    cost_fn : callable, (M, D) float64 -> (M,) float
    X0 : (K, D) float, start poses
    dims_order, levels, grid, shrink, batch_independent, lower, upper, passes :
        as in :func:`hill_climb`
    steps : float, (D,) or (K, D) float, half-width of the coarsest grid per dim (and lane)
    active : (K, D) or (D,) bool, optional, the dims each lane searches (default: all); the
        others keep their start values in that lane (e.g. an evidence proposal climbs only the
        kinematic chain its inverse kinematics moved)
    cost0 : (K,) float, optional, ``cost_fn(X0)`` when known (saves scoring the first centre)
    rescore_centre : bool, score every grid point, the centre included, in every call (the
        search before the centres were skipped; a group's cost is then never carried over).
        Kept for the depth tracker's automatic start, which the body estimate starts from (see
        ``HillClimbDepthTracker.start_hypotheses``)

    Returns
    -------
    StageClimbResult: ``X`` (K, D), ``cost`` (K,), ``evaluations`` (the sum of the lanes'
    :func:`hill_climb` evaluations), ``calls`` (those of one lane).
    """
    X = np.array(X0, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] < 1:
        raise ValueError(f"X0 must be (K, D) start poses, got shape {X.shape}")
    k, d = X.shape
    if not np.all(np.isfinite(X)):
        raise ValueError("x0 must be finite")
    if int(levels) < 1 or int(grid) < 2 or not 0 < shrink < 1 or int(passes) < 1:
        raise ValueError(f"need levels >= 1, grid >= 2, 0 < shrink < 1, passes >= 1; got "
                         f"{levels}, {grid}, {shrink}, {passes}")
    steps = np.broadcast_to(np.asarray(steps, dtype=np.float64), (k, d))
    on = (np.ones((k, d), dtype=bool) if active is None
          else np.broadcast_to(np.asarray(active, dtype=bool), (k, d)))
    lo = np.full(d, -np.inf) if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.full(d, np.inf) if upper is None else np.asarray(upper, dtype=np.float64)
    X = np.clip(X, lo, hi)
    offsets = np.linspace(-1.0, 1.0, int(grid))
    centre = np.flatnonzero(offsets == 0.0)  # (1,) with an odd grid, else empty
    moves = np.flatnonzero(offsets != 0.0)  # the other columns (all, with an even grid)
    cols = np.arange(offsets.size) if rescore_centre else moves
    groups = _groups(dims_order, batch_independent, d)
    call = _CountedCost(cost_fn)
    # cost of each lane's current pose, NaN = not known
    cost = (np.full(k, np.nan) if cost0 is None
            else np.asarray(cost0, dtype=np.float64).reshape(k).copy())

    for _ in range(int(passes)):
        for g in groups:
            gi = np.array(g)
            sub = on[:, gi]  # (K, g) the dims of this group each lane searches
            if not sub.any():
                continue
            for level in range(int(levels)):
                h = steps[:, gi] * shrink ** level  # (K, g)
                vals = np.clip(X[:, gi, None] + h[:, :, None] * offsets, lo[gi, None],
                               hi[gi, None])  # (K, g, grid)
                rows, where = [], []  # candidate poses and their (lane, dim, column) slots
                for lane in range(k):
                    dims = np.flatnonzero(sub[lane])
                    if dims.size == 0:
                        continue
                    if centre.size and np.isnan(cost[lane]) and not rescore_centre:
                        rows.append(X[lane][None])  # the centre, once for all dims
                        where.append((lane, -1, -1))
                    for j in dims:
                        cand = np.repeat(X[lane][None], cols.size, axis=0)
                        cand[:, gi[j]] = vals[lane, j, cols]
                        rows.append(cand)
                        where.extend((lane, j, c) for c in cols)
                scored = call(np.concatenate(rows))
                c = np.full((k, gi.size, offsets.size), np.inf)
                for (lane, j, col), v in zip(where, scored):
                    if j < 0:
                        cost[lane] = v
                    else:
                        c[lane, j, col] = v
                if centre.size and not rescore_centre:
                    c[:, :, centre[0]] = np.where(sub, cost[:, None], np.inf)
                # among equal costs take the candidate nearest the current value
                tie = np.where(c == c.min(axis=2, keepdims=True), np.abs(offsets), np.inf)
                best = np.argmin(tie, axis=2)  # (K, g)
                cb = np.take_along_axis(c, best[:, :, None], axis=2)[:, :, 0]
                vb = np.take_along_axis(vals, best[:, :, None], axis=2)[:, :, 0]
                # a move must beat the current cost (when known), so a flat or noisy cost
                # does not make the pose drift
                move = sub & (np.isnan(cost)[:, None] | (cb < cost[:, None]))
                X[:, gi] = np.where(move, vb, X[:, gi])
                n_moved = move.sum(axis=1)
                one = n_moved == 1
                cost[one] = np.where(move, cb, np.inf)[one].min(axis=1)
                cost[n_moved > 1] = np.nan  # the combined move was never scored as a whole
                if rescore_centre and gi.size > 1:
                    cost[sub.any(axis=1)] = np.nan
    todo = np.flatnonzero(np.isnan(cost))
    if todo.size:
        cost[todo] = call(X[todo])
    return StageClimbResult(X, cost, call.evaluations, call.calls)


@dataclass
class StageClimbResult:
    """Outcome of :func:`stage_climb`.

    Attributes
    ----------
    X : (K, D) float64, best pose of each lane
    cost : (K,) float64, ``cost_fn`` of each row of ``X``
    evaluations : int, candidates passed to ``cost_fn`` (rows over all calls, all lanes)
    calls : int, calls of ``cost_fn``
    """

    X: np.ndarray
    cost: np.ndarray
    evaluations: int
    calls: int


def stage_climb(cost_fn, X0, stages, steps, *, levels: int = 3, grid: int = 5,
                shrink: float = 0.4, lower=None, upper=None, cost0=None, coarse_fn=None,
                fine_levels: int = 1) -> StageClimbResult:
    """Coarse-to-fine search of K independent start poses, one ``cost_fn`` call per stage level.

    Like :func:`hill_climb` with every entry of ``stages`` a batched group, with two differences
    that make a whole stage one call:

    * all dims of a stage are searched in one batch (each varied alone about the current pose,
      each then taking its own best value: a Jacobi step where :func:`hill_climb` walks the
      dims one after the other), and all ``K`` lanes (e.g. heading hypotheses, evidence
      proposals) share that call; the lanes never mix.
    * a combined move (more than one dim moved) is checked: every call also scores each lane's
      current pose (the grid's centre), and a combined move that turned out worse than the best
      single-dim move of its batch is replaced by that single move (whose cost is known), so the
      cost never rises. Why: the dims of one stage are coupled (a shoulder's three rotations,
      the pelvis' translation and turn), and moves that each lower the cost alone can overshoot
      together. The batch scored around a rejected move is not thrown away: its best candidate
      is kept when it beats the single move fallen back to (its cost is known, so the cost
      still never rises). Measured on the depth tracker's hop clip (hc+ep, noise seeds 0-4,
      mean marker error): 130.6 mm without this, 88.0 with it, 73.3 with it and the pelvis'
      translation and turn in two stages (the one-DOF-at-a-time chain: 77.5).

    With an odd ``grid`` each dim's middle value is the lane's current pose, which every call
    scores once (the last row of the lane), not once per dim.

    Parameters
    ----------
    cost_fn : callable, (M, D) float64 -> (M,) float
    X0 : (K, D) or (D,) float, start poses (lanes)
    stages : sequence of sequences of int, the dims of each stage, in search order
    steps : (D,) or (K, D) float, half-width of the coarsest grid per dimension (and lane)
    levels : int >= 1, grid refinements per stage
    grid : int >= 2, grid points per dim and level
    shrink : float in (0, 1), half-width factor from one level to the next
    lower, upper : (D,) float, optional, limits; candidates are clamped into them
    cost0 : (K,) float, optional, ``cost_fn(X0)`` when known
    coarse_fn : callable like ``cost_fn``, optional, a cheaper approximation of it (e.g. a
        coarser mesh in a smaller tile) that scores the levels of every stage before its last
        ``fine_levels``; those, and so the returned costs, are ``cost_fn``'s. Why: the coarse
        levels only have to bring each dim near its best value (their steps are 2.5-6x the
        last level's); the last level places it. Costs of the two functions are never
        compared: every call scores the lanes' centres, and a combined move still to be
        checked when the function changes is scored again by the new one (one more row)
    fine_levels : int >= 1, the last levels of each stage scored with ``cost_fn`` when
        ``coarse_fn`` is given

    Returns
    -------
    StageClimbResult. ``calls == len(stages) * levels`` plus one when a lane's last move was a
    combined one (it is scored once more to be checked).
    """
    X = np.atleast_2d(np.array(X0, dtype=np.float64))
    k, d = X.shape
    if not np.all(np.isfinite(X)):
        raise ValueError("X0 must be finite")
    if int(levels) < 1 or int(grid) < 2 or not 0 < shrink < 1:
        raise ValueError(f"need levels >= 1, grid >= 2, 0 < shrink < 1; got {levels}, {grid}, "
                         f"{shrink}")
    if int(fine_levels) < 1:
        raise ValueError(f"fine_levels must be >= 1, got {fine_levels}")
    n_coarse = max(int(levels) - int(fine_levels), 0) if coarse_fn is not None else 0
    steps = np.broadcast_to(np.asarray(steps, dtype=np.float64), (k, d))
    lo = np.full(d, -np.inf) if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.full(d, np.inf) if upper is None else np.asarray(upper, dtype=np.float64)
    X = np.clip(X, lo, hi)
    groups = []
    for s in stages:
        g = np.array([int(i) for i in np.atleast_1d(s)], dtype=int)
        if g.size == 0 or g.min() < 0 or g.max() >= d:
            raise ValueError(f"stage {s!r} is empty or outside 0..{d - 1}")
        groups.append(g)
    offsets = np.linspace(-1.0, 1.0, int(grid))
    cost = (np.full(k, np.nan) if cost0 is None
            else np.asarray(cost0, dtype=np.float64).reshape(k).copy())
    # a lane whose last move was combined: the best single move of that batch, to fall back to
    fallback_x = [None] * k
    fallback_c = np.full(k, np.nan)
    call = _CountedCost(cost_fn)
    coarse = _CountedCost(coarse_fn) if n_coarse else None
    scored_by = None  # the function of the last call: the costs held now are its

    def settle(lane, c_centre):
        """The centre's cost is known now: keep a combined move or fall back. True = kept."""
        if fallback_x[lane] is not None and c_centre > fallback_c[lane]:
            X[lane] = fallback_x[lane]
            cost[lane] = fallback_c[lane]
            fallback_x[lane] = None
            return False
        fallback_x[lane] = None
        cost[lane] = c_centre
        return True

    # With an odd grid the middle column of every dim is the centre itself, which the last row
    # of each lane scores once: only the other columns are candidates (a fifth fewer with 5)
    moves = np.flatnonzero(offsets != 0.0)
    centre = np.flatnonzero(offsets == 0.0)
    for g in groups:
        for level in range(int(levels)):
            fn = coarse if level < n_coarse else call
            # a combined move's fallback was scored by the other function: score it again
            again = ([lane for lane in range(k) if fallback_x[lane] is not None]
                     if scored_by is not None and fn is not scored_by else [])
            scored_by = fn
            blocks, vals_all = [], []
            for lane in range(k):
                h = steps[lane, g] * shrink ** level
                vals = np.clip(X[lane, g, None] + h[:, None] * offsets, lo[g, None], hi[g, None])
                cand = np.repeat(X[lane][None], g.size * moves.size + 1, axis=0)
                rows = np.arange(g.size * moves.size)
                cand[rows, np.repeat(g, moves.size)] = vals[:, moves].ravel()
                # the last row is the centre itself: its cost checks the lane's last move
                blocks.append(cand)
                vals_all.append(vals)
            c_all = fn(np.concatenate(blocks + [fallback_x[lane][None] for lane in again]))
            if again:
                fallback_c[again] = c_all[-len(again):]
                c_all = c_all[:-len(again)]
            c_all = c_all.reshape(k, -1)
            for lane in range(k):
                if not settle(lane, c_all[lane, -1]):
                    # this batch searched about a rejected pose; a candidate of it that beats
                    # the pose fallen back to is still a known, lower cost: take the best one
                    j = int(np.argmin(c_all[lane, :-1]))
                    if c_all[lane, j] < cost[lane]:
                        X[lane], cost[lane] = blocks[lane][j], c_all[lane, j]
                    continue
                c = np.empty((g.size, offsets.size))
                c[:, moves] = c_all[lane, :-1].reshape(g.size, moves.size)
                c[:, centre] = c_all[lane, -1]
                vals = vals_all[lane]
                tie = np.where(c == c.min(axis=1, keepdims=True), np.abs(offsets), np.inf)
                best = np.argmin(tie, axis=1)
                cb = c[np.arange(g.size), best]
                moved = np.nonzero(cb < cost[lane])[0]
                if moved.size == 0:
                    continue
                one = moved[np.argmin(cb[moved])]
                single = X[lane].copy()
                single[g[one]] = vals[one, best[one]]
                if moved.size == 1:
                    X[lane], cost[lane] = single, cb[one]
                    continue
                fallback_x[lane], fallback_c[lane] = single, cb[one]
                X[lane, g[moved]] = vals[moved, best[moved]]
                cost[lane] = np.nan  # the combined move has not been scored yet
    pending = [lane for lane in range(k) if fallback_x[lane] is not None or np.isnan(cost[lane])]
    if pending:  # the last level of every stage is a fine one, so these are cost_fn's
        c = call(X[pending])
        for lane, cl in zip(pending, c):
            settle(lane, cl)
    n_eval = call.evaluations + (coarse.evaluations if coarse else 0)
    n_call = call.calls + (coarse.calls if coarse else 0)
    return StageClimbResult(X, cost, n_eval, n_call)
