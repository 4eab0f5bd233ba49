"""Coarse-to-fine hill climbing (Ganapathi 2010) on numpy cost functions."""
import numpy as np
import pytest

from gltrack.body.dofs import make_dofs
from gltrack.body.skeleton import default_skeleton
from gltrack.sample import hill_climb, hill_climb_order
from gltrack.sample.hillclimb import hill_climb_lanes


def quadratic(center, scale):
    def cost(x):
        return np.sum(scale * (x - center) ** 2, axis=1)
    return cost


def reference_separable(x0, center, steps, levels, grid, shrink):
    """Independent per-dimension reimplementation: for a separable convex quadratic, each level
    picks the grid point nearest the minimum."""
    x = np.array(x0, dtype=float)
    for i in range(len(x)):
        for level in range(levels):
            g = x[i] + steps[i] * shrink ** level * np.linspace(-1, 1, grid)
            x[i] = g[np.argmin(np.abs(g - center[i]))]
    return x


def test_separable_quadratic_exact_to_grid_resolution():
    rng = np.random.default_rng(0)
    d, levels, grid, shrink = 12, 4, 5, 0.4
    center = rng.uniform(-0.5, 0.5, d)
    scale = rng.uniform(0.5, 5.0, d)
    steps = np.full(d, 0.6)
    x0 = np.zeros(d)
    res = hill_climb(quadratic(center, scale), x0, range(d), steps, levels=levels, grid=grid,
                     shrink=shrink)
    ref = reference_separable(x0, center, steps, levels, grid, shrink)
    assert res.x == pytest.approx(ref, abs=1e-12)
    spacing = 2 * steps * shrink ** (levels - 1) / (grid - 1)
    assert np.all(np.abs(res.x - center) <= spacing / 2 + 1e-12)
    assert res.cost == pytest.approx(quadratic(center, scale)(res.x[None])[0])
    # the grid's centre is the current pose: scored once, for the very first step only
    assert res.evaluations == levels * (grid - 1) * d + 1
    assert res.calls == levels * d


def test_counts_every_candidate_and_improves():
    calls = []
    center = np.array([0.3, -0.2, 0.1])

    def cost(x):
        calls.append(len(x))
        # coupled, non-separable: still a descent method
        d = x - center
        return np.sum(d ** 2, axis=1) + 0.5 * d[:, 0] * d[:, 1]

    x0 = np.zeros(3)
    res = hill_climb(cost, x0, [0, 1, 2], 0.5, levels=3, grid=7, passes=2)
    assert res.evaluations == sum(calls) == 2 * 3 * 6 * 3 + 1
    assert res.calls == len(calls)
    assert res.cost < cost(x0[None])[0]
    assert res.cost == pytest.approx(cost(res.x[None])[0])


def test_batch_independent_matches_sequential_on_separable_cost():
    rng = np.random.default_rng(1)
    d = 8
    center = rng.uniform(-0.4, 0.4, d)
    cost = quadratic(center, np.ones(d))
    order = [0, 1, (2, 4, 6), (3, 5, 7)]  # torso, then two "limb levels" of 3 limbs each
    seq = hill_climb(cost, np.zeros(d), order, 0.5, levels=3, grid=5)
    bat = hill_climb(cost, np.zeros(d), order, 0.5, levels=3, grid=5, batch_independent=True)
    assert bat.x == pytest.approx(seq.x, abs=1e-12)
    assert seq.calls == 3 * d
    assert bat.calls == 3 * 4 + 1  # one batch per level per group, plus the final scoring
    # after a combined move a group's centre is scored again (once, not once per dim)
    assert seq.evaluations <= bat.evaluations <= seq.evaluations + 2 * 3 + 1
    assert bat.cost == pytest.approx(seq.cost)


def test_limits_respected_and_ties_keep_position():
    cost = quadratic(np.array([2.0, 0.0]), np.ones(2))
    res = hill_climb(cost, [0.0, 0.0], [0, 1], 1.0, levels=5, lower=[-1.0, -1.0],
                     upper=[1.0, 1.0])
    assert res.x[0] == pytest.approx(1.0)  # the minimum is beyond the limit
    assert np.all(res.x >= -1) and np.all(res.x <= 1)
    flat = hill_climb(lambda x: np.zeros(len(x)), [0.2, -0.1], [0, 1], 1.0)
    assert flat.x == pytest.approx([0.2, -0.1])


def test_moves_change_with_start_and_steps():
    cost = quadratic(np.array([0.33, -0.71]), np.ones(2))
    a = hill_climb(cost, [0.0, 0.0], [0, 1], 1.0, levels=2)
    b = hill_climb(cost, [0.05, 0.05], [0, 1], 1.0, levels=2)
    c = hill_climb(cost, [0.0, 0.0], [0, 1], 0.3, levels=2)
    assert not np.allclose(a.x, b.x) and not np.allclose(a.x, c.x)


def test_hill_climb_order_for_body_covers_all_dofs():
    dofs = make_dofs(default_skeleton(), "full")
    order = hill_climb_order(dofs)
    flat = [i for e in order for i in np.atleast_1d(e)]
    assert sorted(flat) == list(range(dofs.size))
    assert order[:6] == [0, 1, 2, 3, 4, 5]  # the root first
    groups = [e for e in order if isinstance(e, tuple)]
    assert len(groups[0]) == 4
    assert {dofs.names[i][:2] for i in groups[0]} == {"l_", "r_"}
    seq = hill_climb_order(dofs, group_limbs=False)
    assert sorted(seq) == list(range(dofs.size)) and all(isinstance(i, int) for i in seq)


def test_bad_inputs_raise():
    cost = quadratic(np.zeros(2), np.ones(2))
    with pytest.raises(ValueError):
        hill_climb(cost, [0.0, 0.0], [0, 5], 1.0)
    with pytest.raises(ValueError):
        hill_climb(cost, [0.0, 0.0], [0, 1], 1.0, grid=1)
    with pytest.raises(ValueError):
        hill_climb(lambda x: np.zeros(3), [0.0, 0.0], [0, 1], 1.0)
    with pytest.raises(ValueError):
        hill_climb(cost, [np.nan, 0.0], [0, 1], 1.0)


# -- stage_climb: a whole stage level per call, several lanes per call ----------------------
from gltrack.sample.hillclimb import stage_climb  # noqa: E402


class Counting:
    def __init__(self, fn):
        self.fn, self.calls, self.rows = fn, 0, 0

    def __call__(self, X):
        self.calls += 1
        self.rows += len(X)
        return self.fn(X)


def test_stage_climb_separable_matches_dim_by_dim():
    """On a separable cost each dim's best grid value does not depend on the others, so the
    Jacobi stage step lands where the dim-by-dim reference does, in ``levels`` calls (+1 check)."""
    rng = np.random.default_rng(1)
    d, levels, grid, shrink = 10, 3, 5, 0.4
    center = rng.uniform(-0.5, 0.5, d)
    scale = rng.uniform(0.5, 5.0, d)
    steps = np.full(d, 0.6)
    x0 = np.zeros(d)
    cost = Counting(quadratic(center, scale))
    res = stage_climb(cost, x0, [range(d)], steps, levels=levels, grid=grid, shrink=shrink)
    assert res.X[0] == pytest.approx(reference_separable(x0, center, steps, levels, grid, shrink),
                                     abs=1e-12)
    assert res.calls == cost.calls <= levels + 1
    assert res.evaluations == cost.rows
    assert res.cost[0] == pytest.approx(quadratic(center, scale)(res.X)[0])


def test_stage_climb_lanes_share_calls_and_never_mix():
    rng = np.random.default_rng(2)
    d = 6
    center = rng.uniform(-0.3, 0.3, d)
    fn = quadratic(center, np.ones(d))
    X0 = rng.uniform(-0.5, 0.5, (4, d))
    stages = [[0, 1, 2], [3, 4, 5]]
    together = Counting(fn)
    res = stage_climb(together, X0, stages, 0.5, levels=3)
    for k in range(4):
        alone = stage_climb(fn, X0[k], stages, 0.5, levels=3)
        np.testing.assert_array_equal(res.X[k], alone.X[0])
        assert res.cost[k] == alone.cost[0]
    assert together.calls <= len(stages) * 3 + 1


def test_stage_climb_combined_overshoot_falls_back():
    """Coupled dims: each alone best at 1, together at 2 (cost 1 again): the combined move is
    checked and replaced by the best single move; the cost never rises above the start's."""
    def coupled(X):
        return (X[:, 0] + X[:, 1] - 1.0) ** 2

    res = stage_climb(coupled, np.zeros(2), [[0, 1]], 1.0, levels=1, grid=3)
    assert res.cost[0] == pytest.approx(0.0)
    assert res.X[0].sum() == pytest.approx(1.0)
    assert res.cost[0] == pytest.approx(coupled(res.X)[0])


def test_stage_climb_scores_every_pose_once_per_call():
    """With an odd grid each dim's middle value is the lane's centre, which the call scores
    once: no call holds the same pose twice, and a call has dims * (grid - 1) + 1 rows a lane."""
    seen = []

    def fn(X):
        seen.append(np.array(X))
        return np.sum((X - 0.2) ** 2, axis=1)

    X0 = np.array([[0.0, 0.0, 0.0], [0.5, -0.5, 0.1]])
    stage_climb(fn, X0, [[0, 1], [2]], 0.3, levels=2, grid=5)
    assert [len(c) for c in seen[:4]] == [2 * (2 * 4 + 1)] * 2 + [2 * (1 * 4 + 1)] * 2
    for c in seen:
        assert len(np.unique(c, axis=0)) == len(c)


def test_stage_climb_keeps_a_better_candidate_of_a_rejected_move():
    """A combined move that turns out worse falls back to the best single move, but a candidate
    scored around the rejected pose that beats that single move is kept (its cost is known)."""
    def fn(X):
        return (X[:, 0] + X[:, 1] - 1.0) ** 2 + 0.3 * (X[:, 0] - X[:, 1]) ** 2

    # level 0 moves both dims to 1 (each alone: 0.3), together (1, 1) costs 1: rejected, back
    # to (1, 0) at 0.3; level 1 scored (0.1, 1) at 0.253 around the rejected pose
    res = stage_climb(fn, np.zeros(2), [[0, 1]], 1.0, levels=2, grid=3, shrink=0.9)
    assert res.cost[0] < 0.3 - 1e-6
    assert res.cost[0] == pytest.approx(fn(res.X)[0])


def test_stage_climb_cost_never_rises_and_is_the_true_cost():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(5, 5))
    H = A @ A.T + 0.1 * np.eye(5)  # strongly coupled convex quadratic

    def fn(X):
        return np.einsum("ni,ij,nj->n", X - 0.3, H, X - 0.3)

    X0 = rng.uniform(-1, 1, (3, 5))
    res = stage_climb(fn, X0, [[0, 1], [2, 3, 4]], 0.5, levels=3, lower=np.full(5, -0.8),
                      upper=np.full(5, 0.8))
    assert np.all(res.cost <= fn(np.clip(X0, -0.8, 0.8)) + 1e-12)
    np.testing.assert_allclose(res.cost, fn(res.X), rtol=0, atol=1e-12)
    assert np.all(np.abs(res.X) <= 0.8)


def _coupled_quadratic(seed, d):
    A = np.random.default_rng(seed).normal(size=(d, d))
    H = A @ A.T + 0.1 * np.eye(d)  # coupled: combined moves overshoot and fall back

    def fn(X):
        return np.einsum("ni,ij,nj->n", X - 0.3, H, X - 0.3)

    return fn


def test_stage_climb_scores_its_early_levels_with_the_coarse_function():
    """``coarse_fn`` scores the levels of every stage before its last ``fine_levels``, ``cost_fn``
    the rest; the costs of the two are never compared, so a constant offset between them
    changes nothing, and the returned costs are ``cost_fn``'s."""
    fn = _coupled_quadratic(4, 6)
    X0 = np.random.default_rng(5).uniform(-1, 1, (4, 6))
    stages = [[0, 1, 2], [3, 4, 5]]
    ref = stage_climb(fn, X0, stages, 0.5, levels=3)
    fine, coarse = Counting(fn), Counting(lambda X: fn(X) + 10.0)
    res = stage_climb(fine, X0, stages, 0.5, levels=3, coarse_fn=coarse, fine_levels=1)
    np.testing.assert_array_equal(res.X, ref.X)
    np.testing.assert_array_equal(res.cost, ref.cost)
    assert coarse.calls == 2 * 2 and fine.calls in (2, 3)  # 2 stages x (2 coarse + 1 fine)
    assert res.calls == coarse.calls + fine.calls
    assert res.evaluations == coarse.rows + fine.rows
    # fine_levels covering every level: the coarse function is never called
    never = Counting(lambda X: fn(X) + 10.0)
    res2 = stage_climb(fn, X0, stages, 0.5, levels=3, coarse_fn=never, fine_levels=3)
    assert never.calls == 0
    np.testing.assert_array_equal(res2.X, ref.X)


def test_stage_climb_moves_where_the_coarse_function_leads():
    """A coarse function with its minimum elsewhere changes the search (it is really used),
    and the costs returned are still the true ones of the poses returned."""
    fn = _coupled_quadratic(6, 4)
    X0 = np.zeros((2, 4))
    X0[1] = 0.5
    ref = stage_climb(fn, X0, [[0, 1], [2, 3]], 0.6, levels=3)
    res = stage_climb(fn, X0, [[0, 1], [2, 3]], 0.6, levels=3,
                      coarse_fn=lambda X: fn(X - 0.4), fine_levels=1)
    assert not np.allclose(res.X, ref.X)
    np.testing.assert_allclose(res.cost, fn(res.X), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="fine_levels"):
        stage_climb(fn, X0, [[0, 1]], 0.6, coarse_fn=fn, fine_levels=0)


def test_stage_climb_validates():
    with pytest.raises(ValueError, match="stage"):
        stage_climb(lambda X: X[:, 0], np.zeros(3), [[0, 5]], 0.1)
    with pytest.raises(ValueError, match="finite"):
        stage_climb(lambda X: X[:, 0], np.array([np.nan, 0.0]), [[0]], 0.1)


def test_hill_climb_lanes_climb_each_start_as_alone_in_the_calls_of_one():
    """K lanes give exactly the K one-by-one climbs (coupled cost, limits, batched groups, a
    lane whose last move was combined), in the calls of one climb."""
    rng = np.random.default_rng(3)
    d, k = 6, 4
    center = rng.uniform(-0.4, 0.4, d)

    def coupled(X):
        e = X - center
        return np.sum(e ** 2, axis=1) + 0.6 * e[:, 0] * e[:, 1] + 0.3 * np.abs(e[:, 2] * e[:, 5])

    X0 = rng.uniform(-0.8, 0.8, (k, d))
    steps = rng.uniform(0.2, 0.6, (k, d))
    order = [0, 1, (2, 3), (4, 5)]
    lo, hi = np.full(d, -0.7), np.full(d, 0.7)
    sizes = []

    def counted(X):
        sizes.append(len(X))
        return coupled(X)

    res = hill_climb_lanes(counted, X0, order, steps, levels=3, grid=5, batch_independent=True,
                           lower=lo, upper=hi, passes=2)
    alone = [hill_climb(coupled, X0[i], order, steps[i], levels=3, grid=5,
                        batch_independent=True, lower=lo, upper=hi, passes=2) for i in range(k)]
    for i, a in enumerate(alone):
        np.testing.assert_array_equal(res.X[i], a.x)
        assert res.cost[i] == a.cost
    assert res.evaluations == sum(a.evaluations for a in alone) == sum(sizes)
    assert res.calls == alone[0].calls == len(sizes)
    # the first call holds every lane's grid and its not yet scored centre
    assert sizes[0] == k * 5
    # the lanes really differ: the starts matter
    assert np.ptp(res.cost) > 0


def test_hill_climb_lanes_validates():
    with pytest.raises(ValueError, match="start poses"):
        hill_climb_lanes(lambda X: X[:, 0], np.zeros(3), [0], 0.1)
    with pytest.raises(ValueError, match="one pose"):
        hill_climb(lambda X: X[:, 0], np.zeros((2, 3)), [0], 0.1)


def full_grid_climb(cost, x0, order, steps, levels, grid, shrink, lo, hi):
    """Independent reference: the plain coordinate search that scores every grid point, the
    centre included, one dim after the other (ties go to the value nearest the current one, a
    move must beat the current cost)."""
    x = np.clip(np.array(x0, dtype=float), lo, hi)
    off = np.linspace(-1, 1, grid)
    for i in order:
        for level in range(levels):
            vals = np.clip(x[i] + steps[i] * shrink ** level * off, lo[i], hi[i])
            cand = np.repeat(x[None], grid, axis=0)
            cand[:, i] = vals
            c = cost(cand)
            cur = cost(x[None])[0]
            best = min(range(grid), key=lambda j: (c[j], abs(off[j])))
            if c[best] < cur:
                x = cand[best]
    return x


@pytest.mark.parametrize("grid", [5, 4])
def test_skipping_known_centres_walks_the_full_grid_search(grid):
    """Not re-scoring the current pose changes nothing but the count: the same poses as the
    search that scores every grid point (coupled cost, limits, odd and even grids)."""
    rng = np.random.default_rng(7)
    d = 5
    center = rng.uniform(-0.5, 0.5, d)

    def coupled(X):
        e = X - center
        return np.sum(e ** 2, axis=1) + 0.7 * e[:, 0] * e[:, 3] + 0.2 * np.abs(e[:, 1] * e[:, 4])

    lo, hi = np.full(d, -0.6), np.full(d, 0.6)
    for trial in range(5):
        x0 = rng.uniform(-1, 1, d)
        steps = rng.uniform(0.1, 0.5, d)
        res = hill_climb(coupled, x0, range(d), steps, levels=3, grid=grid, lower=lo, upper=hi)
        ref = full_grid_climb(coupled, x0, range(d), steps, 3, grid, 0.4, lo, hi)
        np.testing.assert_array_equal(res.x, ref)
        per_level = grid - 1 if grid % 2 else grid
        assert res.evaluations == 3 * d * per_level + (grid % 2)
        # rescore_centre: the same poses, every grid point scored in every call
        full = hill_climb(coupled, x0, range(d), steps, levels=3, grid=grid, lower=lo, upper=hi,
                          rescore_centre=True)
        np.testing.assert_array_equal(full.x, ref)
        assert full.evaluations == 3 * d * grid


def test_hill_climb_lanes_active_dims_only():
    """A lane searches only its active dims (the others keep their start values), exactly as
    a climb over those dims alone; an all-true mask is no mask; no call is made for a group no
    lane searches."""
    rng = np.random.default_rng(4)
    d = 7
    center = rng.uniform(-0.4, 0.4, d)

    def coupled(X):
        e = X - center
        return np.sum(e ** 2, axis=1) + 0.5 * e[:, 0] * e[:, 2] + 0.4 * e[:, 3] * e[:, 5]

    order = [0, 1, (2, 3), (4, 5), 6]
    X0 = rng.uniform(-0.5, 0.5, (3, d))
    active = np.ones((3, d), dtype=bool)
    active[1, [2, 4, 5]] = False  # lane 1: a group partly, another wholly off
    active[2, :] = False
    active[2, [0, 3]] = True
    kw = dict(levels=3, grid=5, batch_independent=True)
    res = hill_climb_lanes(coupled, X0, order, 0.3, active=active, **kw)
    for lane in range(3):
        keep = [tuple(j for j in np.atleast_1d(g) if active[lane, j]) for g in order]
        keep = [g[0] if len(g) == 1 else g for g in keep if g]
        alone = hill_climb(coupled, X0[lane], keep, 0.3, **kw)
        np.testing.assert_array_equal(res.X[lane], alone.x)
        assert res.cost[lane] == pytest.approx(alone.cost)
        off = ~active[lane]
        np.testing.assert_array_equal(res.X[lane, off], X0[lane, off])
    full = hill_climb_lanes(coupled, X0, order, 0.3, active=np.ones((3, d), bool), **kw)
    free = hill_climb_lanes(coupled, X0, order, 0.3, **kw)
    np.testing.assert_array_equal(full.X, free.X)
    assert not np.array_equal(full.X, res.X)
    only = hill_climb_lanes(coupled, X0[:1], order, 0.3, active=np.eye(d, dtype=bool)[:1], **kw)
    assert only.calls == 3  # dim 0's three levels; every other group is skipped
