"""Behaviour-model (VLMM) tracker: the prior on its own, and tracking through the CLI."""
import json

import numpy as np
import pytest

import gltrack.motion.vlmm_prior as vp
import gltrack.track.vlmm as tv
from gltrack.bench.rigs import ring_cameras
from gltrack.bench.vlmm import make_multiview_dataset, periodic_motion
from gltrack.body.model import BodyModel
from gltrack.cli import main
from gltrack.data.dataset import Dataset
from gltrack.observe.blob_evidence import LOST_KL
from gltrack.motion.behaviour import BehaviourModel

PERIOD = 0.8
N_FRAMES = 16


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("vlmm")
    body = BodyModel.build(preset="25", lod=0)
    train = periodic_motion(body, 120, period=PERIOD)
    model = BehaviourModel.fit(train, 30.0, np.random.default_rng(0), holdout=0.0,
                               dof_names=body.dofs.names[6:])
    model.save(root / "model.npz")
    test = periodic_motion(body, N_FRAMES, phase=1.0, period=PERIOD)
    test[:, 0] += 0.2
    cams = ring_cameras((0.2, 0.9, 0.0), width=160, height_px=120)
    make_multiview_dataset(root / "ds", body, test, cams)
    return root, body, model, test


def _config(root, name, **kw):
    opts = {"model": str(root / "model.npz"), "particles": 80, "tile": 64, **kw}
    lines = [f"{k} = {json.dumps(v)}" for k, v in opts.items()]
    (root / name).write_text("\n".join(lines) + "\n")
    return str(root / name)


def _errors(root, out, body, test):
    est = np.load(root / out / "poses.npz")["joints"]
    gt = body.joints(test)
    return (np.linalg.norm(est - gt, axis=2).mean(),
            np.linalg.norm(gt[:1] - gt, axis=2).mean())


@pytest.mark.parametrize("evaluation,init", [("silhouette", "groundtruth"), ("blobs", "auto")])
def test_cli_tracking_beats_fixed_pose(setup, evaluation, init):
    root, body, _, test = setup
    cfg = _config(root, f"{evaluation}.toml", evaluation=evaluation, estimate="mean")
    out = f"res_{evaluation}"
    rc = main(["-q", "track", "--body", "dataset", str(root / "ds"), "--method", "vlmm", "--out", str(root / out),
               "--config", cfg, "--init", init, "--seed", "3"])
    assert rc == 0
    err, fixed = _errors(root, out, body, test)
    assert fixed > 0.085  # the motion is large enough to matter
    assert err < 0.75 * fixed, (err, fixed)
    frames = [json.loads(s) for s in (root / out / "frames.jsonl").read_text().splitlines()]
    assert len(frames) == N_FRAMES and frames[0]["evaluations"] >= 80


def test_missing_or_bad_model_is_an_error(setup, tmp_path, capsys):
    root, *_ = setup
    cfg = tmp_path / "c.toml"
    cfg.write_text("particles = 10\n")
    rc = main(["-q", "track", "--body", "dataset", str(root / "ds"), "--method", "vlmm", "--out",
               str(tmp_path / "r"), "--config", str(cfg)])
    assert rc == 1 and "model" in capsys.readouterr().err
    bad = tmp_path / "bad.npz"
    np.savez(bad, x=np.zeros(3))
    cfg.write_text(f"model = {json.dumps(str(bad))}\n")
    rc = main(["-q", "track", "--body", "dataset", str(root / "ds"), "--method", "vlmm", "--out",
               str(tmp_path / "r2"), "--config", str(cfg)])
    assert rc == 1 and "bad.npz" in capsys.readouterr().err


def test_prior_predicts_the_learnt_motion_better_than_diffusion(setup):
    """One-step prediction from true poses with their true history: the VLMM prior lands
    closer to the next true pose than zero-mean Gaussian diffusion with the DOF sigmas."""
    _, body, model, _ = setup
    seq = periodic_motion(body, 40, phase=2.0, period=PERIOD)
    rng = np.random.default_rng(5)
    prior = vp.VlmmPrior(model, body.dofs, 30.0, lam=0.5)
    X = model.features(seq)
    labels = model.label(X)
    sigma = body.dofs.sigma_at(30.0)
    e_vlmm, e_diff = [], []
    for t in range(10, 38, 3):
        n = 200
        P = np.repeat(seq[t:t + 1], n, axis=0)
        prior.X = np.repeat(X[t:t + 1], n, axis=0)
        prior.states = np.full(n, model.state_for(labels[:t + 1]))
        pred = prior.predict(P, rng)
        diff = body.dofs.validate(P + rng.standard_normal(P.shape) * sigma)
        e_vlmm.append(np.abs(pred[:, 6:] - seq[t + 1, 6:]).mean())
        e_diff.append(np.abs(diff[:, 6:] - seq[t + 1, 6:]).mean())
    assert np.mean(e_vlmm) < 0.8 * np.mean(e_diff), (np.mean(e_vlmm), np.mean(e_diff))


def test_prior_bookkeeping(setup):
    _, body, model, test = setup
    rng = np.random.default_rng(0)
    prior = vp.vlmm_prior(setup[0] / "model.npz", body.dofs, 30.0)
    P = np.repeat(test[:1], 50, axis=0)
    prior.reset(P, rng)
    assert np.all(prior.clusters() >= 0)
    Q = prior.predict(P, rng)
    assert Q.shape == P.shape and not np.allclose(Q, P)
    assert np.all(Q >= body.dofs.lower) and np.all(Q <= body.dofs.upper)
    states, X_pred = prior.states.copy(), prior.X.copy()
    idx = rng.integers(0, 50, 50)
    prior.select(idx)
    assert np.array_equal(prior.states, states[idx])
    # follow(): exact copies of predicted rows inherit their own history
    prior.states, prior.X = states, X_pred  # undo select for the check below
    perm = rng.permutation(50)
    prior.follow(Q[perm])
    assert np.array_equal(prior.states, states[perm])
    assert np.allclose(prior.X[:, model.n_angles:], X_pred[perm, model.n_angles:])


def test_prior_rejects_a_model_of_other_dofs(setup):
    _, _, model, _ = setup
    body_full = BodyModel.build(preset="full", lod=0)
    # 25-preset names are a subset of full: mapped by name, the rest diffused
    prior = vp.VlmmPrior(model, body_full.dofs, 30.0)
    assert prior.other.size == body_full.dofs.size - 6 - model.n_angles
    body38 = BodyModel.build(preset="38", lod=0)  # no ankles
    with pytest.raises(ValueError, match="--dof 25"):
        vp.VlmmPrior(model, body38.dofs, 30.0)


@pytest.mark.parametrize("evaluation", ["silhouette", "blobs"])
def test_recovery_from_a_lost_start(setup, ctx, evaluation):
    """Started far from the subject and turned (1.5 rad and a metre and more off),
    the tracker detects it is lost and re-initialises from all clusters at the voxel centroid;
    without recovery it stays lost. With the blob evaluation (bench vlmm's) the failure only
    shows when the blob fit also starts from prototypes on the voxels (``fit_prototypes``):
    fitted from the lost particles alone, the evidence follows them a metre off and their KL
    stays low. (A start that is only shifted is no failure to a tracker with ``root_align``:
    it moves onto the evidence, see the next test.)"""
    root, body, _, test = setup
    ds = Dataset.open(root / "ds")
    wrong = test[0].copy()
    wrong[0] += 1.0
    wrong[2] -= 0.8
    wrong[3] += 1.5  # pelvis_ry: the heading
    gt = body.joints(test)
    res = {}
    for frames in (2, 0):
        opt = tv.VlmmOptions(model=str(root / "model.npz"), particles=60, lost_frames=frames,
                             evaluation=evaluation, headings=8, max_depth=2,
                             fit_prototypes=3)
        tr = tv.VlmmTracker(ds, body, ctx, opt, np.random.default_rng(1))
        try:
            tr.start(0, wrong)
            ests = [tr.step(f) for f in range(6)]
        finally:
            tr.close()
        res[frames] = np.linalg.norm(body.joints(np.stack([e.params for e in ests[-2:]]))
                                     - gt[4:6], axis=2).mean()
        if frames:
            assert any(e.info.get("recovered") for e in ests)
            assert max(e.evaluations for e in ests) > 60
    assert res[2] < 0.15 < res[0], res


def test_root_alignment_absorbs_a_shifted_start(setup):
    """A start only shifted (a metre across, 0.8 m along) with the pose right: with
    ``root_align`` every particle's root moves onto the blob evidence, so the tracker is on the
    subject within two frames with no recovery; sampling the translation like any other DOF
    (``root_align = false``, the default: the paper's filters) it stays lost (no recovery
    here)."""
    root, body, _, test = setup
    wrong = test[0].copy()
    wrong[0] += 1.0
    wrong[2] -= 0.8
    gt = body.joints(test)
    err = {}
    with Dataset.open(root / "ds") as ds:
        for align in (True, False):
            opt = tv.VlmmOptions(model=str(root / "model.npz"), particles=60, lost_frames=0,
                                 max_depth=2, fit_prototypes=3, root_align=align)
            tr = tv.VlmmTracker(ds, body, None, opt, np.random.default_rng(1))
            tr.start(0, wrong)
            ests = [tr.step(f) for f in range(5)]
            err[align] = np.linalg.norm(body.joints(np.stack([e.params for e in ests[2:]]))
                                        - gt[2:5], axis=2).mean()
    assert err[True] < 0.05 and err[False] > 0.5, err
    assert not tv.VlmmOptions(model="m.npz").root_align


def test_fit_from_prototypes_escapes_wrong_predictions(setup):
    """The blob fit started from wrong predictions follows them; with ``fit_prototypes`` the
    cluster means at the estimate's root are fitted too and the most voxel-likely fit wins:
    the evidence no longer follows the predictions and scores the true pose better."""
    root, body, model, test = setup
    f = 8
    wrong = test[f].copy()
    half = periodic_motion(body, N_FRAMES, phase=1.0 + np.pi, period=PERIOD)
    wrong[6:] = half[f, 6:]  # the root right, every limb half a cycle off
    with Dataset.open(root / "ds") as ds:
        got = {}
        for n in (0, 3):
            opt = tv.VlmmOptions(model=str(root / "model.npz"), particles=20, max_depth=2,
                                 colour=False, fit_prototypes=n)
            tr = tv.VlmmTracker(ds, body, None, opt, np.random.default_rng(0))
            tr.start(f, wrong)
            tr.evidence.set_frame(f)
            tr._fit_from_clusters(tr.P)
            got[n] = (tr.evidence.fit_loglik, tr.evidence.costs(test[f:f + 1])[0])
    assert got[3][0] > got[0][0], got
    assert got[3][1] < 0.8 * got[0][1], got
    with pytest.raises(ValueError, match="fit_prototypes"):
        tv.VlmmOptions(model="m.npz", fit_prototypes=-1).validate()


def test_blob_evidence_follows_lost_particles_without_prototypes(setup):
    """The drift's mechanism: fitted only from particles a metre off, the blob evidence stays
    with them (the true pose scores hundreds of nats, the lost set a few); the prototypes on
    the voxels put the evidence back on the body and the lost set's KL flags the failure.
    The root translation is sampled here (``root_align = false``, the default): aligned, a
    set that is only shifted moves onto the evidence and is not lost at all."""
    root, body, _, test = setup
    wrong = test[0].copy()
    wrong[0] += 1.0
    wrong[2] -= 0.8
    with Dataset.open(root / "ds") as ds:
        kl = {}
        for n in (0, 3):
            tr = tv.VlmmTracker(ds, body, None, tv.VlmmOptions(
                model=str(root / "model.npz"), particles=40, max_depth=2, headings=8,
                fit_prototypes=n, lost_frames=0, root_align=False), np.random.default_rng(1))
            tr.start(0, wrong)
            e = tr.step(0)
            kl[n] = (e.info["quality"], float(tr.evidence.costs(test[:1])[0]))
    # the lost set scores 19 nats without prototypes (under the diffusion filters' 25-nat
    # limit, unseen), 286 with them (flagged by both limits)
    assert kl[0][0] < LOST_KL < kl[3][0] and kl[3][0] > 10 * kl[0][0], kl
    assert kl[3][0] > tv.LOST_DEFAULT["blobs"], kl
    assert kl[3][1] < 0.2 * kl[0][1], kl


def test_search_fits_from_both_headings(setup):
    """Initialisation and recovery fit the blobs from the best-ranked candidates and from as
    many of the best turned round from the first: the kept fit (best voxel likelihood) is
    then not bound to one heading. The fit from all of them is at least as likely as the fit
    from the first heading's alone."""
    root, body, _, _ = setup
    yi = body.dofs.index("pelvis_ry")
    with Dataset.open(root / "ds") as ds:
        tr = tv.VlmmTracker(ds, body, None, tv.VlmmOptions(
            model=str(root / "model.npz"), particles=20, max_depth=2, headings=8, fit_inits=2),
            np.random.default_rng(0))
        seen = []
        fit = tr.evidence.fit
        tr.evidence.fit = lambda poses: (seen.append(np.array(poses)), fit(poses))[1]
        P, _, c = tr._search(3)
        starts = seen[-1]
        assert len(starts) == 4 and len(c) == len(P)
        turn = np.abs(np.angle(np.exp(1j * (starts[:, yi] - starts[0, yi]))))
        assert turn[0] == 0 and np.all(turn[2:] > np.pi / 2), turn
        both = tr.evidence.fit_loglik
        one = fit(starts[:2])
    assert both >= one


def test_annealing_layers_after_the_prior(setup):
    """``layers`` > 1: the prior predicts the first layer and annealing layers weigh the same
    frame's blob evidence again (fitted once a frame). Every frame costs particles x layers
    evaluations, the VLMM histories stay one per particle, and the track differs from the
    one-layer filter's and beats a fixed pose."""
    root, body, _, test = setup
    gt = body.joints(test)
    fixed = np.linalg.norm(gt[:1] - gt[1:], axis=2).mean()
    err = {}
    with Dataset.open(root / "ds") as ds:
        for layers in (1, 3):
            tr = tv.VlmmTracker(ds, body, None, tv.VlmmOptions(
                model=str(root / "model.npz"), particles=40, layers=layers, max_depth=3,
                colour=False, lost_frames=0), np.random.default_rng(2))
            fits = []
            fit = tr.evidence.fit
            tr.evidence.fit = lambda poses: (fits.append(len(poses)), fit(poses))[1]
            tr.start(0, test[0])
            ests = [tr.step(f) for f in range(1, N_FRAMES)]
            assert [e.evaluations for e in ests] == [40 * layers] * len(ests)
            assert len(fits) == len(ests)  # one blob fit a frame, whatever the layers
            assert tr.prior.X.shape[0] == len(tr.P) == 40
            assert np.array_equal(tr.prior.X[:, :tr.prior._a], tr.P[:, tr.prior.idx])
            err[layers] = np.linalg.norm(body.joints(np.stack([e.params for e in ests]))
                                         - gt[1:], axis=2).mean()
    assert err[1] != err[3]
    assert err[3] < 0.75 * fixed, (err, fixed)
    for bad in ({"layers": 0}, {"alpha": 1.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            tv.VlmmOptions(model="m.npz", **bad).validate()
