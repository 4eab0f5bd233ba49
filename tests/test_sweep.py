"""The limb sweep (gltrack.sample.sweep): its grids and its choice, on plain weight functions."""
from types import SimpleNamespace

import numpy as np
import pytest

from gltrack.body.model import BodyModel
from gltrack.sample.sweep import LEGS, arm_grid, limb_grid, sweep_limbs



def assert_grids_span(d, grids, dofs, points):
    """Each grid moves its side's ``dofs`` (suffixes after ``l_`` / ``r_``), has ``swing**2 *
    flex`` distinct points for ``points = (swing, flex)`` and spans those DOFs' limits."""
    swing, flex = points
    for joint, idx, grid in grids:
        assert [d.names[i] for i in idx] == [f"{joint[0]}_{n}" for n in dofs]
        assert grid.shape == (swing * swing * flex, len(dofs))
        np.testing.assert_allclose(grid.min(axis=0), d.lower[idx])
        np.testing.assert_allclose(grid.max(axis=0), d.upper[idx])
        assert len(np.unique(grid, axis=0)) == len(grid)

@pytest.mark.parametrize("preset", ["full", "38", "25", "upper"])
def test_grids_span_each_arms_limits(preset):
    body = BodyModel.build(None, preset)
    d = body.dofs
    grids = arm_grid(d, swing=5, flex=3)
    assert [g[0] for g in grids] == ["l_shoulder", "r_shoulder"]
    assert_grids_span(d, grids, ("shoulder_ry", "shoulder_rz", "elbow_ry"), (5, 3))


def test_an_arm_without_its_elbow_is_swept_by_its_swing_only():
    names = ("pelvis_tx", "l_shoulder_ry", "l_shoulder_rz", "r_shoulder_rz")
    d = SimpleNamespace(names=names, lower=np.array([-1.0, -2.0, -1.0, -1.0]),
                        upper=np.array([1.0, 1.0, 2.0, 1.0]))
    grids = arm_grid(d, swing=4, flex=3)
    assert len(grids) == 1  # the right arm has one swing axis: nothing to sweep
    joint, idx, grid = grids[0]
    assert joint == "l_shoulder" and idx.tolist() == [1, 2] and grid.shape == (16, 2)
    assert arm_grid(d, swing=4, flex=0)[0][2].shape == (16, 2)


def test_sweep_moves_an_arm_to_the_best_grid_point_and_keeps_a_better_estimate():
    body = BodyModel.build()
    d = body.dofs
    grids = arm_grid(d, swing=6, flex=3)
    x = d.zero(body.skeleton).copy()
    x[d.index("r_shoulder_rz")] = 1.2  # hanging
    target = x.copy()
    _, idx, grid = grids[1]
    target[idx] = grid[40] + 0.05  # a raised arm near a grid point
    calls = []

    def weights(X):  # larger nearer the target's right arm
        calls.append(len(X))
        moved = set(np.flatnonzero(np.ptp(X, axis=0) > 0).tolist())
        assert moved == set(grids[len(calls) - 1][1].tolist())  # one arm at a time, only it
        return -np.linalg.norm(X[:, idx] - target[idx], axis=1)

    res = sweep_limbs(x, weights, grids)
    np.testing.assert_allclose(res.estimate[idx], grid[40])
    np.testing.assert_allclose(res.delta, res.estimate - x)
    assert res.improved == ("r_shoulder",)
    assert calls == [len(g[2]) + 1 for g in grids] and res.evaluations == sum(calls)
    # a grid point that wins by less than the margin leaves the estimate as it is
    gain = np.linalg.norm(x[idx] - target[idx]) - np.linalg.norm(grid[40] - target[idx])
    calls.clear()
    assert sweep_limbs(x, weights, grids, margin=gain + 1e-9).improved == ()
    calls.clear()
    assert sweep_limbs(x, weights, grids, margin=gain - 1e-3).improved == ("r_shoulder",)
    # an estimate that already weighs most stays as it is
    res = sweep_limbs(target, lambda X: -np.linalg.norm(X - target, axis=1), grids)
    np.testing.assert_array_equal(res.estimate, target)
    assert res.improved == () and not res.delta.any()


@pytest.mark.parametrize("preset", ["full", "38"])
def test_limb_grids_add_each_legs_hip_swing_and_knee(preset):
    """The limb grid holds both arms (as :func:`arm_grid`) and both legs: hip flexion and
    abduction, knee flexion, spanning their limits."""
    d = BodyModel.build(None, preset).dofs
    grids = limb_grid(d, swing=4, flex=3)
    assert [g[0] for g in grids] == ["l_shoulder", "r_shoulder", "l_hip", "r_hip"]
    for (ja, ia, ga), (jb, ib, gb) in zip(grids[:2], arm_grid(d, swing=4, flex=3)):
        assert ja == jb and ia.tolist() == ib.tolist()
        np.testing.assert_array_equal(ga, gb)
    assert_grids_span(d, grids[2:], ("hip_rx", "hip_rz", "knee_rx"), (4, 3))
    assert [g[0] for g in limb_grid(d, 4, 3, LEGS)] == ["l_hip", "r_hip"]
