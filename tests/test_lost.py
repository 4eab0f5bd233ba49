"""The runner's judgement of a lost track (gltrack.track.lost.LossWatch); pure Python."""
import numpy as np

from gltrack.track.lost import FLOOR, RATIO, LossWatch


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
