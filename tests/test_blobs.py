"""Gaussian blobs of the body model, EM fit to voxels, and the KL evaluation."""
import numpy as np
import pytest

from gltrack.bench.rigs import ring_cameras
from gltrack.bench.vlmm import render_masks
from gltrack.body.mesh import BodyMesh
from gltrack.body.model import BodyModel
from gltrack.observe.blobs import (BlobModel, Blobs, PartColours, fit_blobs, fit_blobs_from,
                                   gaussian_kl, kl_translation, mixture_kl, mixture_loglik)
from gltrack.observe.voxels import carve


@pytest.fixture(scope="module")
def body():
    return BodyModel.build(preset="25", lod=0)


def _pose(body):
    d = body.dofs
    x = d.zero(body.skeleton)
    x[d.index("l_shoulder_rz")] = -1.0
    x[d.index("r_elbow_ry")] = 1.2
    x[d.index("l_hip_rx")] = -0.5
    x[d.index("l_knee_rx")] = 0.6
    return x


def _random_spd(rng, n):
    A = rng.normal(size=(n, 3, 3))
    return A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)


def test_gaussian_kl_matches_monte_carlo(rng):
    mf, mg = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    Sf, Sg = _random_spd(rng, 3), _random_spd(rng, 3)
    kl = gaussian_kl(mf, Sf, mg, Sg)
    for i in range(3):
        x = rng.multivariate_normal(mf[i], Sf[i], size=200_000)

        def logpdf(x, m, S):
            d = x - m
            return -0.5 * (np.sum(d @ np.linalg.inv(S) * d, 1) + np.log(np.linalg.det(S))
                           + 3 * np.log(2 * np.pi))

        mc = np.mean(logpdf(x, mf[i], Sf[i]) - logpdf(x, mg[i], Sg[i]))
        assert abs(mc - kl[i]) < 0.02 * kl[i] + 0.01, (mc, kl[i])
    assert np.allclose(gaussian_kl(mf, Sf, mf, Sf), 0, atol=1e-9)
    assert not np.allclose(kl, gaussian_kl(mg, Sg, mf, Sf))  # not symmetric


def test_model_blobs_match_a_dense_solid_sample(body):
    """Solid-volume moments from the surface formula agree with the moments of an explicit
    interior sample (anchor + s (v - anchor), s on a fine grid with density 2 s)."""
    bm = BlobModel(body.mesh, body.skeleton)
    S = body.skinning(_pose(body)[None])
    b = bm.blobs(S)[0]
    # the vertices and their anchors posed by the mesh's own skinning, vertex by vertex
    m = body.mesh
    X = np.concatenate([m.skin(S)[0], BodyMesh(bm._anchor, m.faces, m.joints, m.weights,
                                               m.part).skin(S)[0]])
    V = body.mesh.n_vertices
    s = (np.arange(200) + 0.5) / 200
    ws = 2 * s / np.sum(2 * s)
    for p in range(bm.n_blobs):
        w = bm._part_w[p]
        pts = X[V:, None, :] + s[None, :, None] * (X[:V] - X[V:])[:, None, :]
        ww = (w[:, None] * ws[None, :]).ravel()
        pts = pts.reshape(-1, 3)
        m = ww @ pts
        C = ((pts - m) * ww[:, None]).T @ (pts - m)
        assert np.allclose(b.means[p], m, atol=1e-9)
        assert np.allclose(b.covs[p], C, atol=1e-6)
    # the solid blob of a limb is thinner than its skin
    surf = BlobModel(body.mesh, body.skeleton, interior=False).blobs(S)[0]
    arm = bm.parts.index("l_upper_arm")
    assert np.linalg.eigvalsh(b.covs[arm])[0] < 0.7 * np.linalg.eigvalsh(surf.covs[arm])[0]


def test_blobs_follow_the_pose(body, rng):
    bm = BlobModel(body.mesh, body.skeleton)
    x = _pose(body)
    moved = x.copy()
    moved[:3] += [0.3, 0.0, -0.2]
    a, b = bm.blobs(body.skinning(np.stack([x, moved])))
    assert np.allclose(b.means - a.means, [0.3, 0.0, -0.2])
    assert np.allclose(a.covs, b.covs)
    assert np.isclose(bm.weights.sum(), 1) and bm.n_blobs == 15
    # a raised arm moves only the arm blobs (and barely the torso)
    up = x.copy()
    up[body.dofs.index("r_shoulder_rz")] = 1.2
    c = bm.blobs(body.skinning(up[None]))[0]
    moved_parts = {bm.parts[i] for i in np.nonzero(np.linalg.norm(c.means - a.means, axis=1) > 0.02)[0]}
    assert moved_parts == {"r_upper_arm", "r_forearm", "r_hand"}


def test_kl_zero_for_identical_and_grows_with_perturbation(body):
    bm = BlobModel(body.mesh, body.skeleton)
    x = _pose(body)
    ref = bm.blobs(body.skinning(x[None]))[0]
    assert np.isclose(mixture_kl(bm.blobs(body.skinning(x[None])), ref)[0], 0, atol=1e-9)
    sig = body.dofs.sigma_at(30.0)
    rng = np.random.default_rng(1)
    z = rng.standard_normal((50, body.dofs.size))
    means = [mixture_kl(bm.blobs(body.skinning(x + s * z * sig)), ref).mean()
             for s in (0.5, 1, 2, 4)]
    assert np.all(np.diff(means) > 0) and means[0] > 0


def test_kl_translation_is_the_numerical_minimum(body):
    """The closed-form root translation against a numerical minimiser of eq. 9 (scipy's BFGS
    on the KL of the shifted blobs), for posed bodies against evidence from other poses."""
    from scipy.optimize import minimize
    bm = BlobModel(body.mesh, body.skeleton)
    rng = np.random.default_rng(3)
    x = _pose(body)
    sig = body.dofs.sigma_at(30.0)
    P = x + 3 * sig * rng.standard_normal((4, body.dofs.size))
    model = bm.blobs(body.skinning(P))
    obs = bm.blobs(body.skinning((x + 3 * sig * rng.standard_normal(body.dofs.size))[None]))[0]
    obs = Blobs(obs.means + np.array([0.12, -0.05, 0.3]), obs.covs, obs.weights)
    t = kl_translation(model, obs)
    assert t.shape == (4, 3)
    for i in range(4):
        def kl(s, i=i):
            return mixture_kl(Blobs(model.means[i] + s, model.covs[i], model.weights[i])[None],
                              obs)[0]
        best = minimize(kl, np.zeros(3), method="BFGS", options={"gtol": 1e-10})
        assert np.allclose(t[i], best.x, atol=1e-5), (t[i], best.x)
        assert kl(t[i]) <= kl(np.zeros(3)) and kl(t[i]) < kl(t[i] + 0.01)
    # the evidence moved by v: every candidate's translation moves by v
    v = np.array([-0.2, 0.1, 0.05])
    moved = Blobs(obs.means + v, obs.covs, obs.weights)
    assert np.allclose(kl_translation(model, moved), t + v, atol=1e-12)


def test_fit_to_voxels_of_the_rendered_body(body):
    """Voxels carved from four rendered silhouettes: the EM fit started from a perturbed pose
    moves towards the true blobs, and KL ranks the true pose above perturbed ones."""
    bm = BlobModel(body.mesh, body.skeleton)
    x = _pose(body)
    x[body.dofs.index("l_shoulder_rz")] = -0.4  # arm clear of the torso in every view
    cams = ring_cameras((0.0, 0.9, 0.0), width=160, height_px=120)
    masks = render_masks(body, x[None], cams)[0]
    vox = carve(cams, masks, (-1.2, -0.1, -1.2, 1.2, 2.0, 1.2), base=12, max_depth=3)
    pts, vol = vox.points(max_size=0.04)
    true = bm.blobs(body.skinning(x[None]))[0]
    off = x.copy()
    off[:3] += [0.05, 0.0, 0.04]
    off[body.dofs.index("l_shoulder_rz")] += 0.15
    init = bm.blobs(body.skinning(off[None]))[0]
    fitted, ll = fit_blobs(pts, init, point_weights=vol, iterations=6)
    assert ll > mixture_loglik(pts, init, point_weights=vol)
    # the visual hull of four views is not the body, so compare with the fit started from
    # the true pose: EM from the perturbed pose converges most of the way to it
    ref, ll_ref = fit_blobs(pts, true, point_weights=vol, iterations=6)
    err_init = np.linalg.norm(init.means - ref.means, axis=1)
    err_fit = np.linalg.norm(fitted.means - ref.means, axis=1)
    assert np.median(err_fit) < 0.5 * np.median(err_init), (err_fit, err_init)
    rng = np.random.default_rng(2)
    sig = body.dofs.sigma_at(30.0)
    cand = np.concatenate([x[None], x + 2 * rng.standard_normal((30, body.dofs.size)) * sig])
    kl = mixture_kl(bm.blobs(body.skinning(cand)), fitted)
    assert kl[0] < np.percentile(kl[1:], 10)
    hard, _ = fit_blobs(pts, init, point_weights=vol, iterations=6, hard=True)
    assert np.median(np.linalg.norm(hard.means - ref.means, axis=1)) < np.median(err_init)


def test_fit_input_checks(body):
    b = Blobs(np.zeros((2, 3)), np.stack([np.eye(3)] * 2), np.array([0.5, 0.5]))
    with pytest.raises(ValueError, match="points"):
        fit_blobs(np.zeros((0, 3)), b)
    with pytest.raises(ValueError, match="point_weights"):
        fit_blobs(np.zeros((4, 3)), b, point_weights=-np.ones(4))
    with pytest.raises(ValueError, match="blobs"):
        mixture_kl(b, Blobs(np.zeros((3, 3)), np.stack([np.eye(3)] * 3), np.ones(3) / 3))


def _em_direct(X, init, w, iterations, hard, colours=None, part_colour=None, reg=1e-4,
               min_support=1e-3):
    """The EM of fit_blobs written the direct way: scipy's densities of every point under
    every blob, explicit weighted sums about each new mean; one start (an independent twin of
    the feature-moment version)."""
    from scipy.special import logsumexp
    from scipy.stats import multivariate_normal

    mean, cov = init.means.copy(), init.covs + np.eye(3) * reg
    pi = init.weights / init.weights.sum()
    w = w / w.sum()
    col = 0.0 if colours is None else np.stack(
        [multivariate_normal(m, c).logpdf(colours) for m, c in
         zip(part_colour.means, part_colour.covs)], axis=1)
    for it in range(iterations + 1):
        lp = np.stack([multivariate_normal(m, c).logpdf(X) for m, c in zip(mean, cov)],
                      axis=1) + np.log(pi) + col
        norm = logsumexp(lp, axis=1)
        ll = float(w @ norm)
        if it == iterations:
            return Blobs(mean, cov, pi), ll
        r = np.exp(lp - norm[:, None])
        if hard:
            r = (np.arange(len(pi))[None] == np.argmax(lp, axis=1)[:, None]).astype(float)
        for p in range(len(pi)):
            rw = r[:, p] * w
            nk = rw.sum()
            if nk > min_support:
                m = rw @ X / nk
                d = X - m
                mean[p], cov[p] = m, (d * rw[:, None]).T @ d / nk + np.eye(3) * reg
        nk = (r * w[:, None]).sum(axis=0)
        pi = np.where(nk > min_support, nk, min_support)
        pi = pi / pi.sum()


@pytest.mark.parametrize("hard", [False, True])
@pytest.mark.parametrize("colour", [False, True])
def test_batched_fit_is_the_direct_em(hard, colour):
    """fit_blobs_from (all starts at once, the EM steps through ten point features) against
    the direct EM of each start on its own, on room coordinates far from the origin; a changed
    start changes its fit and no other."""
    rng = np.random.default_rng(7)
    M, P, K = 600, 6, 3
    X = rng.normal(0.0, 0.3, (M, 3)) + [2.5, 0.9, -1.8]
    w = rng.uniform(0.5, 1.5, M)
    means = X[rng.choice(M, (K, P))] + rng.normal(0.0, 0.05, (K, P, 3))
    covs = _random_spd(rng, K * P).reshape(K, P, 3, 3) * 0.01
    weights = rng.dirichlet(np.ones(P), K)
    kw = {}
    if colour:
        kw = {"colours": rng.normal(0.0, 30.0, (M, 3)),
              "part_colour": PartColours(rng.normal(0.0, 30.0, (P, 3)),
                                         np.repeat(np.eye(3)[None] * 900.0, P, 0))}
    got, ll = fit_blobs_from(X, Blobs(means, covs, weights), point_weights=w, iterations=4,
                             hard=hard, **kw)
    for k in range(K):
        ref, ll_ref = _em_direct(X, Blobs(means[k], covs[k], weights[k]), w, 4, hard, **kw)
        np.testing.assert_allclose(got.means[k], ref.means, atol=1e-10)
        np.testing.assert_allclose(got.covs[k], ref.covs, atol=1e-10)
        np.testing.assert_allclose(got.weights[k], ref.weights, atol=1e-10)
        assert ll[k] == pytest.approx(ll_ref, abs=1e-9)
        one, ll_one = fit_blobs(X, Blobs(means[k], covs[k], weights[k]), point_weights=w,
                                iterations=4, hard=hard, **kw)
        np.testing.assert_allclose(one.means, got.means[k], atol=1e-12)
        assert ll_one == pytest.approx(ll[k], abs=1e-12)
    moved = means.copy()
    moved[1] += 0.2
    again, ll2 = fit_blobs_from(X, Blobs(moved, covs, weights), point_weights=w, iterations=4,
                                hard=hard, **kw)
    assert np.abs(again.means[1] - got.means[1]).max() > 1e-3
    np.testing.assert_array_equal(again.means[[0, 2]], got.means[[0, 2]])
    with pytest.raises(ValueError, match="batch"):
        fit_blobs_from(X, Blobs(means[0], covs[0], weights[0]))


def test_colour_keeps_blobs_on_their_own_parts():
    """Two parts side by side, blobs started swapped: by shape alone EM keeps the swap; with
    the acquired part colours each blob moves to the points of its own colour."""
    from gltrack.observe.blobs import Blobs, PartColours, bgr_to_yuv, fit_blobs, part_colours

    rng = np.random.default_rng(3)
    a = rng.normal([0.0, 0.0, 0.0], 0.05, (400, 3))
    b = rng.normal([0.3, 0.0, 0.0], 0.05, (400, 3))
    pts = np.concatenate([a, b])
    red, blue = bgr_to_yuv([30, 40, 200]), bgr_to_yuv([200, 60, 20])
    col = np.concatenate([np.repeat(red[None], 400, 0), np.repeat(blue[None], 400, 0)])
    col += rng.normal(0, 4, col.shape)
    cov = np.repeat((np.eye(3) * 0.05 ** 2)[None], 2, 0)
    truth = Blobs(np.array([[0.0, 0, 0], [0.3, 0, 0]]), cov, np.array([0.5, 0.5]))
    colours = part_colours(pts, col, truth)
    assert np.allclose(colours.means, [red, blue], atol=2.0)
    assert isinstance(colours, PartColours) and np.all(np.linalg.eigvalsh(colours.covs) > 0)
    swapped = Blobs(np.array([[0.22, 0, 0], [0.08, 0, 0]]), cov, np.array([0.5, 0.5]))
    shape_only, _ = fit_blobs(pts, swapped, iterations=10)
    coloured, _ = fit_blobs(pts, swapped, iterations=10, colours=col, part_colour=colours)
    assert shape_only.means[0, 0] > 0.2 and shape_only.means[1, 0] < 0.1
    assert abs(coloured.means[0, 0]) < 0.02 and abs(coloured.means[1, 0] - 0.3) < 0.02


def test_log_gauss_and_logsumexp_match_scipy():
    """The written-out 3-D quadratic form, the general path and the lean logsumexp agree
    with scipy on random Gaussians (and an all -inf row stays -inf)."""
    from scipy.special import logsumexp as lse_ref
    from scipy.stats import multivariate_normal

    from gltrack.observe.blobs import _log_gauss, logsumexp

    rng = np.random.default_rng(3)
    for d in (3, 2):
        X = rng.normal(size=(50, d))
        mean = rng.normal(size=(4, d))
        A = rng.normal(size=(4, d, d))
        cov = A @ np.transpose(A, (0, 2, 1)) + 0.1 * np.eye(d)
        ref = np.stack([multivariate_normal(mean[p], cov[p]).logpdf(X) for p in range(4)], 1)
        np.testing.assert_allclose(_log_gauss(X, mean, cov), ref, rtol=1e-10, atol=1e-10)
        moved = _log_gauss(X, mean + 0.5, cov)
        assert np.all(np.abs(moved - ref).max(axis=0) > 1e-3)
    a = rng.normal(size=(6, 5)) * 30
    a[2] = -np.inf
    for axis, keep in ((1, False), (0, True), (1, True)):
        np.testing.assert_allclose(logsumexp(a, axis=axis, keepdims=keep),
                                   lse_ref(a, axis=axis, keepdims=keep))


def test_mixture_loglik_is_the_direct_sum(body):
    """mixture_loglik against a direct twin (scipy's Gaussian densities, one mixture at a
    time), on voxels far from the origin (the room's coordinates)."""
    from scipy.special import logsumexp as sp_logsumexp
    from scipy.stats import multivariate_normal

    bm = BlobModel(body.mesh, body.skeleton)
    rng = np.random.default_rng(4)
    X = np.repeat(_pose(body)[None], 6, axis=0)
    X[:, :3] += [3.0, 0.0, -2.0]
    X += rng.normal(0.0, 0.1, X.shape) * body.dofs.sigma_at(30.0) * 10
    B = bm.blobs(body.skinning(X))
    pts = B.means[0, rng.integers(0, B.n_blobs, 400)] + rng.normal(0.0, 0.05, (400, 3))
    vol = rng.uniform(0.5, 2.0, 400)
    want = []
    for n in range(len(X)):
        lp = np.stack([multivariate_normal(B.means[n, k], B.covs[n, k]).logpdf(pts)
                       + np.log(B.weights[n, k]) for k in range(B.n_blobs)], axis=1)
        want.append(np.sum(vol / vol.sum() * sp_logsumexp(lp, axis=1)))
    got = mixture_loglik(pts, B, point_weights=vol)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    assert np.ptp(got) > 1.0  # the poses differ, and so do their likelihoods
    # float32 sums (the ranking's): the same to 1e-5 nats, the same order
    fast = mixture_loglik(pts, B, point_weights=vol, dtype=np.float32)
    np.testing.assert_allclose(fast, want, rtol=0, atol=1e-5)
    assert np.array_equal(np.argsort(fast), np.argsort(got))
    assert np.allclose(mixture_loglik(pts, B, point_weights=vol, chunk=1), got, rtol=1e-12)
    one = Blobs(B.means[2], B.covs[2], B.weights[2])
    assert np.shape(mixture_loglik(pts, one, point_weights=vol)) == ()
    assert mixture_loglik(pts, one, point_weights=vol) == pytest.approx(got[2], rel=1e-12)
