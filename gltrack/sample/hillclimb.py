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
               passes: int = 1) -> HillClimbResult:
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

    Returns
    -------
    HillClimbResult. ``evaluations == passes * levels * grid * (number of dims)`` plus one when
    the last step was a batched group (its combined pose is scored once to report its cost).
    """
    x = np.array(x0, dtype=np.float64).ravel()
    d = x.size
    if not np.all(np.isfinite(x)):
        raise ValueError("x0 must be finite")
    if int(levels) < 1 or int(grid) < 2 or not 0 < shrink < 1 or int(passes) < 1:
        raise ValueError(f"need levels >= 1, grid >= 2, 0 < shrink < 1, passes >= 1; got "
                         f"{levels}, {grid}, {shrink}, {passes}")
    steps = np.broadcast_to(np.asarray(steps, dtype=np.float64), (d,))
    lo = np.full(d, -np.inf) if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.full(d, np.inf) if upper is None else np.asarray(upper, dtype=np.float64)
    x = np.clip(x, lo, hi)
    offsets = np.linspace(-1.0, 1.0, int(grid))
    groups = _groups(dims_order, batch_independent, d)
    evals = calls = 0
    cost = None  # cost of the current x, when known

    def call(cand):
        nonlocal evals, calls
        c = np.asarray(cost_fn(cand), dtype=np.float64).ravel()
        if c.shape != (cand.shape[0],) or np.any(np.isnan(c)):
            raise ValueError(f"cost_fn must return ({cand.shape[0]},) non-NaN costs, "
                             f"got shape {c.shape}")
        evals += cand.shape[0]
        calls += 1
        return c

    for _ in range(int(passes)):
        for g in groups:
            gi = np.array(g)
            for level in range(int(levels)):
                h = steps[gi] * shrink ** level
                vals = np.clip(x[gi, None] + h[:, None] * offsets, lo[gi, None], hi[gi, None])
                cand = np.repeat(x[None], gi.size * offsets.size, axis=0)
                rows = np.arange(cand.shape[0])
                cand[rows, np.repeat(gi, offsets.size)] = vals.ravel()
                c = call(cand).reshape(gi.size, offsets.size)
                # among equal costs take the candidate nearest the current value
                tie = np.where(c == c.min(axis=1, keepdims=True), np.abs(offsets), np.inf)
                best = np.argmin(tie, axis=1)
                # a move must beat the current cost (when known), so a flat or noisy cost
                # does not make the pose drift
                for k, i in enumerate(gi):
                    if cost is None or c[k, best[k]] < cost:
                        x[i] = vals[k, best[k]]
                if gi.size == 1:
                    cost = float(c[0, best[0]]) if cost is None else min(cost, float(c[0, best[0]]))
                else:
                    cost = None  # the combined move was never scored as a whole
    if cost is None:
        cost = float(call(x[None])[0])
    return HillClimbResult(x, cost, evals, calls)
