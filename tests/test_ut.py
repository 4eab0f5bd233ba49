"""Scaled unscented transform: exact on linear maps, close to Monte Carlo on a non-linear one."""
import numpy as np
import pytest

from gltrack.evidence.ut import MerweScaledSigmaPoints, cross_covariance, unscented_transform


def _random_gaussian(rng, n):
    x = rng.normal(size=n)
    A = rng.normal(size=(n, n))
    return x, A @ A.T + 0.1 * np.eye(n)


@pytest.mark.parametrize("n,alpha,beta,kappa", [(1, 1.0, 2.0, 2.0), (4, 0.5, 2.0, 0.0),
                                                (7, 1e-3, 2.0, 0.0), (15, 0.3, 2.0, 0.0)])
def test_weights_and_points_reproduce_the_gaussian(rng, n, alpha, beta, kappa):
    pts = MerweScaledSigmaPoints(n, alpha, beta, kappa)
    assert pts.Wm.shape == pts.Wc.shape == (2 * n + 1,)
    tol = 1e-12 if alpha >= 0.3 else 1e-9  # tiny alpha makes Wm[0] ~ -1/alpha^2
    assert pts.Wm.sum() == pytest.approx(1.0, abs=tol)
    assert pts.Wc.sum() == pytest.approx(2.0 - alpha ** 2 + beta, rel=1e-9)
    x, P = _random_gaussian(rng, n)
    S = pts.sigma_points(x, P)
    assert S.shape == (2 * n + 1, n)
    np.testing.assert_array_equal(S[0], x)
    # points are symmetric about the mean
    np.testing.assert_allclose(S[1:n + 1] + S[n + 1:], np.broadcast_to(2 * x, (n, n)), atol=1e-12)
    m, C = unscented_transform(S, pts.Wm, pts.Wc)
    np.testing.assert_allclose(m, x, atol=tol * 10)
    np.testing.assert_allclose(C, P, atol=tol * np.abs(P).max())


@pytest.mark.parametrize("alpha,tol", [(1.0, 1e-12), (0.5, 1e-12), (1e-3, 1e-9)])
def test_linear_map_is_exact(rng, alpha, tol):
    n, m = 5, 3
    x, P = _random_gaussian(rng, n)
    A = rng.normal(size=(m, n))
    b = rng.normal(size=m)
    Q = np.diag([0.1, 0.2, 0.3])
    pts = MerweScaledSigmaPoints(n, alpha=alpha, beta=2.0, kappa=3.0 - n)
    S = pts.sigma_points(x, P)
    Y = S @ A.T + b
    mean, cov = unscented_transform(Y, pts.Wm, pts.Wc, noise_cov=Q)
    ref_cov = A @ P @ A.T + Q
    np.testing.assert_allclose(mean, A @ x + b, rtol=0, atol=tol * 10 * np.abs(A @ x + b).max())
    np.testing.assert_allclose(cov, ref_cov, rtol=0, atol=tol * np.abs(ref_cov).max())
    Pxy = cross_covariance(S, x, Y, mean, pts.Wc)
    np.testing.assert_allclose(Pxy, P @ A.T, rtol=0, atol=tol * np.abs(P @ A.T).max())


def _polar(X):
    return np.stack([X[:, 0] * np.cos(X[:, 1]), X[:, 0] * np.sin(X[:, 1])], axis=1)


def test_polar_to_cartesian_matches_monte_carlo_and_closed_form():
    x = np.array([1.0, np.pi / 3])
    P = np.diag([0.05 ** 2, 0.3 ** 2])
    pts = MerweScaledSigmaPoints(2, alpha=1.0, beta=2.0, kappa=1.0)  # kappa = 3 - n
    mean, cov = unscented_transform(_polar(pts.sigma_points(x, P)), pts.Wm, pts.Wc)

    mc_rng = np.random.default_rng(2024)
    samples = mc_rng.multivariate_normal(x, P, size=100_000)
    Y = _polar(samples)
    mc_mean, mc_cov = Y.mean(0), np.cov(Y.T)
    # closed form: E[cos t] = cos(mu) exp(-s^2/2) for t ~ N(mu, s^2)
    e = np.exp(-P[1, 1] / 2)
    exact_mean = x[0] * e * np.array([np.cos(x[1]), np.sin(x[1])])
    # tolerance: MC standard error ~0.3/sqrt(1e5) ~ 1e-3 plus the UT's O(s^6) truncation
    np.testing.assert_allclose(mean, exact_mean, atol=2e-3)
    np.testing.assert_allclose(mean, mc_mean, atol=4e-3)
    np.testing.assert_allclose(cov, mc_cov, atol=4e-3, rtol=0.05)
    # a first-order (Jacobian) linearisation misses the shrinkage of the mean the UT captures
    lin_mean = _polar(x[None])[0]
    assert np.linalg.norm(lin_mean - mc_mean) > 5 * np.linalg.norm(mean - mc_mean)


def test_residual_hook_wraps_angles():
    def wrap(a, b):
        return (a - b + np.pi) % (2 * np.pi) - np.pi

    def circ_mean(S, W):
        return np.array([np.arctan2(W @ np.sin(S[:, 0]), W @ np.cos(S[:, 0]))])

    pts = MerweScaledSigmaPoints(1, alpha=1.0, beta=2.0, kappa=2.0)
    S = pts.sigma_points([np.pi - 0.05], [[0.1 ** 2]])
    S_wrapped = (S + np.pi) % (2 * np.pi) - np.pi  # the map wraps: points straddle +-pi
    assert S_wrapped.min() < 0 < S_wrapped.max()
    m, c = unscented_transform(S_wrapped, pts.Wm, pts.Wc, mean_fn=circ_mean, residual=wrap)
    assert abs(wrap(m, np.pi - 0.05)[0]) < 1e-9
    assert c[0, 0] == pytest.approx(0.1 ** 2, rel=1e-9)
    _, c_naive = unscented_transform(S_wrapped, pts.Wm, pts.Wc)
    assert c_naive[0, 0] > 100 * c[0, 0]


def test_singular_covariance_falls_back_to_eigen_root(rng):
    n = 4
    B = rng.normal(size=(n, 2))
    P = B @ B.T  # rank 2: Cholesky fails
    x = rng.normal(size=n)
    pts = MerweScaledSigmaPoints(n, alpha=0.7, kappa=0.0)
    m, C = unscented_transform(pts.sigma_points(x, P), pts.Wm, pts.Wc)
    np.testing.assert_allclose(m, x, atol=1e-12)
    np.testing.assert_allclose(C, P, atol=1e-12)
    with pytest.raises(ValueError, match="positive semi-definite"):
        pts.sigma_points(x, -np.eye(n))


def test_bad_shapes_raise():
    pts = MerweScaledSigmaPoints(3)
    with pytest.raises(ValueError, match="size 3"):
        pts.sigma_points(np.zeros(2), np.eye(2))
    with pytest.raises(ValueError, match="weights"):
        unscented_transform(np.zeros((5, 2)), pts.Wm, pts.Wc)
    with pytest.raises(ValueError, match="n \\+ lambda"):
        MerweScaledSigmaPoints(3, alpha=1.0, kappa=-3.0)
