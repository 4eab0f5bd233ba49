"""The runner's judgement of a lost track (gltrack.track.lost.LossWatch); pure Python."""
import numpy as np

import pytest

from gltrack.track.lost import FLOOR, RATIO, SPREAD, LossWatch


def test_absolute_threshold_until_there_are_good_frames():
    w = LossWatch(0.45)
    assert w.limit() == 0.45
    assert [w.update(q) for q in (0.6, 0.7, 0.5)] == [1, 2, 3]  # a wrong start: no reference
    assert w.update(0.3) == 0 and w.limit() == min(0.45, max(RATIO * 0.3, FLOOR))


def test_relative_limit_catches_a_fall_from_a_good_fit():
    w = LossWatch(0.45)
    for q in (0.01, 0.012, 0.009):
        assert w.update(q) == 0
    assert w.limit() == FLOOR  # twice 0.01 is below the floor
    assert w.update(0.2) == 1 and w.update(0.21) == 2  # well under 0.45, far above the track's
    w.reset()
    assert w.limit() == 0.45 and w.bad == 0


def test_noise_around_a_mismatched_model_is_not_lost():
    w = LossWatch(0.45)
    rng = np.random.default_rng(0)
    assert max(w.update(q) for q in rng.uniform(0.25, 0.35, 50)) == 0


def test_absolute_only_and_never():
    w = LossWatch(2.0, relative=False)
    for q in (0.1, 0.1, 0.1):
        w.update(q)
    assert w.limit() == 2.0 and w.update(1.5) == 0 and w.update(2.5) == 1
    n = LossWatch(None)
    assert n.limit() is None and n.update(100.0) == 0
    assert LossWatch(0.45).update(float("nan")) == 0


def test_a_check_that_kept_the_track_moves_the_limit_to_its_level():
    """Masks that keep a good track near the absolute threshold: once a check has kept the
    track at quality ~0.47, frames within the spread of that level are no longer bad (no check
    every few frames for the same answer), frames clearly worse than it are; the level goes
    into the checkpoint state and a re-start forgets it."""
    w = LossWatch(0.45)
    for q in (0.33, 0.34, 0.35):
        w.update(q)
    assert [w.update(q) for q in (0.46, 0.47, 0.48)] == [1, 2, 3]
    w.reset()
    w.confirm([0.46, 0.47, float("nan"), None, 0.48])
    assert w.confirmed == pytest.approx(0.47)
    assert w.limit() == pytest.approx((1 + SPREAD) * 0.47)
    assert max(w.update(q) for q in (0.47, 0.5, 0.55, 0.48, 0.46)) == 0
    assert [w.update(q) for q in (0.6, 0.62, 0.65)] == [1, 2, 3]  # worse than the level again
    v = LossWatch(0.45)
    v.set_state(w.get_state())
    assert v.limit() == w.limit() and v.bad == 3
    v.set_state({"good": [0.3], "bad": 0})  # a checkpoint from before the level existed
    assert v.confirmed is None and v.limit() == 0.45
    w.confirm([None, float("nan")])  # nothing judged: the level stays
    assert w.confirmed == pytest.approx(0.47)
    w.reset()
    assert w.confirmed is None and w.limit() == 0.45
    lower = LossWatch(0.45)
    lower.confirm([0.2, 0.2])  # kept at a level under the threshold: the threshold stays
    assert lower.limit() == 0.45
    lost = LossWatch(0.45)
    lost.confirm([1.0, 1.0, 1.0])  # every hypothesis as bad: the track is still checked
    assert lost.limit() == RATIO * 0.45 and lost.update(1.0) == 1
