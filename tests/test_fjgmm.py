"""Figueiredo-Jain Gaussian mixture: model selection, accuracy, densities, invariants."""
import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from scipy.stats import multivariate_normal

from gltrack.motion.fjgmm import GaussianMixture, fit_fj_gmm, sqrtm_psd


def separated_means(rng, k, d, min_dist=8.0, box=12.0):
    """k random means in a box, pairwise at least min_dist apart (rejection sampling)."""
    out = []
    while len(out) < k:
        m = rng.uniform(-box, box, d)
        if all(np.linalg.norm(m - o) >= min_dist for o in out):
            out.append(m)
    return np.array(out)


def make_data(seed, k, d, n_per=250):
    rng = np.random.default_rng(seed)
    means = separated_means(rng, k, d)
    covs = []
    for _ in range(k):
        a = rng.normal(size=(d, d)) * 0.3
        covs.append(a @ a.T + 0.3 * np.eye(d))  # random anisotropic, std ~ 0.6..1.5
    X = np.concatenate([rng.multivariate_normal(m, c, n_per) for m, c in zip(means, covs)])
    labels = np.repeat(np.arange(k), n_per)
    return X, labels, means, np.array(covs)


@pytest.mark.parametrize("k,d", [(3, 2), (5, 2), (3, 10), (5, 10)])
def test_recovers_number_of_components_and_means(k, d):
    X, labels, means, covs = make_data(10 * k + d, k, d)
    gmm = fit_fj_gmm(X, np.random.default_rng(1), k_max=30)
    assert gmm.n_components == k
    dist = np.linalg.norm(gmm.means[:, None] - means[None], axis=2)
    r, c = linear_sum_assignment(dist)
    assert dist[r, c].max() < 0.6  # sampling error of a mean of 250 points: ~0.2 in 10-D
    # against the sample means of the generating groups the match is much tighter
    group = np.array([X[labels == j].mean(axis=0) for j in range(k)])
    assert np.linalg.norm(gmm.means[r] - group[c], axis=1).max() < 0.05
    np.testing.assert_allclose(gmm.weights[r], 1.0 / k, atol=0.03)
    # covariance of each recovered component close to its source
    for i, j in zip(r, c):
        assert np.linalg.norm(gmm.covs[i] - covs[j]) / np.linalg.norm(covs[j]) < 0.35
    # labels agree with the generating components up to the permutation
    perm = np.empty(k, dtype=int)
    perm[r] = c
    assert np.mean(perm[gmm.predict(X)] == labels) > 0.99


def test_cost_path_records_each_k_and_best_is_minimum():
    X, *_ = make_data(3, 3, 2)
    gmm = fit_fj_gmm(X, np.random.default_rng(0), k_max=20)
    ks, costs = gmm.cost_path[:, 0], gmm.cost_path[:, 1]
    assert ks[-1] == 1 and np.all(np.diff(ks) < 0)  # walked down to k_min, one entry per k
    assert ks[0] <= 20
    assert ks[np.argmin(costs)] == gmm.n_components == 3
    # the MML cost strictly prefers 3 over the neighbouring model sizes
    assert costs[ks == 2][0] > costs[ks == 3][0]


def test_never_more_than_k_max_and_k_min_respected():
    X, *_ = make_data(4, 5, 2)
    gmm = fit_fj_gmm(X, np.random.default_rng(0), k_max=3)
    assert gmm.n_components <= 3
    assert gmm.cost_path[0, 0] <= 3
    gmm = fit_fj_gmm(X, np.random.default_rng(0), k_max=12, k_min=4)
    assert gmm.n_components == 5
    assert gmm.cost_path[-1, 0] == 4  # the forced removals stop at k_min


def test_single_gaussian_gives_one_component():
    rng = np.random.default_rng(5)
    X = rng.multivariate_normal([1.0, -2.0, 0.5], np.diag([1.0, 0.2, 3.0]), 3000)
    gmm = fit_fj_gmm(X, np.random.default_rng(2), k_max=6)
    assert gmm.n_components == 1
    np.testing.assert_allclose(gmm.means[0], X.mean(axis=0), atol=1e-6)
    np.testing.assert_allclose(gmm.covs[0], np.cov(X.T, bias=True), rtol=1e-3, atol=1e-5)


def test_diagonal_covariance_option():
    X, labels, means, _ = make_data(7, 4, 6)
    gmm = fit_fj_gmm(X, np.random.default_rng(3), k_max=25, covariance="diag")
    off = gmm.covs - np.einsum("kii->ki", gmm.covs)[:, :, None] * np.eye(6)
    assert np.all(off == 0)
    assert gmm.n_components >= 4  # diagonal components may split a tilted cluster
    dist = np.linalg.norm(gmm.means[:, None] - means[None], axis=2)
    assert dist.min(axis=0).max() < 1.0  # every true cluster has a component near it


def test_degenerate_dimension_is_regularised():
    """A constant feature (a joint that never moves) must not break the fit."""
    X, *_ = make_data(8, 3, 2)
    X = np.concatenate([X, np.full((len(X), 1), 0.25)], axis=1)
    gmm = fit_fj_gmm(X, np.random.default_rng(0), k_max=15, reg=1e-6)
    assert gmm.n_components == 3
    assert np.all(np.isfinite(gmm.logpdf_components(X)))
    assert np.all(np.linalg.eigvalsh(gmm.covs) > 0)


def test_logpdf_matches_scipy_and_mixture_sampling():
    rng = np.random.default_rng(0)
    d = 4
    means = rng.normal(size=(3, d))
    covs = []
    for _ in range(3):
        a = rng.normal(size=(d, d))
        covs.append(a @ a.T + 0.1 * np.eye(d))
    covs.append(np.diag([0.5, 1.0, 2.0, 0.1]))  # exercises the diagonal fast path
    means = np.vstack([means, np.zeros(d)])
    gmm = GaussianMixture(np.array([0.1, 0.2, 0.3, 0.4]), means, np.array(covs))
    X = rng.normal(size=(50, d))
    ref = np.stack([multivariate_normal(m, c).logpdf(X) for m, c in zip(means, covs)], axis=1)
    np.testing.assert_allclose(gmm.logpdf_components(X), ref, rtol=1e-10, atol=1e-10)
    mix = np.log(np.exp(ref) @ gmm.weights)
    np.testing.assert_allclose(gmm.score_samples(X), mix, rtol=1e-10)
    np.testing.assert_allclose(np.exp(gmm.log_responsibilities(X)).sum(axis=1), 1.0)

    S, lab = gmm.sample(np.random.default_rng(1), 40000)
    np.testing.assert_allclose(np.bincount(lab) / len(lab), gmm.weights, atol=0.01)
    sel = S[lab == 2]
    np.testing.assert_allclose(np.cov(sel.T), covs[2], atol=0.15 * np.abs(covs[2]).max())


def test_sqrtm_psd():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(5, 5))
    c = a @ a.T
    r = sqrtm_psd(c)
    np.testing.assert_allclose(r, r.T, atol=1e-12)
    np.testing.assert_allclose(r @ r, c, atol=1e-10)


def test_seeded_and_seed_dependent():
    X, *_ = make_data(9, 3, 2)
    a = fit_fj_gmm(X, np.random.default_rng(4), k_max=20)
    b = fit_fj_gmm(X, np.random.default_rng(4), k_max=20)
    c = fit_fj_gmm(X, np.random.default_rng(5), k_max=20)
    np.testing.assert_array_equal(a.means, b.means)
    assert not np.array_equal(a.cost_path, c.cost_path)  # another seed, another path


def test_invalid_inputs():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError):
        fit_fj_gmm(np.zeros(10), rng)
    with pytest.raises(ValueError):
        fit_fj_gmm(np.array([[0.0, np.nan], [1.0, 2.0]]), rng)
    with pytest.raises(ValueError):
        fit_fj_gmm(np.zeros((10, 2)), rng, covariance="spherical")
    with pytest.raises(ValueError):
        GaussianMixture(np.array([0.5, 0.6]), np.zeros((2, 2)), np.stack([np.eye(2)] * 2))
    with pytest.raises(ValueError):
        GaussianMixture(np.array([1.0]), np.zeros((1, 2)), -np.eye(2)[None])
