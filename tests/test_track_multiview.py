"""Multi-view particle-filter trackers (Bandouch 2009) through the CLI, on a tiny rendered dataset.

The dataset is rendered with the CPU reference rasteriser (no GL, no simulator): 4 cameras of
128x96 around a person walking quickly (about 8 cm per frame at 15 frames/s) while raising an
arm and bending the knees.
"""
import json

import cv2
import numpy as np
import pytest

from gltrack.bench.multiview import RING, method_configs, render_dataset
from gltrack.bench.rigs import ring_cameras
from gltrack.body.model import BodyModel
from gltrack.cli import main
from gltrack.eval.metrics import EVAL_JOINTS, common_names, mean_joint_error

N_FRAMES = 5
FPS = 15.0


def motion(body, n):
    d, sk = body.dofs, body.skeleton
    t = np.arange(n) / FPS
    P = np.repeat(d.zero(sk)[None], n, axis=0)
    P[:, 2] += 1.2 * t
    P[:, 0] += 0.3 * t
    P[:, d.index("pelvis_ry")] = 0.4 * t
    P[:, d.index("l_shoulder_rz")] = -1.2 + 2.0 * t
    P[:, d.index("r_shoulder_rz")] = 1.2 - 1.0 * t
    P[:, d.index("l_elbow_ry")] = -0.3 - 1.5 * t
    P[:, d.index("l_hip_rx")] = -1.5 * t
    P[:, d.index("r_hip_rx")] = 1.0 * t
    P[:, d.index("l_knee_rx")] = 0.2 + 2.0 * t
    return d.validate(P)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    body = BodyModel.build()
    P = motion(body, N_FRAMES)
    out = tmp_path_factory.mktemp("mv") / "ds"
    cams = ring_cameras((0.1, 0.9, 0.2), **dict(RING, radius=3.0))
    render_dataset(out, body, P, cams, FPS, np.random.default_rng(3), mask_flip=0.002)
    return out, body, P


def _track(dataset_path, tmp_path, method, config, extra=("--init", "groundtruth"), seed=1):
    """Track through the CLI; by default from the true first pose (the tracking tests measure
    the filters, the automatic start has tests of its own)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    cfg = tmp_path / f"{method}.toml"
    cfg.write_text("\n".join(f"{k} = {json.dumps(v)}" for k, v in config.items()) + "\n")
    out = tmp_path / f"res_{method}"
    rc = main(["-q", "track", "--body", "dataset", str(dataset_path), "--method", method, "--out", str(out),
               "--config", str(cfg), "--seed", str(seed), *extra])
    assert rc == 0
    js = tmp_path / f"{method}.json"
    assert main(["-q", "eval", str(out), str(dataset_path), "--json", str(js)]) == 0
    metrics = json.loads(js.read_text())
    frames = [json.loads(line) for line in (out / "frames.jsonl").read_text().splitlines() if line]
    return metrics, frames


def _summary(metrics):
    return metrics.get("summary", metrics)["mean_joint_error_mm"]


def static_error_mm(body, P):
    """Mean joint error of holding the initial pose fixed (computed without the tracker)."""
    J = body.joints(P)
    names, ip, ig = common_names(body.skeleton.names, body.skeleton.names, EVAL_JOINTS)
    still = np.repeat(J[:1], len(J), axis=0)
    return 1000.0 * float(np.mean(mean_joint_error(still[:, ip], J[:, ig])))


def test_hps_tracks_better_than_standing_still(dataset, tmp_path):
    path, body, P = dataset
    static = static_error_mm(body, P)
    assert static > 120.0  # the motion is large enough for the comparison to mean something
    metrics, frames = _track(path, tmp_path, "hps", {"particles": 60, "tile": 64})
    err = _summary(metrics)
    assert err < 70.0, err
    assert err < 0.5 * static, (err, static)
    assert len(frames) == N_FRAMES
    # 60 particles: 6 torso layers, 8 limb layers, 1 re-weighting, + 1 for the estimate's score
    assert all(f["evaluations"] == 60 * 15 + 1 for f in frames), [f["evaluations"] for f in frames]


@pytest.mark.parametrize("method,config", [
    ("sir", {"particles": 200, "weights": "exp", "appearance": False}),
    ("apf", {"particles": 60, "layers": 4}),
    ("ps", {"particles": 40, "environment": False}),
])
def test_other_methods_run_and_count_evaluations(dataset, tmp_path, method, config):
    path, body, P = dataset
    metrics, frames = _track(path, tmp_path, method, config,
                             ["--frames", "0:3", "--init", "groundtruth"])
    per = {"sir": 200, "apf": 60 * 4, "ps": 40 * 10}[method]
    assert [f["evaluations"] for f in frames] == [per + 1] * 3
    # every frame records its per-camera IoU, and eval summarises it
    assert all(len(f["info"]["iou"]) == 4 for f in frames)
    assert metrics["quality"]["iou_frames"] == 3 and min(metrics["quality"]["iou_mean"]) > 0.4
    # Three frames cover too little motion for an accuracy ranking; it must not diverge though.
    assert _summary(metrics) < 150.0


def test_options_are_validated(dataset, tmp_path):
    path, _, _ = dataset
    cfg = tmp_path / "bad.toml"
    for text in ("nonsense = 3\n", "estimate = \"median\"\n", "particles = \"many\"\n", "tile = 48\n",
                 "sigma_scale = -1\n", "appearance_init = \"half\"\n", "prior_diffusion = -1\n",
                 "iou_tile = 48\n", "mesh_lod = 3\n", "arm_sweep = 1\n", "arm_sweep = -2\n",
                 "leg_sweep = 1\n"):
        cfg.write_text(text)
        rc = main(["-q", "track", "--body", "dataset", str(path), "--method", "hps", "--out", str(tmp_path / "o"),
                   "--config", str(cfg), "--overwrite"])
        assert rc == 1, text


def test_method_configs_share_the_budget():
    cfg = method_configs(2000, n_partitions=10)
    evals = {"sir": cfg["sir"][1]["particles"],
             "apf": cfg["apf"][1]["particles"] * cfg["apf"][1]["layers"],
             "ps": cfg["ps"][1]["particles"] * 10,
             "hps": cfg["hps"][1]["particles"] * 15}
    assert all(abs(v - 2000) <= 15 for v in evals.values()), evals
    assert cfg["hps/4"][1]["particles"] == cfg["hps"][1]["particles"] // 4


def test_background_subtraction_foreground_matches_silhouettes(dataset):
    from gltrack.data.dataset import Dataset
    from gltrack.observe.multiview import MultiviewObservation

    path, _, _ = dataset
    ds = Dataset.open(path)
    obs = MultiviewObservation(ds, "background", np.random.default_rng(0))
    assert obs.mode == "background"
    images, masks = obs(2)
    for c, m in enumerate(masks):
        gt = ds.gtmask(2, c)
        iou = np.count_nonzero(m & gt) / np.count_nonzero(m | gt)
        assert iou > 0.7, (c, iou)
    assert MultiviewObservation(ds, "auto", None).mode == "dataset"


def test_weights_follow_eq2_and_prefer_the_true_pose(dataset, ctx):
    from gltrack.data.dataset import Dataset
    from gltrack.sample import bandouch_weights
    from gltrack.track.multiview import HpsOptions, HPSTracker

    path, body, P = dataset
    ds = Dataset.open(path)
    tr = HPSTracker(ds, body, ctx, HpsOptions(particles=12), np.random.default_rng(0))
    try:
        tr.start(0, P[0])
        tr.observe(3)
        rng = np.random.default_rng(5)
        X = np.repeat(P[3][None], 8, axis=0)
        X[1:] += rng.normal(0.0, 0.15, X[1:].shape) * (np.arange(8)[1:, None] / 4.0)
        X = body.dofs.validate(X)
        e_s, c_a = tr.scores(X)
        w = tr.weights(X)
        np.testing.assert_allclose(w, bandouch_weights(e_s, c_a, 0.7, 0.3))
        assert np.argmax(w) == 0 and np.argmin(e_s) == 0
        tr.opt.weights = "exp"
        w2 = tr.weights(X)
        assert np.argmax(w2) == 0 and w2[0] == pytest.approx(np.max(w2))
        assert not np.allclose(w2 / w2.max(), w / w.max())
        # A different frame's observation changes the silhouette errors of the same poses.
        tr.observe(0)
        assert not np.array_equal(tr.scores(X)[0], e_s)
    finally:
        tr.close()


def test_mesh_lod_is_the_mesh_the_engine_scores(dataset, ctx):
    from gltrack.data.dataset import Dataset
    from gltrack.track.multiview import HpsOptions, HPSTracker

    path, body, P = dataset
    ds = Dataset.open(path)
    rng = np.random.default_rng(5)
    X = np.repeat(P[3][None], 8, axis=0)
    X[1:] += rng.normal(0.0, 0.15, X[1:].shape) * (np.arange(8)[1:, None] / 4.0)
    X = body.dofs.validate(X)
    e_s = {}
    for lod in (0, 1):
        tr = HPSTracker(ds, body, ctx, HpsOptions(particles=12, mesh_lod=lod),
                        np.random.default_rng(0))
        try:
            assert tr.engine.mesh is tr.body.mesh
            assert tr.body.mesh.n_faces == body.with_lod(lod).mesh.n_faces
            assert tr.body.skeleton is body.skeleton
            tr.start(0, P[0])
            tr.observe(3)
            e_s[lod] = tr.scores(X)[0]
        finally:
            tr.close()
    assert body.with_lod(0).mesh.n_faces < body.mesh.n_faces
    # the coarser surface still prefers the true pose (the data was drawn with lod 1) ...
    assert np.argmin(e_s[0]) == 0
    # ... and it is a different surface
    assert not np.allclose(e_s[0], e_s[1])


def test_early_annealing_layers_score_the_coarse_mesh(dataset, ctx, tmp_path):
    from gltrack.data.dataset import Dataset
    from gltrack.track.multiview import (AnnealedOptions, ApfOptions, APFTracker, HpsOptions,
                                         HPSTracker, uses_coarse_mesh)

    path, body, P = dataset
    ds = Dataset.open(path)
    assert uses_coarse_mesh("apf", ApfOptions()) and not uses_coarse_mesh("hps", HpsOptions())
    assert uses_coarse_mesh("hps", HpsOptions(fine_layers=1))
    assert not uses_coarse_mesh("apf", ApfOptions(layers=4, fine_layers=6))
    assert not uses_coarse_mesh("apf", ApfOptions(fine_layers=0))
    assert not uses_coarse_mesh("apf", ApfOptions(mesh_lod=0))  # already the coarsest
    assert not uses_coarse_mesh("ps", AnnealedOptions())
    assert uses_coarse_mesh("hps", HpsOptions(layers=1, limb_layers=1, joint_layers=2,
                                              fine_layers=1))
    assert not uses_coarse_mesh("hps", HpsOptions(layers=1, limb_layers=1, joint_layers=1,
                                                  fine_layers=1))
    # hps: its runs end on the fine mesh, the rest of them score the coarse one
    tr = HPSTracker(ds, body, ctx, HpsOptions(particles=30, layers=3, fine_layers=1),
                    np.random.default_rng(0))
    try:
        tr.start(0, P[0])
        fine0, coarse0 = tr.engine.evaluations, tr.likelihood.coarse_engine.evaluations
        tr.step(1)
        pipes = list(zip(tr.sampler.shares(30), tr.sampler.pipelines))
        # torso 2 coarse layers + 1 fine; every limb partition all but its last layer coarse;
        # the combination of the pipelines (and the estimate's record) fine
        assert tr.likelihood.coarse_engine.evaluations - coarse0 == 2 * 30 + sum(
            n * sum(k - 1 for k in p.layers) for n, p in pipes)
        assert tr.engine.evaluations - fine0 >= 30 + sum(n * len(p.layers) for n, p in pipes) + 30
    finally:
        tr.close()
    tr = APFTracker(ds, body, ctx, ApfOptions(particles=30, layers=4, fine_layers=1),
                    np.random.default_rng(0))
    try:
        coarse = tr.likelihood.coarse_engine
        assert coarse.mesh.n_faces == body.with_lod(0).mesh.n_faces < tr.engine.mesh.n_faces
        tr.start(0, P[0])
        fine0, coarse0 = tr.engine.evaluations, coarse.evaluations
        tr.step(1)
        assert coarse.evaluations - coarse0 == 3 * 30  # three layers of 30 on the coarse mesh
        assert tr.engine.evaluations - fine0 >= 30     # the last layer on the fine one
        # the coarse mesh sees this frame's masks and colours: it prefers the true pose, and
        # counts about as many colour-consistent pixels there as the fine mesh
        tr.observe(3)
        rng = np.random.default_rng(5)
        X = np.repeat(P[3][None], 8, axis=0)
        X[1:] += rng.normal(0.0, 0.15, X[1:].shape) * (np.arange(8)[1:, None] / 4.0)
        X = body.dofs.validate(X)
        e_f, c_f = tr.likelihood.scores(X)
        e_c, c_c = tr.likelihood.scores(X, coarse=True)
        assert np.argmin(e_c) == 0 and np.argmax(tr.coarse_weights(X)) == 0
        assert c_c[0] == pytest.approx(c_f[0], rel=0.15) and not np.array_equal(c_c, c_f)
        assert not np.array_equal(e_c, e_f)
    finally:
        tr.close()
    # ps has no coarse layers
    cfg = tmp_path / "c.toml"
    for method, text in (("ps", "fine_layers = 2\n"), ("apf", "fine_layers = -1\n")):
        cfg.write_text(text)
        rc = main(["-q", "track", "--body", "dataset", str(path), "--method", method, "--out",
                   str(tmp_path / "o"), "--config", str(cfg), "--overwrite"])
        assert rc == 1, (method, text)


def test_step_reports_per_camera_iou_of_the_estimate(dataset, ctx):
    """info["iou"], info["model_on_fg"], info["fg_covered"]: one value per camera, equal to the
    CPU rasteriser's counts against the foreground at the IoU tile (the tracking tile or a finer
    one); a worse pose scores lower."""
    from gltrack.data.dataset import Dataset
    from gltrack.render import reference as ref
    from gltrack.track.multiview import HpsOptions, HPSTracker

    path, body, P = dataset
    ds = Dataset.open(path)
    tr = HPSTracker(ds, body, ctx, HpsOptions(particles=12, layers=1, environment=False,
                                              iou_tile=128), np.random.default_rng(0))
    try:
        tr.start(0, P[0])
        est = tr.step(1)
        iou = est.info["iou"]
        for key in ("iou", "model_on_fg", "fg_covered"):
            v = est.info[key]
            assert len(v) == len(ds.cameras) and all(0.0 <= x <= 1.0 for x in v), key
        # the IoU is at most either share (its union is at least either area)
        assert all(i <= min(a, b) + 1e-9 for i, a, b in
                   zip(iou, est.info["model_on_fg"], est.info["fg_covered"]))
        assert est.info["quality"] == pytest.approx(est.score / tr.area)
        _, fgs, blocks = tr.observe(1)
        bad = body.dofs.validate(P[1] + 0.3 * (np.arange(P.shape[1]) % 3 == 0))[0]
        means = []
        for tile in (None, 128):
            for pose in (est.params, bad):
                got3 = tr.likelihood.silhouette_overlap(pose, tile)
                got = got3[0]
                np.testing.assert_array_equal(got, tr.likelihood.silhouette_iou(pose, tile))
                cams = [v.camera.scaled(tile or 64, tile or 64) for v in tr.engine.views]
                S = body.skinning(pose[None])
                want = []
                for c, k in enumerate(cams):
                    rz, _ = ref.render_candidates(body.mesh, S, k.K, k.R, k.t, k.width, k.height)
                    size = (k.width, k.height)
                    fg, bl = (cv2.resize(m.astype(np.uint8), size,
                                         interpolation=cv2.INTER_NEAREST_EXACT) > 0
                              for m in (fgs[c], blocks[c]))
                    want.append(ref.silhouette_overlap(rz[0], fg, bl))
                want = np.array(want).T  # (3, C)
                assert np.abs(got3 - want).max() < 0.03, (tile, got3, want)
                means.append(np.mean(got))
                if tile == 128 and pose is est.params:
                    for k, key in enumerate(("iou", "model_on_fg", "fg_covered")):
                        np.testing.assert_allclose(est.info[key], got3[k], atol=1e-4)
        assert means[1] < means[0] - 0.05 and means[3] < means[2] - 0.05, means
    finally:
        tr.close()
        ds.close()


# ---------------------------------------------------------------- behaviour prior (--prior vlmm)
@pytest.fixture(scope="module")
def periodic(tmp_path_factory):
    """A walk-like cycle in place (0.8 s period at 15 frames/s) and a behaviour model learnt from
    other cycles of the same motion."""
    from gltrack.bench.vlmm import periodic_motion
    from gltrack.motion.behaviour import BehaviourModel

    root = tmp_path_factory.mktemp("mv_prior")
    body = BodyModel.build()
    train = periodic_motion(body, 240, fps=FPS, period=0.8)
    model = BehaviourModel.fit(train, FPS, np.random.default_rng(0), holdout=0.0,
                               dof_names=body.dofs.names[6:])
    model.save(root / "model.npz")
    P = periodic_motion(body, 8, fps=FPS, phase=1.0, period=0.8)
    P[:, 0] += 0.1
    cams = ring_cameras((0.1, 0.9, 0.0), **dict(RING, radius=3.0))
    render_dataset(root / "ds", body, P, cams, FPS, np.random.default_rng(4), mask_flip=0.002)
    return root, body, P


def test_hps_with_the_vlmm_prior_tracks(periodic, tmp_path):
    """The median of three tracking seeds: with 40 particles one seed's error swings between
    0.4 and 1.1 times the static error (18 seeds, 2026-11-27), and a one-pixel change in the
    engine's triangle ids sends a seed elsewhere."""
    root, body, P = periodic
    static = static_error_mm(body, P)
    assert static > 60.0
    cfg = {"particles": 40, "prior": "vlmm", "prior_model": str(root / "model.npz")}
    errs = []
    for seed in (0, 1, 2):
        metrics, frames = _track(root / "ds", tmp_path / str(seed), "hps", cfg, seed=seed)
        errs.append(_summary(metrics))
        assert len(frames) == len(P)
        assert all(f["evaluations"] == 40 * 15 + 1 for f in frames)
    assert np.median(errs) < 0.8 * static, (errs, static)


def test_prior_option_is_validated(periodic, tmp_path, capsys):
    from gltrack.track.multiview import MultiviewOptions

    root, _, _ = periodic
    with pytest.raises(ValueError, match="prior_model"):
        MultiviewOptions(prior="vlmm").validate()
    with pytest.raises(ValueError, match="prior"):
        MultiviewOptions(prior="kalman").validate()
    cfg = tmp_path / "p.toml"
    for text, needle in (("prior = \"vlmm\"\n", "prior_model"),
                         ("prior = \"vlmm\"\nprior_model = "
                          f"{json.dumps(str(tmp_path / 'no.npz'))}\n", "no.npz")):
        cfg.write_text(text)
        rc = main(["-q", "track", "--body", "dataset", str(root / "ds"), "--method", "hps", "--out", str(tmp_path / "o"),
                   "--config", str(cfg), "--overwrite"])
        assert rc == 1 and needle in capsys.readouterr().err, text


def test_sigma_scale_and_full_resolution_appearance(dataset, ctx):
    """sigma_scale scales the motion model's noise (0: square-root scaling of the 30 fps sigmas
    with the frame rate); the default appearance initialisation at
    camera resolution gives colours to many more triangles than sampling the 64-pixel tiles."""
    from gltrack.data.dataset import Dataset
    from gltrack.track.multiview import AnnealedOptions, HpsOptions, HPSTracker, make_sampler

    path, body, P = dataset
    a, _ = make_sampler("hps", body.dofs, FPS, HpsOptions())
    b, _ = make_sampler("ps", body.dofs, FPS, AnnealedOptions(sigma_scale=0.7))
    c, _ = make_sampler("hps", body.dofs, FPS, HpsOptions(sigma_scale=0))
    np.testing.assert_allclose(a.space.sigma, body.dofs.sigma_at(FPS))
    np.testing.assert_allclose(b.space.sigma, 0.7 * body.dofs.sigma_at(FPS))
    np.testing.assert_allclose(c.space.sigma, body.dofs.sigma30 * np.sqrt(30.0 / FPS))
    ds = Dataset.open(path)
    seen = {}
    for init in ("tile", "full"):
        tr = HPSTracker(ds, body, ctx, HpsOptions(particles=6, tile=16, appearance_init=init),
                        np.random.default_rng(0))
        try:
            tr.start(0, P[0])
            seen[init] = np.unique(tr.appearance._tri).size
        finally:
            tr.close()
    assert seen["full"] > 3 * seen["tile"] > 0, seen


def test_particles_and_layers_flags(dataset, tmp_path, capsys):
    """--particles / --layers set the sampler budget; flags that do not apply are usage errors."""
    path = dataset[0]
    out = tmp_path / "apf_flags"
    assert main(["-q", "track", "--body", "dataset", str(path), "--method", "apf", "--out", str(out), "--particles", "30",
                 "--layers", "3", "--frames", "0:2"]) == 0
    frames = [json.loads(line) for line in (out / "frames.jsonl").read_text().splitlines()]
    assert all(f["evaluations"] == 30 * 3 + 1 for f in frames), [f["evaluations"] for f in frames]
    for extra in (["--method", "hc", "--particles", "10"], ["--method", "sir", "--layers", "3"],
                  ["--method", "hps", "--particles", "0"], ["--method", "hc", "--behaviour", "m.npz"]):
        assert main(["track", str(path), "--out", str(tmp_path / "bad"), *extra]) == 2
    assert "does not apply" in capsys.readouterr().err


@pytest.mark.parametrize("turn, shift", [(0.0, 0.0), (np.pi / 2, 0.0), (-2.5, 0.7)])
def test_auto_init_finds_a_turned_and_shifted_body(tmp_path, ctx, turn, shift):
    """--init auto without any pose: the library search on the visual hull plus the sampler's
    refinement lands within a few centimetres of the truth, whichever way the body faces and
    wherever it stands; a start at the rest pose in the middle would be far off."""
    from gltrack.data.dataset import Dataset
    from gltrack.track.multiview import HpsOptions, HPSTracker

    body = BodyModel.build()
    P = motion(body, 1)
    P[:, body.dofs.index("pelvis_ry")] += turn
    P[:, 0] += shift
    cams = ring_cameras((0.1, 0.9, 0.2), **dict(RING, radius=3.0))
    render_dataset(tmp_path / "ds", body, P, cams, FPS, np.random.default_rng(3), mask_flip=0.002)
    ds = Dataset.open(tmp_path / "ds")
    tr = HPSTracker(ds, body, ctx, HpsOptions(particles=100), np.random.default_rng(0))
    try:
        x = tr.auto_init(0)
    finally:
        tr.close()
    err = np.linalg.norm(body.joints(x[None])[0] - body.joints(P)[0], axis=1).mean()
    naive = np.linalg.norm(body.joints(body.dofs.zero(body.skeleton)[None])[0]
                           - body.joints(P)[0], axis=1).mean()
    yaw = body.dofs.index("pelvis_ry")
    assert err < 0.06, (err, naive)
    assert abs(np.angle(np.exp(1j * (x[yaw] - P[0, yaw])))) < 0.35
    assert naive > 0.1


def test_auto_init_without_a_person_names_the_frame(tmp_path, ctx):
    from gltrack.data.dataset import Dataset
    from gltrack.track.multiview import HpsOptions, HPSTracker

    body = BodyModel.build()
    P = motion(body, 1)
    P[:, 0] += 30.0  # far outside every camera's view
    cams = ring_cameras((0.1, 0.9, 0.2), **dict(RING, radius=3.0))
    render_dataset(tmp_path / "ds", body, P, cams, FPS, np.random.default_rng(3))
    ds = Dataset.open(tmp_path / "ds")
    tr = HPSTracker(ds, body, ctx, HpsOptions(particles=20), np.random.default_rng(0))
    try:
        with pytest.raises(ValueError, match="frame 0: .*no person"):
            tr.auto_init(0)
    finally:
        tr.close()


def test_a_track_that_explained_the_person_away_is_not_a_good_fit(dataset, ctx):
    """A colour model learnt off the person (the background's colours) makes the environment
    layers remove the person's foreground; with the body then out of every view the XOR is
    zero. The frame's quality must still say lost (at least the share of foreground removed)
    and the IoU of a camera with neither model nor foreground is missing, not perfect."""
    from gltrack.data.dataset import Dataset
    from gltrack.track.multiview import HpsOptions, HPSTracker

    path, body, P = dataset
    tr = HPSTracker(Dataset.open(path), body, ctx, HpsOptions(particles=12, layers=1, iou_tile=128),
                    np.random.default_rng(0))
    try:
        tr.start(0, P[0])
        good = tr.step(1).info
        assert good["foreground_kept"] > 0.9
        images, masks = tr.obs(1)
        beside = P[1].copy()
        beside[0] += 1.5
        tr.likelihood.init_appearance(beside, images, masks)  # learns the background's colours
        gone = P[1].copy()
        gone[0] += 50.0  # out of every camera
        tr.particles[:] = gone
        info = tr.step(2).info
        assert info["foreground_kept"] < 0.05 and info["e_s"] < 0.05 * good["e_s"] + 1, info
        assert info["quality"] >= 0.95 > tr.lost_quality
        assert any(v is None for v in info["iou"]), info["iou"]
        assert all(v is None or 0.0 <= v <= 1.0 for v in info["iou"])
    finally:
        tr.close()


def test_a_start_pose_that_left_the_person_is_not_used():
    """Masks that miss much of the person (a still torso) let a model out of view score well;
    the automatic start keeps only refined poses near where they were placed, unless none is."""
    from gltrack.track.multiview import near_home

    X = np.zeros((4, 8))
    X[:, 0] = [0.1, 3.0, -0.4, 12.0]  # root x, metres from the hull at 0
    cost = np.array([50.0, 10.0, 40.0, 5.0])
    kept, c = near_home(X, cost, np.zeros(3), 1.0)
    assert kept[:, 0].tolist() == [0.1, -0.4] and c.tolist() == [50.0, 40.0]
    far = X[[1, 3]]
    assert near_home(far, cost[[1, 3]], np.zeros(3), 1.0)[0] is far  # nothing near: all kept




def test_auto_init_tries_the_other_leg_forward(tmp_path, ctx, monkeypatch):
    """A walker in mid-stride (left leg and right arm forward) and a pose library that holds
    only the mirror-image stride: the refinement keeps the wrong leg forward, and only the
    start's limb exchange (each heading's best refined pose mirrored and refined again) offers
    the right one among the start hypotheses. Without the exchange no hypothesis has it."""
    import gltrack.track.multiview as mv
    from gltrack.data.dataset import Dataset
    from gltrack.sample.partitions import exchange_limbs, limb_pairs

    from trackdata import legs_right_way, mid_stride

    body = BodyModel.build()
    d = body.dofs
    P = mid_stride(body)
    mirror = d.validate(exchange_limbs(P, limb_pairs(d)))
    monkeypatch.setattr(mv, "canonical_poses", lambda dofs, skeleton=None: (["stride"], mirror))
    cams = ring_cameras((0.1, 0.9, 0.2), **dict(RING, radius=3.0))
    render_dataset(tmp_path / "ds", body, P, cams, FPS, np.random.default_rng(3), mask_flip=0.002)
    want = body.joints(P)[0]

    def right_way(x):
        return legs_right_way(body, x, P[0])

    def hypotheses():
        # one heading, the true one (and its turned-round twin): only the legs are in question
        tr = mv.HPSTracker(Dataset.open(tmp_path / "ds"), body, ctx,
                           mv.HpsOptions(particles=100, init_headings=1), np.random.default_rng(0))
        try:
            return tr.start_hypotheses(0)
        finally:
            tr.close()

    found = [x for x in hypotheses() if right_way(x)]
    assert found
    assert min(np.linalg.norm(body.joints(x[None])[0] - want, axis=1).mean() for x in found) < 0.12
    monkeypatch.setattr(mv, "limb_pairs", lambda dofs: [])  # the start without the exchange
    assert not any(right_way(x) for x in hypotheses())



def _raised_leg_dataset(path):
    """A rendered subject standing on its left leg, the right thigh raised forward and the
    knee bent (2 frames, 4 cameras): (body, poses (2, D), true joints (B, 3), right knee's
    index)."""
    body = BodyModel.build()
    d, sk = body.dofs, body.skeleton
    P = np.repeat(d.zero(sk)[None], 2, axis=0)
    P[:, d.index("r_hip_rx")] = -1.4
    P[:, d.index("r_knee_rx")] = 1.4
    P = d.validate(P)
    knee = sk.index("r_knee")
    want = body.joints(P[:1])[0]
    assert want[knee, 1] > want[sk.index("l_knee"), 1] + 0.3  # the premise: the leg is raised
    cams = ring_cameras((0.1, 0.9, 0.2), **dict(RING, radius=3.0))
    render_dataset(path, body, P, cams, FPS, np.random.default_rng(3), mask_flip=0.002)
    return body, P, want, knee


def test_auto_init_limb_sweep_finds_a_raised_leg(tmp_path, ctx):
    """The subject stands on its left leg with the right thigh raised forward and the knee
    bent. Refined from the library's standing poses, the start leaves that leg hanging (knee
    over 0.3 m off); the start's limb sweep (each heading's best pose with every limb swept
    over a grid and refined again) finds it: knee within 0.1 m in the best hypothesis."""
    import gltrack.track.multiview as mv
    from gltrack.data.dataset import Dataset

    body, P, want, knee = _raised_leg_dataset(tmp_path / "ds")

    def knee_errors(sweep):
        # one heading, the true one (and its turned-round twin): only the limbs are in question
        opt = mv.HpsOptions(particles=100, init_headings=1, init_limb_sweep=sweep)
        tr = mv.HPSTracker(Dataset.open(tmp_path / "ds"), body, ctx, opt,
                           np.random.default_rng(0))
        try:
            H = tr.start_hypotheses(0)
        finally:
            tr.close()
        return [np.linalg.norm(body.joints(x[None])[0, knee] - want[knee]) for x in H]

    off, on = knee_errors(0), knee_errors(10)
    assert min(off) > 0.3, off
    assert on[0] < 0.1, on


def _check_sweep(ds_path, body, ctx, start, want, joint, option, swept, grids, far, near,
                 **fixed):
    """Step ``hps`` (40 particles, ``fixed`` options) once from ``start`` on frame 0 of
    ``ds_path`` with the sweep ``option`` off and at 10: without it the estimate's ``joint``
    stays more than ``far`` metres from ``want`` (3,), with it it comes within ``near``, the
    frame records ``swept`` as swept, the particles move with it, and the sweep costs one
    evaluation per point of ``grids`` plus one per limb."""
    import gltrack.track.multiview as mv
    from gltrack.data.dataset import Dataset

    def step(points):
        opt = mv.HpsOptions(particles=40, **{option: points}, **fixed)
        tr = mv.HPSTracker(Dataset.open(ds_path), body, ctx, opt, np.random.default_rng(0))
        try:
            tr.start(0, start)
            est = tr.step(1)
            spread = np.linalg.norm(body.joints(tr.particles)[:, joint] - want, axis=1)
        finally:
            tr.close()
        return np.linalg.norm(body.joints(est.params[None])[0, joint] - want), est, spread

    off, est_off, _ = step(0)
    on, est_on, spread = step(10)
    assert off > far, off
    assert on < near, on
    assert swept in est_on.info["limb_sweep"] and "limb_sweep" not in est_off.info
    assert np.median(spread) < 0.25, np.median(spread)  # the particles moved with it
    assert est_on.evaluations - est_off.evaluations == sum(len(g) + 1 for _, _, g in grids)


def test_leg_sweep_finds_a_raised_leg_the_particles_left_hanging(tmp_path, ctx):
    """The tracker starts from the raised-leg subject's pose with that leg hanging (thigh 1.4
    rad and knee 1.4 rad away). With the per-frame leg sweep the first step's estimate raises
    it (knee within 0.12 m) and the particles follow; without it the knee stays off."""
    import gltrack.track.multiview as mv

    body, P, want, knee = _raised_leg_dataset(tmp_path / "ds")
    d = body.dofs
    start = P[0].copy()
    start[[d.index("r_hip_rx"), d.index("r_knee_rx")]] = 0.0  # hanging

    _check_sweep(tmp_path / "ds", body, ctx, start, want[knee], knee, "leg_sweep", "r_hip",
                 mv.limb_grid(d, 10, limbs=mv.LEGS), far=0.3, near=0.12)


def test_arm_sweep_finds_a_raised_arm_the_particles_left_hanging(tmp_path, ctx):
    """The subject holds its right arm up; the tracker starts with it hanging (2 rad away, far
    beyond what one step's diffusion reaches). With the arm sweep the first step's estimate
    raises it (wrist within 0.15 m) and the particles follow; without it the wrist stays off."""
    import gltrack.track.multiview as mv

    body = BodyModel.build()
    d, sk = body.dofs, body.skeleton
    P = np.repeat(d.zero(sk)[None], 2, axis=0)
    P[:, d.index("l_shoulder_rz")] = -1.2
    P[:, d.index("r_shoulder_rz")] = -0.6
    P = d.validate(P)
    wrist, shoulder = sk.index("r_wrist"), sk.index("r_shoulder")
    J = body.joints(P[:1])[0]
    assert J[wrist, 1] > J[shoulder, 1] + 0.2  # the premise: the arm is raised
    cams = ring_cameras((0.1, 0.9, 0.2), **dict(RING, radius=3.0))
    render_dataset(tmp_path / "ds", body, P, cams, FPS, np.random.default_rng(3), mask_flip=0.002)
    start = P[0].copy()
    start[d.index("r_shoulder_rz")] = 1.2  # hanging

    _check_sweep(tmp_path / "ds", body, ctx, start, J[wrist], wrist, "arm_sweep", "r_shoulder",
                 mv.arm_grid(d, 10), far=0.4, near=0.15)


def test_a_recording_without_a_floor_is_searched_round_the_cameras_gaze(dataset, tmp_path):
    """A calibration's origin need not lie on the floor (caliscope's lies where the board lay:
    on the seated take, at head height), so a recording whose floor is unknown is searched in a
    3 m cube round the cameras' gaze, not from the origin up. The test take with its world
    origin moved 1 m up: the visual hull in that cube holds the whole body, the one in the
    floor-based volume only what is above the new origin. A synthetic dataset (no ``world``
    record) keeps its floor at 0, a recorded floor is kept as it is."""
    import shutil
    from dataclasses import replace

    from gltrack.data.dataset import Dataset
    from gltrack.observe.blob_evidence import default_volume
    from gltrack.observe.voxels import carve

    path, body, P = dataset
    ds = Dataset.open(path)
    assert ds.assumed_floor() == 0.0
    up = np.array([0.0, 1.0, 0.0])  # X_world' = X_world - up, so t' = t + R @ up
    cams = [replace(c, t=c.t + c.R @ up) for c in ds.cameras]
    masks = [ds.mask(0, k) for k in range(len(cams))]
    tall = body.joints(P[0][None])[0, :, 1].max() - body.joints(P[0][None])[0, :, 1].min()

    def hull_height(volume):
        pts, vol = carve(cams, masks, volume, base=16, max_depth=2, distort=False).points(0.06)
        return pts[:, 1].max() - pts[:, 1].min() + np.cbrt(vol.min())

    cube = default_volume(cams, None)
    assert cube[4] - cube[1] == pytest.approx(3.0) and cube[1] < -1.0 < 0.0 < cube[4]
    assert hull_height(cube) > tall
    assert hull_height(default_volume(cams, 0.0)) < 0.6 * tall
    for floor in (None, 0.3):
        moved = tmp_path / f"floor_{floor}"
        shutil.copytree(path, moved)
        meta = json.loads((moved / "meta.json").read_text())
        meta["world"] = {"up": "y", "R_user_from_internal": np.eye(3).tolist(), "floor": floor}
        (moved / "meta.json").write_text(json.dumps(meta))
        assert Dataset.open(moved).assumed_floor() == floor


def test_ground_contact_weighs_down_a_floating_pose(dataset, ctx, tmp_path):
    """``ground_contact``: a pose lifted 0.3 m off the ground the cameras see the person on is
    weighted as if its silhouette error were ``area * (excess / GROUND_SCALE)`` pixels larger
    (its lowest joint's height over the reference beyond the allowance), a pose standing within
    the allowance as before. The reference is the bottom of the frame's visual hull, put down
    to the floor when the dataset records one within reach; a dataset without a floor still has
    the hull's. Off (0), nothing changes."""
    import shutil

    from gltrack.data.dataset import Dataset
    from gltrack.sample import bandouch_weights
    from gltrack.track.multiview import HpsOptions, HPSTracker

    path, body, P = dataset
    lowest = body.joints(P[3][None])[0, :, 1].min()
    floored = tmp_path / "ds"
    shutil.copytree(path, floored)
    meta = json.loads((floored / "meta.json").read_text())
    meta["world"] = {"up": "y", "R_user_from_internal": np.eye(3).tolist(),
                     "floor": float(lowest - 0.05)}  # the true pose 5 cm above it
    (floored / "meta.json").write_text(json.dumps(meta))
    # the true pose, lifted 0.3 m, shifted 0.2 m sideways (the lifted one explains the
    # silhouettes better: 707 against 915 pixels of XOR when this was written)
    X = np.repeat(P[3][None], 3, axis=0)
    X[1, body.dofs.index("pelvis_ty")] += 0.3
    X[2, body.dofs.index("pelvis_tx")] += 0.2

    def weigh(ds_path, contact):
        tr = HPSTracker(Dataset.open(ds_path), body, ctx,
                        HpsOptions(particles=12, ground_contact=contact), np.random.default_rng(0))
        try:
            tr.start(0, P[0])
            _, fgs, blocks = tr.observe(3)
            tr.observe_ground([f | b for f, b in zip(fgs, blocks)])
            return tr.weights(X), tr.scores(X), tr.area, tr.ground
        finally:
            tr.close()

    w_off, (e_s, c_a), area, ground = weigh(floored, 0.0)
    assert ground is None
    w_on, (e_s2, c_a2), area2, ground = weigh(floored, 0.1)
    reference, allowance = ground
    assert reference == pytest.approx(lowest - 0.05)  # the hull reaches the floor: on it
    assert 0.1 < allowance < 0.2  # ground_contact plus a voxel edge
    np.testing.assert_array_equal(e_s2, e_s)  # the silhouette error itself is unchanged
    excess = np.clip(np.array([0.05, 0.35, 0.05]) - allowance, 0.0, None)
    want = bandouch_weights(e_s + area2 * excess / HPSTracker.GROUND_SCALE, c_a, 0.7, 0.3)
    np.testing.assert_allclose(w_on, want, rtol=1e-9)
    assert np.argmax(w_off) == np.argmax(w_on) == 0
    assert w_off[1] > w_off[2] and w_on[1] < w_on[2], (w_off, w_on)  # the floating one drops
    # no floor recorded: the hull's bottom (the soles, within a voxel) is the reference
    w_hull, _, _, ground = weigh(path, 0.1)
    assert lowest - 0.15 < ground[0] < lowest
    assert w_hull[1] < w_hull[2], w_hull
    with pytest.raises(ValueError, match="ground_contact"):
        HpsOptions(ground_contact=-0.1).validate()


def test_ground_contact_follows_a_jump(dataset, ctx):
    """Masks of a body 0.5 m in the air (a jump) lift the reference with it: the airborne pose
    costs (next to) nothing, whatever the floor; masks that do not meet give no reference."""
    from gltrack.data.dataset import Dataset
    from gltrack.observe.model_masks import model_silhouette
    from gltrack.render.reference import skin_vertices
    from gltrack.track.multiview import HpsOptions, HPSTracker

    path, body, P = dataset
    jump = P[3].copy()
    jump[body.dofs.index("pelvis_ty")] += 0.5
    lowest = body.joints(jump[None])[0, :, 1].min()
    tr = HPSTracker(Dataset.open(path), body, ctx, HpsOptions(particles=12, ground_contact=0.1),
                    np.random.default_rng(0))
    try:
        tr.floor = float(body.joints(P[3][None])[0, :, 1].min() - 0.05)
        tr.observe(3)
        V = skin_vertices(body.mesh, body.skinning(jump[None]))[0]
        masks = [model_silhouette(cam, V, body.mesh.faces) for cam in tr.obs.pinholes]
        tr.observe_ground(masks)
        assert tr.ground is not None and tr.ground[0] > tr.floor + 0.3
        assert tr.ground[0] < lowest
        high = jump.copy()
        high[body.dofs.index("pelvis_ty")] += 0.4
        assert tr.ground_cost(high[None])[0] > 0.0
        # nothing, or the price of a few centimetres: the coarse hull (5 cm voxels, one camera
        # may miss one) can reach below the soles (here by one and a half voxels), and then
        # the ankle ends up just past the allowance (Intel Xeon VM: 0; AMD EPYC VM: 2.3 cm
        # past it, 34 px against 633 px for the pose 0.4 m higher)
        assert tr.ground_cost(jump[None])[0] < 0.1 * tr.ground_cost(high[None])[0]
        tr.observe_ground([np.zeros_like(m) for m in masks])
        assert tr.ground is None and tr.ground_cost(high[None]) == 0.0
    finally:
        tr.close()
