"""VLMM learning and entropy, motion features, and the behaviour model (clusters + VLMM)."""
import json
import os
from pathlib import Path

import numpy as np
import pytest

from gltrack.motion import features as feat
from gltrack.motion.behaviour import BehaviourModel
from gltrack.motion.vlmm import Vlmm


def _shared():
    env = os.environ.get("GLTRACK_SHARED")
    for cand in ([Path(env)] if env else []) + [Path(__file__).resolve().parents[2] / "shared"]:
        if cand.is_dir():
            return cand
    pytest.skip("../shared (or GLTRACK_SHARED) is absent: mocap test skipped")


# ---------------------------------------------------------------- Markov sources
def generate(table, n, rng, order):
    """Sample n symbols from an order-`order` source: table[history tuple] -> (K,) probs."""
    k = next(iter(table.values())).size
    s = list(rng.integers(0, k, order))
    u = rng.random(n)
    for i in range(n - order):
        p = table[tuple(s[len(s) - order:])]
        s.append(min(int(np.searchsorted(np.cumsum(p), u[i], side="right")), k - 1))
    return np.array(s, dtype=np.int64)


def entropy_rate(table, order, k, base=2.0):
    """Exact entropy rate of a Markov source via the stationary law of its histories."""
    hist = list(table)
    idx = {h: i for i, h in enumerate(hist)}
    T = np.zeros((len(hist), len(hist)))
    for h in hist:
        for c in range(k):
            T[idx[h], idx[h[1:] + (c,)]] += table[h][c]
    w, v = np.linalg.eig(T.T)
    pi = np.real(v[:, np.argmin(np.abs(w - 1))])
    pi /= pi.sum()
    return -sum(pi[idx[h]] * np.sum(table[h] * np.log(table[h])) for h in hist) / np.log(base)


def order2_table(rng, k=3):
    return {(a, b): rng.dirichlet(np.full(k, 0.7)) for a in range(k) for b in range(k)}


@pytest.fixture(scope="module")
def order2():
    rng = np.random.default_rng(0)
    table = order2_table(rng)
    train = generate(table, 20000, np.random.default_rng(1), 2)
    test = generate(table, 20000, np.random.default_rng(2), 2)
    return table, train, test, Vlmm.fit([train], 3, max_memory=6, epsilon=1e-3)


def test_learns_order2_source(order2):
    table, train, test, v = order2
    for (a, b), p in table.items():
        q = v.initial_state([a, b])
        np.testing.assert_allclose(v.next_distribution(q), p, atol=0.04)
    assert v.depth.max() == 2  # memory 6 allowed, only 2 needed


def test_entropy_near_source_rate(order2):
    table, train, test, v = order2
    h = entropy_rate(table, 2, 3)
    h_train, h_test = v.entropy([train]), v.entropy([test])
    assert abs(h_test - h) < 0.03
    assert h_train <= h_test + 0.01  # no better on unseen data than on training data
    # a model with no memory is measurably worse than the learnt one
    v0 = Vlmm.fit([train], 3, max_memory=0)
    assert v0.n_states == 1
    assert v0.entropy([test]) > h_test + 0.05
    # the per-symbol entropy is the mean of -log2 P(k_i | q_i) computed independently
    q = v.states_along(test)
    np.testing.assert_allclose(h_test, -np.mean(np.log2(v.next_dist[q, test])), rtol=1e-12)


def test_order1_source_gives_depth1_contexts():
    rng = np.random.default_rng(3)
    k = 4
    table = {(a,): rng.dirichlet(np.full(k, 0.7)) for a in range(k)}
    x = generate(table, 20000, np.random.default_rng(4), 1)
    v = Vlmm.fit([x], k, max_memory=8, epsilon=1e-3)
    assert v.depth.max() == 1
    assert v.n_states == 1 + k
    for (a,), p in table.items():
        np.testing.assert_allclose(v.next_distribution(v.initial_state([2, a])), p, atol=0.03)


def test_memory_grows_only_where_needed():
    """After symbol 0 the next symbol depends on the one before it; elsewhere only on the last."""
    rng = np.random.default_rng(5)
    k = 3
    first = {b: rng.dirichlet(np.full(k, 1.0)) for b in range(1, k)}
    after0 = {a: np.eye(k)[(a + 1) % k] * 0.8 + 0.2 / k for a in range(k)}
    table = {(a, b): (after0[a] if b == 0 else first[b]) for a in range(k) for b in range(k)}
    x = generate(table, 30000, np.random.default_rng(6), 2)
    v = Vlmm.fit([x], k, max_memory=5, epsilon=2e-3)
    deep = [s for s, d in zip(v.states, v.depth) if d >= 2 and v.learnt[v.index[s]]]
    assert deep, "the order-2 dependency after symbol 0 was not found"
    assert all(s[-1] == 0 for s in deep)
    assert v.depth.max() == 2
    for a in range(k):
        np.testing.assert_allclose(v.next_distribution(v.initial_state([a, 0])), after0[a],
                                   atol=0.04)


def test_finds_dependency_invisible_at_depth1():
    """x_t = x_{t-1} xor x_{t-2} (with noise): every depth-1 context predicts 50/50."""
    rng = np.random.default_rng(7)
    x = [0, 1]
    for _ in range(20000):
        x.append((x[-1] ^ x[-2]) if rng.random() < 0.9 else 1 - (x[-1] ^ x[-2]))
    v = Vlmm.fit([np.array(x)], 2, max_memory=4, epsilon=1e-3)
    assert v.depth.max() == 2
    np.testing.assert_allclose(v.next_distribution(v.initial_state([1, 1]))[0], 0.9, atol=0.02)
    np.testing.assert_allclose(v.next_distribution(v.initial_state([1, 0]))[1], 0.9, atol=0.02)


def test_larger_epsilon_fewer_states(order2):
    _, train, _, _ = order2
    counts = [Vlmm.fit([train], 3, max_memory=6, epsilon=e).n_states
              for e in (1e-5, 1e-4, 1e-3, 3e-2, 1.0)]
    assert all(a >= b for a, b in zip(counts, counts[1:]))
    assert counts[0] > counts[2] and counts[-1] == 1


def test_automaton_state_is_longest_suffix_of_history(order2):
    """step() through the PFSA equals a direct longest-suffix search over the whole history."""
    _, _, test, _ = order2
    _, train, _, _ = order2
    v = Vlmm.fit([train], 3, max_memory=6, epsilon=1e-4)  # deeper, irregular tree
    assert v.depth.max() >= 3
    states = set(v.states)
    q = v.initial_state([])
    for t in range(400):
        h = tuple(int(s) for s in test[:t])
        ref = next(h[i:] for i in range(len(h) + 1) if h[i:] in states)
        assert v.states[q] == ref
        assert q == v.initial_state(test[:t])
        q = v.step(q, test[t])


def test_sample_reproduces_the_model(order2):
    table, _, _, v = order2
    a = v.sample(np.random.default_rng(8), 30000)
    b = v.sample(np.random.default_rng(8), 30000)
    np.testing.assert_array_equal(a, b)
    # order-2 transition frequencies of the generated symbols match the source
    for (x0, x1), p in table.items():
        m = (a[:-2] == x0) & (a[1:-1] == x1)
        freq = np.bincount(a[2:][m], minlength=3) / m.sum()
        np.testing.assert_allclose(freq, p, atol=0.05)


def test_vlmm_tree_roundtrip_and_validation(order2):
    v = order2[3]
    tree = json.loads(json.dumps(v.tree_dict()))
    w = Vlmm.from_tree(tree, v.next_dist)
    assert w.states == v.states
    np.testing.assert_array_equal(w.trans, v.trans)
    bad = dict(tree, states=tree["states"][:-1] + [[0, 1, 2, 0, 1, 2, 0, 1]])
    with pytest.raises(ValueError, match="longer than max_memory"):
        Vlmm.from_tree(bad, v.next_dist)
    bad = dict(tree, states=tree["states"][:-1] + [[2, 2, 2, 2, 1]])  # suffixes missing
    with pytest.raises(ValueError, match="not closed"):
        Vlmm.from_tree(bad, v.next_dist)
    with pytest.raises(ValueError, match="next_dist"):
        Vlmm.from_tree(tree, v.next_dist[:, :2])
    with pytest.raises(ValueError):
        Vlmm.fit([np.array([0, 1, 5])], 3)
    with pytest.raises(ValueError):
        Vlmm.fit([np.array([0, 1, 2])], 3, gamma=0.5)


# ---------------------------------------------------------------- features
def test_features_angles_and_velocities():
    t = np.arange(60) / 30.0
    params = np.zeros((60, 9))
    params[:, 0] = t  # root translation must be ignored
    params[:, 6] = 0.5 * np.sin(2 * np.pi * t)
    params[:, 7] = 2.0 * t
    X = feat.motion_features(params, 30.0)
    assert X.shape == (60, 6)
    np.testing.assert_allclose(X[:, :3], params[:, 6:])
    np.testing.assert_allclose(X[1:-1, 4], 2.0, rtol=1e-12)
    w, h = 2 * np.pi, 1 / 30.0  # central difference of a sine: exact up to sin(wh)/(wh)
    np.testing.assert_allclose(X[1:-1, 3], 0.5 * w * np.cos(w * t[1:-1]) * np.sin(w * h) / (w * h),
                               atol=1e-12)
    # the same motion sampled at 60 fps has the same velocities per second
    p60 = np.zeros((119, 9))
    p60[:, 7] = 2.0 * np.arange(119) / 60.0
    np.testing.assert_allclose(feat.motion_features(p60, 60.0)[:, 4], 2.0, rtol=1e-9)


def test_features_unwrap_angle_jumps():
    a = np.linspace(3.0, 3.3, 10)
    params = np.zeros((10, 7))
    params[:, 6] = np.angle(np.exp(1j * a))  # wraps from +pi to -pi mid-sequence
    X = feat.motion_features(params, 10.0)
    np.testing.assert_allclose(X[:, 1], 0.3 / 9 * 10.0, rtol=1e-9)


def test_augment_speeds_and_smoothing():
    params = np.zeros((101, 8))
    params[:, 6] = np.linspace(0.0, 1.0, 101)
    params[:, 7] = (np.arange(101) % 2) * 0.1  # frame-rate jitter
    out = feat.augment(params, speeds=(0.5, 1.0, 2.0), smoothing=(0.0, 2.0))
    assert [len(o) for o in out] == [201, 201, 101, 101, 51, 51]
    np.testing.assert_allclose(out[0][:, 6], np.linspace(0.0, 1.0, 201), atol=1e-12)
    assert np.ptp(out[3][10:-10, 7]) < 0.2 * np.ptp(out[2][10:-10, 7])  # smoothing works
    np.testing.assert_allclose(out[3][10:-10, 6], out[2][10:-10, 6], atol=1e-9)  # linear kept


# ---------------------------------------------------------------- behaviour model
def synthetic_motion(rng, n_cycles, fps=30.0, period=1.2, n_angles=4):
    """Periodic 'walk' angles with a pause every third cycle (needs memory to predict)."""
    frames = []
    for c in range(n_cycles):
        t = np.arange(int(period * fps)) / fps
        ph = 2 * np.pi * t / period
        a = np.stack([0.6 * np.sin(ph + j) for j in range(n_angles)], axis=1)
        frames.append(a)
        if c % 3 == 2:
            frames.append(np.repeat(a[-1:], int(0.5 * fps), axis=0))
    ang = np.concatenate(frames) + rng.normal(0, 0.01, (sum(len(f) for f in frames), n_angles))
    params = np.zeros((len(ang), 6 + n_angles))
    params[:, 6:] = ang
    params[:, 2] = np.arange(len(ang)) * 0.04  # root moves; must not matter
    return params


@pytest.fixture(scope="module")
def synth_model():
    params = synthetic_motion(np.random.default_rng(0), 24)
    return params, BehaviourModel.fit(params, 30.0, np.random.default_rng(1), k_max=20,
                                      max_memory=6, epsilon=1e-3,
                                      dof_names=("a", "b", "c", "d"))


def test_behaviour_fit_report(synth_model):
    params, m = synth_model
    r = m.report()
    assert 2 <= r["n_clusters"] <= 20
    assert r["n_states"] >= r["n_clusters"] + 1
    assert r["feature_dim"] == 8
    assert 0 < r["train_entropy"] < np.log2(r["n_clusters"])
    assert np.isfinite(r["heldout_entropy"]) and r["heldout_frames"] > 0
    labels = m.label(m.features(params))
    assert len(np.unique(labels)) >= 2


def test_behaviour_predict_local_dynamics_and_jumps(synth_model):
    params, m = synth_model
    X = m.features(params)
    labels = m.label(X)
    states = np.array([m.state_for(labels[max(0, i - 6):i + 1]) for i in range(len(X))])
    rng = np.random.default_rng(2)
    Xn, sn = m.predict(rng, X, states, lam=0.0)
    Xn2, sn2 = m.predict(np.random.default_rng(2), X, states, lam=0.0)
    np.testing.assert_array_equal(Xn, Xn2)
    cur = m.vlmm.last_symbol[states]
    nxt = m.vlmm.last_symbol[sn]
    same = nxt == cur
    assert same.mean() > 0.5  # clusters span several frames
    # lam = 0: deterministic constant-velocity step x + dx / fps inside a cluster
    np.testing.assert_allclose(Xn[same, :4], X[same, :4] + X[same, 4:] / 30.0, atol=1e-12)
    np.testing.assert_allclose(Xn[same, 4:], X[same, 4:], atol=1e-12)
    # a cluster change re-samples from the new cluster: close to its mean in Mahalanobis terms
    if np.any(~same):
        lp = m.gmm.logpdf_components(Xn[~same])
        assert np.all(np.argmax(lp, axis=1) == nxt[~same]) or np.mean(
            np.argmax(lp, axis=1) == nxt[~same]) > 0.8
    np.testing.assert_array_equal(sn, m.vlmm.step(states, nxt))
    # with noise the prediction changes, with the cluster covariance's scale
    Xl, _ = m.predict(np.random.default_rng(2), X, states, lam=1.0)
    d = (Xl - Xn)[same]
    assert np.all(np.abs(d).max(axis=0) > 0)
    # the predicted next frame is close to the true next frame for most particles
    err = np.linalg.norm(Xn[:-1, :4] - X[1:, :4], axis=1)
    assert np.median(err) < 0.05


def test_transition_probabilities_eq3(synth_model):
    _, m = synth_model
    X, lab = m.gmm.sample(np.random.default_rng(3), 50)
    states = np.array([m.state_for([k]) for k in lab])
    lp = m.transition_logprob(X, states)
    ref = m.gmm.logpdf_components(X) + np.log(m.vlmm.next_dist[states])
    ref = np.exp(ref - ref.max(axis=1, keepdims=True))
    np.testing.assert_allclose(np.exp(lp), ref / ref.sum(axis=1, keepdims=True), rtol=1e-9,
                               atol=1e-300)


def test_behaviour_save_load_roundtrip(synth_model, tmp_path):
    params, m = synth_model
    path = tmp_path / "model.npz"
    m.save(path)
    with np.load(path, allow_pickle=False) as z:
        assert "meta" in z.files
    m2 = BehaviourModel.load(path)
    assert m2.report() == m.report()
    assert m2.dof_names == ("a", "b", "c", "d")
    np.testing.assert_array_equal(m2.vel_rho, m.vel_rho)
    np.testing.assert_array_equal(m2.root_dyn, m.root_dyn)
    np.testing.assert_array_equal(m2.local_covs, m.local_covs)
    X = m.features(params[:50])
    s = np.zeros(50, dtype=int)
    a = m.predict(np.random.default_rng(4), X, s)
    b = m2.predict(np.random.default_rng(4), X, s)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def _rewrite(src, dst, **changes):
    with np.load(src, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    d.update(changes)
    d = {k: v for k, v in d.items() if v is not None}
    with open(dst, "wb") as f:
        np.savez(f, **d)


def _old_model(m, tmp_path, **missing):
    """``m`` saved, then rewritten without the arrays named in ``missing`` (as a model written
    before they were learnt) and loaded again."""
    good, old = tmp_path / "good.npz", tmp_path / "old.npz"
    m.save(good)
    _rewrite(good, old, **missing)
    return BehaviourModel.load(old)


def _prior(m, **kwargs):
    """A VlmmPrior of ``m`` on the 25-DOF default body, the model's angles named as its first
    angles."""
    from dataclasses import replace

    from gltrack.body.dofs import make_dofs
    from gltrack.body.skeleton import default_skeleton
    from gltrack.motion.vlmm_prior import VlmmPrior

    dofs = make_dofs(default_skeleton(), "25")
    names = tuple(dofs.names[6:6 + m.n_angles])
    return VlmmPrior(replace(m, dof_names=names), dofs, 30.0, **kwargs), dofs


def test_behaviour_load_rejects_bad_files(synth_model, tmp_path):
    _, m = synth_model
    good = tmp_path / "good.npz"
    m.save(good)
    with np.load(good, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        covs = z["gmm_covs"]
        nd = z["vlmm_next_dist"]
    cases = {
        "gmm_covs": dict(gmm_covs=-covs),
        "gmm_means": dict(gmm_means=None),
        "vlmm_next_dist": dict(vlmm_next_dist=nd[:, :-1]),
        "meta": dict(meta=np.array("{not json")),
        "meta.fps": dict(meta=np.array(json.dumps(dict(meta, fps=-1)))),
        "meta.format": dict(meta=np.array(json.dumps(dict(meta, format="other")))),
        "meta.vlmm": dict(meta=np.array(json.dumps(dict(meta, vlmm={"states": "x"})))),
        "vel_rho": dict(vel_rho=np.full(4, 1.5)),
        "root_dynamics": dict(root_dynamics=np.ones((2, 5))),
        "local_covariances": dict(local_covariances=-m.local_covs),
    }
    for field, change in cases.items():
        bad = tmp_path / f"bad_{field}.npz"
        _rewrite(good, bad, **change)
        with pytest.raises(ValueError) as e:
            BehaviourModel.load(bad)
        msg = str(e.value)
        assert str(bad) in msg and field.split(".")[0].split("_")[0] in msg, msg
    obj = tmp_path / "pickled.npz"
    _rewrite(good, obj, meta=np.array([{"a": 1}], dtype=object))
    with pytest.raises(ValueError, match="pickled.npz"):
        BehaviourModel.load(obj)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="junk.npz"):
        BehaviourModel.load(junk)


def test_behaviour_from_cmu_walk():
    shared = _shared()
    clip = shared / "mocap" / "cmu_02_01_walk.bvh"
    if not clip.is_file():
        pytest.skip(f"{clip} is absent")
    retarget = pytest.importorskip("gltrack.motion.retarget")
    if not hasattr(retarget, "load_motion"):
        pytest.skip("gltrack.motion.retarget.load_motion is not available yet")
    _, dofs, params, fps = retarget.load_motion(clip, preset="full", fps=30)
    assert fps == 30
    m = BehaviourModel.fit(params, fps, np.random.default_rng(0), max_memory=5,
                           speeds=(0.8, 0.9, 1.0, 1.1, 1.2), dof_names=dofs.names[6:])
    r = m.report()
    assert 2 <= r["n_clusters"] <= 40
    assert np.isfinite(r["train_entropy"]) and np.isfinite(r["heldout_entropy"])
    assert r["heldout_frames"] == len(params) - int(round(0.8 * len(params)))
    X = m.features(params)
    Xn, sn = m.predict(np.random.default_rng(1), X, np.zeros(len(X), dtype=int), lam=0.5)
    assert np.all(np.isfinite(Xn)) and np.all(sn >= 0)


def test_no_transition_across_sequences():
    """Sequences are kept apart: the end of one never precedes the start of the next, so a
    symbol only ever followed by itself within each sequence predicts itself alone."""
    v = Vlmm.fit([np.zeros(30, dtype=np.int64), np.ones(30, dtype=np.int64)], 2,
                 max_memory=2, min_count=1, gamma=1e-3)
    p = v.next_distribution(v.initial_state([0]))
    assert p[1] < 2e-3 and p[0] > 0.99
    # glued into one sequence, the same symbols do show the 0 -> 1 transition
    glued = Vlmm.fit([np.r_[np.zeros(30), np.ones(30)].astype(np.int64)], 2, max_memory=2,
                     min_count=1, gamma=1e-3)
    assert glued.next_distribution(glued.initial_state([0]))[1] > 0.02


def test_velocity_noise_attenuated_separately(synth_model):
    """``lam_dx`` scales only the velocities' noise; None is the paper's single ``lam``."""
    params, m = synth_model
    X = m.features(params)
    labels = m.label(X)
    states = np.array([m.state_for(labels[max(0, i - 6):i + 1]) for i in range(len(X))])

    def run(**kw):
        return m.predict(np.random.default_rng(7), X, states, **kw)

    paper, same_lam, keep_v = run(lam=0.5), run(lam=0.5, lam_dx=0.5), run(lam=0.5, lam_dx=0.0)
    np.testing.assert_array_equal(paper[0], same_lam[0])
    stay = m.vlmm.last_symbol[keep_v[1]] == m.vlmm.last_symbol[states]
    assert stay.mean() > 0.5
    # lam_dx = 0: a particle that stays in its cluster keeps its velocity exactly ...
    np.testing.assert_array_equal(keep_v[0][stay, 4:], X[stay, 4:])
    # ... and its angles still get the attenuated cluster noise around x + dx dt
    d = keep_v[0][stay, :4] - (X[stay, :4] + X[stay, 4:] / 30.0)
    assert np.all(np.std(d, axis=0) > 0)
    np.testing.assert_allclose(d, (paper[0][stay, :4] - (X[stay, :4] + paper[0][stay, 4:] / 30.0)),
                               atol=1e-12)


def test_vlmm_options_lam_dx():
    from gltrack.track.vlmm import VlmmOptions

    opt = VlmmOptions(model="m.npz").validate()
    assert opt.lam == opt.lam_dx == 0.5  # the paper's single coefficient
    assert VlmmOptions.from_dict({"model": "m.npz", "lam_dx": 0}).lam_dx == 0.0
    with pytest.raises(ValueError, match="lam_dx = -0.1"):
        VlmmOptions.from_dict({"model": "m.npz", "lam_dx": -0.1})


def _ar1_velocities(rng, rho, n=4000, a=3, sd=2.0, mean=(1.0, -0.5, 0.0)):
    """(n, 2a) feature vectors whose velocities are a stationary AR(1) about ``mean``."""
    v = np.empty((n, a))
    v[0] = mean + sd * rng.standard_normal(a)
    for t in range(1, n):
        v[t] = mean + rho * (v[t - 1] - mean) + sd * np.sqrt(1 - rho ** 2) * rng.standard_normal(a)
    return np.concatenate([np.cumsum(v, axis=0) / 30.0, v], axis=1)


def test_velocity_memory_recovers_the_autocorrelation():
    """The learnt rho is the lag-1 autocorrelation about each cluster's mean velocity, only
    over frames that stay in one cluster."""
    from gltrack.motion.behaviour import velocity_memory

    rng = np.random.default_rng(0)
    mean = np.array([[1.0, -0.5, 0.0]])
    for rho in (0.3, 0.8):
        X = _ar1_velocities(rng, rho)
        got = velocity_memory([X], [np.zeros(len(X), dtype=np.int64)], mean)
        np.testing.assert_allclose(got, rho, atol=0.05)
    # a cluster change between two frames is no evidence of memory: alternating labels with
    # two clusters of very different means would otherwise give a spurious correlation
    X = _ar1_velocities(rng, 0.0)
    X[1::2, 3:] += 10.0
    labels = np.tile([0, 1], len(X) // 2)
    two = np.array([[1.0, -0.5, 0.0], [11.0, 9.5, 10.0]])
    np.testing.assert_array_equal(velocity_memory([X], [labels], two), 0.0)
    assert np.all(velocity_memory([X[:1]], [labels[:1]], two) == 0.0)  # no pair: no memory


def test_ar1_velocities_stay_in_the_cluster():
    """Iterated inside one cluster, the paper's random walk spreads the velocities without
    bound; the learnt autoregression keeps them at the cluster's own spread and pulls a
    velocity far from the cluster's mean back towards it."""
    X = _ar1_velocities(np.random.default_rng(1), 0.5, n=3000, mean=(0.0, 0.0, 0.0))
    params = np.zeros((len(X), 9))
    params[:, 6:] = X[:, :3]
    m = BehaviourModel.fit(params, 30.0, np.random.default_rng(2), k_max=1, augment=False,
                           holdout=0)
    assert m.gmm.n_components == 1  # no cluster jumps: the local dynamics alone
    assert np.all((m.vel_rho > 0.4) & (m.vel_rho < 0.95)), m.vel_rho
    n, a = 2000, m.n_angles
    sd = np.sqrt(np.diagonal(m.gmm.covs[0])[a:])
    state = np.full(n, m.state_for([0]))
    spread = {}
    for velocity in ("walk", "ar1"):
        Xp, rng = np.repeat(m.gmm.means[:1], n, axis=0), np.random.default_rng(5)
        for _ in range(60):
            Xp, _s = m.predict(rng, Xp, state, lam=0.5, velocity=velocity)
        spread[velocity] = np.std(Xp[:, a:], axis=0) / sd
    assert np.all(spread["walk"] > 2.5), spread  # 0.5 * sqrt(60) = 3.9 cluster sds
    assert np.all((spread["ar1"] > 0.85) & (spread["ar1"] < 1.15)), spread
    Xp = np.repeat(m.gmm.means[:1], n, axis=0)
    Xp[:, a:] += 5 * sd
    Xn, _s = m.predict(np.random.default_rng(6), Xp, state, lam=0.0, velocity="ar1")
    off = (Xn[:, a:] - m.gmm.means[0, a:]) / sd
    np.testing.assert_allclose(np.mean(off, axis=0), 5 * m.vel_rho, atol=0.1)
    np.testing.assert_allclose(np.std(off, axis=0), np.sqrt(1 - m.vel_rho ** 2), rtol=0.1)


def test_velocity_option_and_models_without_memory(synth_model, tmp_path, caplog):
    """A model written before vel_rho existed loads; predict refuses "ar1" with it and the
    prior falls back to the walk with a warning. Bad option values are errors."""
    import logging

    from gltrack.track.vlmm import VlmmOptions

    params, m = synth_model
    m_old = _old_model(m, tmp_path, vel_rho=None)
    assert m_old.vel_rho is None and m_old.report()["velocity_rho_median"] is None
    X = m.features(params[:20])
    s = np.zeros(20, dtype=int)
    with pytest.raises(ValueError, match="velocity memory"):
        m_old.predict(np.random.default_rng(0), X, s, velocity="ar1")
    with pytest.raises(ValueError, match="'walk' or 'ar1'"):
        m.predict(np.random.default_rng(0), X, s, velocity="other")
    # the two velocity models give different predictions from the same draws
    a = m.predict(np.random.default_rng(0), X, s, velocity="walk")[0]
    b = m.predict(np.random.default_rng(0), X, s, velocity="ar1")[0]
    assert not np.allclose(a, b)
    assert VlmmOptions(model="m.npz").validate().velocity == "ar1"
    with pytest.raises(ValueError, match="velocity"):
        VlmmOptions.from_dict({"model": "m.npz", "velocity": "fast"})
    with caplog.at_level(logging.WARNING, logger="gltrack.motion.vlmm_prior"):
        assert _prior(m_old)[0].velocity == "walk"
    assert "velocity memory" in caplog.text
    assert _prior(m)[0].velocity == "ar1"


def _root_walk(rng, sd, rho, n=20000, fps=30.0, n_angles=2):
    """Params whose six root velocities follow AR(1)s with the given sds and memories."""
    sd, rho = np.asarray(sd, float), np.asarray(rho, float)
    v = np.zeros((n, 6))
    v[0] = rng.standard_normal(6) * sd
    for t in range(1, n):
        v[t] = rho * v[t - 1] + np.sqrt(1 - rho ** 2) * sd * rng.standard_normal(6)
    params = np.zeros((n + 1, 6 + n_angles))
    params[1:, :6] = np.cumsum(v, axis=0) / fps
    return params


def test_root_dynamics_recovers_spread_and_memory():
    """The learnt root dynamics are each root velocity's spread and lag-1 autocorrelation; the
    two horizontal translations share theirs; rotations are unwrapped first."""
    from gltrack.motion.behaviour import root_dynamics, velocity_memory

    sd = np.array([0.6, 0.2, 0.4, 3.0, 0.8, 1.0])
    rho = np.array([0.9, 0.7, 0.9, 0.75, 0.3, 0.2])
    params = _root_walk(np.random.default_rng(0), sd, rho)
    got = root_dynamics(params, 30.0)
    assert got.shape == (2, 6)
    want_sd = sd.copy()
    want_sd[[0, 2]] = np.sqrt((0.6 ** 2 + 0.4 ** 2) / 2)  # pooled floor directions
    np.testing.assert_allclose(got[0], want_sd, rtol=0.06)
    np.testing.assert_allclose(got[1], rho, atol=0.04)
    assert got[0, 0] == got[0, 2] and got[1, 0] == got[1, 2]
    # the heading wrapped into (-pi, pi] (as a BVH may store it) gives the same answer
    wrapped = params.copy()
    wrapped[:, 3] = np.angle(np.exp(1j * wrapped[:, 3]))
    assert np.abs(wrapped[:, 3] - params[:, 3]).max() > 1.0  # the walk did wrap
    np.testing.assert_allclose(root_dynamics(wrapped, 30.0), got, atol=1e-9)
    # twice the frame rate: velocities per second keep their spread
    np.testing.assert_allclose(root_dynamics(params, 60.0)[0], 2 * got[0])
    np.testing.assert_array_equal(root_dynamics([params[:2]], 30.0), 0.0)  # too short
    # the model learns them from the takes as recorded, not from the smoothed copies that
    # augment its clusters (smoothing would invent memory)
    part = params[:3000].copy()
    part[:, 6:] = np.random.default_rng(1).normal(0, 0.1, (len(part), 2))
    m = BehaviourModel.fit(part, 30.0, np.random.default_rng(2), k_max=1, holdout=0)
    np.testing.assert_allclose(m.root_dyn, root_dynamics(part, 30.0))
    X = m.features(part)
    np.testing.assert_allclose(m.vel_rho, velocity_memory([X], [m.label(X)],
                                                          m.gmm.means[:, m.n_angles:]))
    with pytest.raises(ValueError, match="fps"):
        root_dynamics(params, 0.0)


def _prior_with_root(m, root_dyn, **kwargs):
    from dataclasses import replace

    return _prior(replace(m, root_dyn=root_dyn), **kwargs)


def test_prior_root_velocities_keep_their_memory(synth_model):
    """With the learnt root dynamics a particle keeps turning the way it turned (its heading
    velocity decays by rho a frame), the velocities keep the learnt spread over many frames,
    and resampling carries every particle's velocity with it; "walk" diffuses as before."""
    params, m = synth_model
    root_dyn = np.array([[0.5, 0.2, 0.5, 3.0, 0.8, 1.0], [0.9, 0.7, 0.9, 0.75, 0.3, 0.2]])
    prior, dofs = _prior_with_root(m, root_dyn)
    assert prior.root == "ar1"
    n = 4000
    P = np.repeat(dofs.zero()[None], n, axis=0)
    rng = np.random.default_rng(0)
    prior.reset(P, rng)
    prior.V[:] = 0.0
    prior.V[:, 3] = 6.0  # every particle spins at 6 rad/s
    out = prior.predict(P, rng)
    turn = (out[:, 3] - P[:, 3]) * 30.0  # the heading's velocity over this frame, rad/s
    assert abs(np.mean(turn) - 0.75 * 6.0) < 0.1, np.mean(turn)
    assert abs(np.std(turn) - 3.0 * np.sqrt(1 - 0.75 ** 2)) < 0.1
    for _ in range(40):
        out = prior.predict(out, rng)
    np.testing.assert_allclose(np.std(prior.V, axis=0), root_dyn[0], rtol=0.08)
    # resampling: the rows' velocities move with them
    idx = np.argsort(prior.V[:, 3])[-10:]
    fast = prior.V[idx, 3].copy()
    prior.select(idx)
    np.testing.assert_array_equal(prior.V[:, 3], fast)
    state = prior.get_state()
    prior.V = None
    prior.set_state(state)
    np.testing.assert_array_equal(prior.V[:, 3], fast)
    # recovery restarts roots at rest
    prior.respawn(out[:10], np.zeros(10, dtype=int))
    np.testing.assert_array_equal(prior.V, 0.0)
    # the paper's diffusion: no memory, the DOF set's root sigmas
    walk, _ = _prior_with_root(m, root_dyn, root="walk")
    walk.reset(P, rng)
    out = walk.predict(P, rng)
    np.testing.assert_allclose(np.std(out[:, 3] - P[:, 3]), dofs.sigma_at(30.0)[3], rtol=0.08)
    assert abs(np.mean(out[:, 3] - P[:, 3])) < 0.005


def test_root_option_and_models_without_root_dynamics(synth_model, tmp_path, caplog):
    """A model written before root_dyn existed loads and the prior falls back to the paper's
    diffusion with a warning; the option is validated."""
    import logging

    from gltrack.track.vlmm import VlmmOptions

    _, m = synth_model
    assert m.root_dyn is not None and m.report()["heading_rate_sd"] == m.root_dyn[0, 3]
    m_old = _old_model(m, tmp_path, root_dynamics=None)
    assert m_old.root_dyn is None and m_old.report()["root_speed_sd"] is None
    with caplog.at_level(logging.WARNING, logger="gltrack.motion.vlmm_prior"):
        assert _prior_with_root(m_old, None)[0].root == "walk"
    assert "root dynamics" in caplog.text
    with pytest.raises(ValueError, match="root"):
        _prior_with_root(m, m.root_dyn, root="spin")
    assert VlmmOptions(model="m.npz").validate().root == "ar1"
    with pytest.raises(ValueError, match="root"):
        VlmmOptions.from_dict({"model": "m.npz", "root": "spin"})


def test_local_covariances_are_each_clusters_full_covariance():
    """Two far-apart clusters of correlated samples, described by a mixture with diagonal
    covariances: each cluster's full covariance about its mean, off-diagonal terms included."""
    from gltrack.motion.behaviour import local_covariances
    from gltrack.motion.fjgmm import GaussianMixture

    rng = np.random.default_rng(0)
    c1 = np.array([[1.0, 0.8, 0.0], [0.8, 1.0, -0.5], [0.0, -0.5, 1.0]])
    c2 = np.array([[0.5, -0.3, 0.1], [-0.3, 0.4, 0.0], [0.1, 0.0, 0.2]])
    mu = np.array([[0.0, 0.0, 0.0], [40.0, -40.0, 40.0]])
    X = np.concatenate([rng.multivariate_normal(mu[0], c1, 20000),
                        rng.multivariate_normal(mu[1], c2, 20000)])
    diag = np.stack([np.diag(np.diag(c1)), np.diag(np.diag(c2))])
    g = GaussianMixture(np.array([0.5, 0.5]), mu, diag)
    got = local_covariances(X, g, reg=0.0)
    np.testing.assert_allclose(got[0], c1, atol=0.04)
    np.testing.assert_allclose(got[1], c2, atol=0.02)
    np.testing.assert_allclose(got, np.swapaxes(got, 1, 2))
    assert np.all(np.linalg.eigvalsh(local_covariances(X[:5], g)) > 0)  # reg keeps it definite


def _copies_in_a_cluster(m, n=20000, depth=1.0):
    """n copies of a training frame of the most populated cluster, with its VLMM state; and that
    cluster. ``depth`` 1: the frame deepest inside the cluster, 0.5 the median one (its angles
    away from the cluster's mean)."""
    X = m.features(synthetic_motion(np.random.default_rng(0), 24))
    lab = m.label(X)
    k = np.bincount(lab).argmax()
    inside = np.nonzero(lab == k)[0]
    order = inside[np.argsort(m.gmm.logpdf_components(X[inside])[:, k])]
    i = order[min(int(depth * len(order)), len(order) - 1)]
    return np.repeat(X[i:i + 1], n, axis=0), np.full(n, m.state_for([k])), k


def test_full_local_dynamics_move_the_angles_together(synth_model):
    """local="full": the angles' noise has the cluster's full covariance (the synthetic angles
    are phase-shifted sines, correlated), "diag" only its diagonal; both share the variances."""
    _, m = synth_model
    X, s, k = _copies_in_a_cluster(m)
    a = m.n_angles
    full = m.local_covs[k, :a, :a]
    sd = np.sqrt(np.diag(full))
    corr = full / np.outer(sd, sd)
    assert np.max(np.abs(corr - np.eye(a))) > 0.15  # the test needs correlated angles
    for local, want in (("full", corr), ("diag", np.eye(a))):
        Xn, sn = m.predict(np.random.default_rng(1), X, s, lam=1.0, lam_dx=0.0,
                           velocity="walk", local=local)
        stay = m.vlmm.last_symbol[sn] == k
        assert stay.mean() > 0.5
        step = Xn[stay, :a] - X[stay, :a] - X[stay, a:] / m.fps  # = lam * n_x
        np.testing.assert_allclose(np.std(step, axis=0), np.sqrt(np.diag(m.gmm.covs[k]))[:a],
                                   rtol=0.05)
        np.testing.assert_allclose(np.corrcoef(step.T), want, atol=0.05)


def test_regressed_local_dynamics_regress_the_velocity_on_the_angles(synth_model):
    """With velocity="ar1", "regressed" takes the velocity's mean where the angles are in the
    cluster: mu_dx + S_dx,x S_xx^-1 (x - mu_x); "full" and "diag" the cluster's mean
    velocity."""
    _, m = synth_model
    X, s, k = _copies_in_a_cluster(m, depth=0.5)
    a = m.n_angles
    c, mu = m.local_covs[k], m.gmm.means[k]
    target = {"regressed": mu[a:] + c[a:, :a] @ np.linalg.solve(c[:a, :a], X[0, :a] - mu[:a]),
              "full": mu[a:], "diag": mu[a:]}
    assert np.linalg.norm(target["regressed"] - target["diag"]) > 0.1 * np.linalg.norm(mu[a:])
    for local in ("regressed", "full", "diag"):
        Xn, sn = m.predict(np.random.default_rng(2), X, s, lam=0.0, velocity="ar1", local=local)
        stay = m.vlmm.last_symbol[sn] == k
        want = target[local] + m.vel_rho * (X[0, a:] - target[local])
        sd = np.sqrt(np.diag(c)[a:] / stay.sum())
        np.testing.assert_allclose(Xn[stay, a:].mean(axis=0), want, atol=6 * sd.max())


def test_local_option_and_models_without_full_covariances(synth_model, tmp_path, caplog):
    """A model written before local_covs existed loads; predict refuses "full" with it and the
    prior falls back to the diagonal covariances with a warning. Bad values are errors."""
    import logging

    from dataclasses import replace

    from gltrack.track.vlmm import VlmmOptions

    params, m = synth_model
    assert m.report()["local_covariances"] is True
    m_old = _old_model(m, tmp_path, local_covariances=None)
    assert m_old.local_covs is None and m_old.report()["local_covariances"] is False
    X = m.features(params[:20])
    st = np.zeros(20, dtype=int)
    for local in ("full", "regressed"):
        with pytest.raises(ValueError, match="full cluster covariances"):
            m_old.predict(np.random.default_rng(0), X, st, local=local)
    with pytest.raises(ValueError, match="local must be one of"):
        m.predict(np.random.default_rng(0), X, st, local="other")
    with pytest.raises(ValueError, match="local_covs"):
        replace(m, local_covs=m.local_covs[:1])
    assert VlmmOptions(model="m.npz").validate().local == "full"
    with pytest.raises(ValueError, match="local"):
        VlmmOptions.from_dict({"model": "m.npz", "local": "wide"})
    with caplog.at_level(logging.WARNING, logger="gltrack.motion.vlmm_prior"):
        assert _prior(m_old)[0].local == "diag"
        assert _prior(m_old, local="regressed")[0].local == "diag"
    assert "full cluster covariances" in caplog.text
    assert _prior(m)[0].local == "full"
    with pytest.raises(ValueError, match="local"):
        _prior(m, local="wide")
