"""Connected foreground blobs for the automatic start (gltrack.observe.people)."""
import logging

import numpy as np

from gltrack.observe.people import person_blobs, pick_person


def _person(rng, centre, height=1.7, n=2000):
    """Points filling a vertical box of a person's size standing on y=0 at ``centre`` (x, z)."""
    p = rng.uniform([-0.2, 0.0, -0.12], [0.2, height, 0.12], size=(n, 3))
    return p + np.array([centre[0], 0.0, centre[1]])


def test_two_people_are_two_blobs_and_the_larger_is_picked(caplog):
    rng = np.random.default_rng(0)
    a, b = _person(rng, (0.0, 0.0)), _person(rng, (1.2, 0.5), height=1.6, n=1500)
    pts = np.concatenate([a, b])
    blobs = person_blobs(pts)
    assert len(blobs) == 2
    np.testing.assert_allclose(blobs[0].centroid, a.mean(0), atol=1e-9)
    with caplog.at_level(logging.WARNING, logger="gltrack.observe.people"):
        best = pick_person(pts, where="frame 3")
    np.testing.assert_allclose(best.centroid, a.mean(0), atol=1e-9)
    assert "frame 3: 2 person-sized blobs" in caplog.text
    # the mean of all points lies between the two, where nobody is
    assert np.linalg.norm(pts.mean(0) - best.centroid) > 0.4


def test_small_clutter_is_no_second_person(caplog):
    rng = np.random.default_rng(1)
    pts = np.concatenate([_person(rng, (0.0, 0.0)), rng.uniform(0, 0.2, (100, 3)) + [2, 0, 0]])
    with caplog.at_level(logging.WARNING, logger="gltrack.observe.people"):
        best = pick_person(pts)
    assert "person-sized" not in caplog.text and best.height() > 1.6
    np.testing.assert_array_equal(best.centroid, pts.mean(axis=0))  # clutter is not left out
    assert pick_person(np.zeros((0, 3))) is None


def test_weights_and_thinning():
    rng = np.random.default_rng(2)
    a = _person(rng, (0.0, 0.0), n=8000)  # thinned to every 2nd point
    b = _person(rng, (1.5, 0.0), n=1000)
    w = np.r_[np.full(len(a), 0.1), np.full(len(b), 10.0)]  # b weighs more
    best = person_blobs(np.concatenate([a, b]), w)[0]
    assert abs(best.centroid[0] - 1.5) < 0.05
