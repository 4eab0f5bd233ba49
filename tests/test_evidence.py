"""Evidence propagation: interest points, patch features, part classifier, UT-IK and the EP loop."""
import subprocess
import sys
import time
from argparse import ArgumentParser

import numpy as np
import pytest
from scipy.optimize import least_squares

from gltrack.body.dofs import make_dofs
from gltrack.body.kinematics import Kinematics
from gltrack.body.mesh import make_body_mesh
from gltrack.body.skeleton import default_skeleton
from gltrack.camera import look_at_camera
from gltrack.evidence import classifier as C
from gltrack.evidence.associate import evidence_propagation, prune_explained
from gltrack.evidence.detect import foreground_mask, geodesic_extrema
from gltrack.evidence.features import GEOMETRY, n_features, patch_features
from gltrack.evidence.ik import chain_dofs, part_chains, ut_ik
from gltrack.evidence.parts import PART_CLASSES, PART_NAMES, Detections, PartModel
from gltrack.evidence.synthetic import default_depth_camera, render_frames
from gltrack.render.reference import render_candidates
from gltrack.sample.hillclimb import hill_climb, hill_climb_lanes


@pytest.fixture(scope="module")
def body():
    sk = default_skeleton()
    dofs = make_dofs(sk, "full")
    kin = Kinematics(sk, dofs)
    return sk, dofs, kin, PartModel(kin), make_body_mesh(sk, lod=1)


def _pose(dofs, sk, **angles):
    x = dofs.zero(sk)
    for k, v in angles.items():
        x[dofs.index(k)] = v
    return x


def _render(body, x, cam):
    sk, dofs, kin, pm, mesh = body
    S = kin.skinning_matrices(x[None], dtype=np.float64)
    return render_candidates(mesh, S, cam.K, cam.R, cam.t, cam.width, cam.height)[0][0]


# ------------------------------------------------------------------------------------------
# interest points


def _plate_camera():
    return look_at_camera("d", [0, 0, 2.0], [0, 0, 0], 160, 120, 45.0, kind="depth")


def test_geodesic_extrema_of_a_strip_are_its_ends():
    cam = _plate_camera()
    z = np.zeros((120, 160))
    z[58:61, 20:101] = 2.0  # 81 x 3 pixel strip, fronto-parallel, 2 m away
    ip = geodesic_extrema(z, cam, k=2)
    assert len(ip) == 2
    assert sorted(np.round(ip.pixels[:, 0])) == [20, 100]
    s = 2.0 / cam.fx  # metres per pixel at 2 m
    np.testing.assert_allclose(ip.centre_distance, 40 * s, rtol=0.02)
    np.testing.assert_allclose(ip.geodesic, 40 * s, rtol=0.02)
    # the world points are the back-projected pixels (camera at z=+2 looking at the origin)
    np.testing.assert_allclose(ip.points[:, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(ip.points[:, 0]), np.abs(ip.pixels[:, 0] - cam.cx) * s,
                               rtol=1e-9)
    np.testing.assert_allclose(np.abs(ip.points[:, 1]), np.abs(ip.pixels[:, 1] - cam.cy) * s,
                               rtol=1e-9)
    # direction to the centre points back along the strip
    assert np.all(np.abs(ip.direction[:, 0]) > 0.98)


def test_depth_discontinuities_cut_the_graph():
    cam = _plate_camera()
    z = np.zeros((120, 160))
    z[58:61, 20:101] = 2.0
    z[61:70, 60:70] = 2.5  # a smaller blob just below, 50 cm further away
    cut = geodesic_extrema(z, cam, k=3, max_gap=0.0)
    assert cut.n_pixels == 243  # only the strip (243 px) is larger than the blob (90 px)
    assert geodesic_extrema(z, cam, k=3).n_pixels == 243  # 50 cm is too far to link
    joined = geodesic_extrema(z, cam, k=3, max_edge=1.0, max_gap=0.0)
    assert joined.n_pixels == 243 + 90
    linked = geodesic_extrema(z, cam, k=3, max_gap=0.6)
    assert linked.n_pixels == 243 + 90
    # through the link (>= 50 cm long) the blob's far corner becomes the farthest point
    assert linked.geodesic[0] > 0.5 + cut.geodesic[1] * 0.5
    fg = foreground_mask(z, background=np.full_like(z, 2.5))
    assert fg.sum() == 243  # background subtraction removes the far blob


def test_body_extrema_are_the_five_part_tips(body):
    sk, dofs, kin, pm, mesh = body
    cam = default_depth_camera()
    x = _pose(dofs, sk, l_shoulder_rz=-0.6, r_shoulder_rz=0.3, l_hip_rz=0.25, r_hip_rz=-0.25)
    z = _render(body, x, cam)
    t0 = time.perf_counter()
    ip = geodesic_extrema(z, cam, k=7)
    dt = time.perf_counter() - t0
    parts = pm.positions(x)[0]
    d = np.linalg.norm(ip.points[:5, None] - parts[None], axis=2)
    assert sorted(d.argmin(1)) == [0, 1, 2, 3, 4]  # one extremum per part
    assert d.min(1).max() < 0.08
    assert np.all(np.diff(ip.geodesic) <= 1e-12)  # AGEX scores never increase
    assert dt < 0.5


def test_patches_are_invariant_to_camera_roll(body):
    sk, dofs, kin, pm, mesh = body
    x = _pose(dofs, sk, l_shoulder_rz=-0.4, r_elbow_ry=1.0)
    cam = look_at_camera("d", [0, 1.0, 3.5], [0, 0.95, 0], 128, 128, 45.0, kind="depth")
    # the same camera rolled by 90 degrees about its optical axis: the image rotates with it
    roll = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    cam2 = look_at_camera("d", [0, 1.0, 3.5], [0, 0.95, 0], 128, 128, 45.0, kind="depth")
    from dataclasses import replace
    cam2 = replace(cam2, R=roll @ cam.R, t=roll @ cam.t)
    z1, z2 = _render(body, x, cam), _render(body, x, cam2)
    ip1, ip2 = geodesic_extrema(z1, cam, k=5), geodesic_extrema(z2, cam2, k=5)
    F1 = patch_features(z1, cam, ip1)
    F2 = patch_features(z2, cam2, ip2)
    assert F1.shape == (5, n_features(12)) and F1.dtype == np.float32
    # match extrema by world position (both images see the same surface)
    m = np.linalg.norm(ip1.points[:, None] - ip2.points[None], axis=2).argmin(1)
    P1, P2 = F1[:, :144], F2[m, :144]
    assert np.mean(np.abs(P1 - P2)) < 0.06
    # control: without the orientation the rolled patches differ
    ip2.direction[:] = ip1.direction[np.argsort(m)]
    F2_fixed = patch_features(z2, cam2, ip2)[m, :144]
    assert np.mean(np.abs(P1 - F2_fixed)) > 2 * np.mean(np.abs(P1 - P2))
    assert len(GEOMETRY) == F1.shape[1] - 144


# ------------------------------------------------------------------------------------------
# classifier


@pytest.fixture(scope="module")
def trained():
    rng = np.random.default_rng(7)
    model, report = C.train_default_model(rng, n_frames=160, heldout=0.25)
    return model, report


def test_label_points_nearest_part_within_radius():
    parts = np.array([[0, 1.8, 0], [0.8, 1.4, 0], [-0.8, 1.4, 0], [0.1, 0, 0.1], [-0.1, 0, 0.1]])
    pts = np.array([[0, 1.75, 0], [0.75, 1.4, 0], [-0.1, 0.05, 0.1], [0, 1.0, 0], [0.8, 1.55, 0]])
    np.testing.assert_array_equal(C.label_points(pts, parts, 0.1), [1, 2, 3, 0, 0])
    parts[1] = np.nan  # unknown parts label nothing
    np.testing.assert_array_equal(C.label_points(pts, parts, 0.1), [1, 0, 3, 0, 0])


def test_default_model_precision_recall(trained):
    model, report = trained
    assert set(report) == {"head", "hand", "foot"}
    for cls, r in report.items():
        assert r["support"] > 10, cls
        assert r["precision"] >= 0.8, (cls, r)
        assert r["recall"] >= 0.8, (cls, r)
        assert r["found"] >= 0.6, (cls, r)


def test_detect_finds_parts_on_a_new_frame(trained, body):
    model, _ = trained
    sk, dofs, kin, pm, mesh = body
    cam = default_depth_camera()
    x = _pose(dofs, sk, l_shoulder_rz=-0.2, r_shoulder_rz=0.9, r_elbow_ry=1.2, l_hip_rx=-0.5,
              l_knee_rx=0.6)
    z = _render(body, x, cam)
    det = model.detect(z, cam)
    assert isinstance(det, Detections) and len(det) >= 4
    parts = pm.positions(x)[0]
    for p, c in zip(det.points, det.classes):
        i = int(np.argmin(np.linalg.norm(parts - p, axis=1)))
        assert PART_CLASSES[PART_NAMES[i]] == c
    assert np.all(det.confidence >= model.min_confidence)


def test_model_roundtrip_and_validation(trained, tmp_path):
    model, _ = trained
    path = tmp_path / "parts.npz"
    model.save(path)
    back = C.PartClassifier.load(path)
    X = np.random.default_rng(3).normal(size=(50, model.W.shape[1]))
    np.testing.assert_array_equal(back.predict_proba(X), model.predict_proba(X))
    assert back.config == model.config
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    bad = dict(arrays, W=arrays["W"][:, :-1])
    np.savez(tmp_path / "bad.npz", **bad)
    with pytest.raises(ValueError, match=r"bad\.npz.*'W'"):
        C.PartClassifier.load(tmp_path / "bad.npz")
    np.savez(tmp_path / "obj.npz", **dict(arrays, classes=np.array([{"a": 1}], dtype=object)))
    with pytest.raises(ValueError, match=r"obj\.npz"):
        C.PartClassifier.load(tmp_path / "obj.npz")
    with pytest.raises(ValueError, match="missing"):
        C.PartClassifier.load(tmp_path / "nope.npz")


def test_learn_parts_command_on_a_dataset(body, tmp_path, capsys):
    from gltrack.cli import learn_parts
    from gltrack.data.dataset import DatasetWriter

    sk, dofs, kin, pm, mesh = body
    rng = np.random.default_rng(11)
    frames = render_frames(rng, 24)
    cam = frames[0].camera
    with DatasetWriter(tmp_path / "ds", "depth", 30, [cam]) as w:
        for i, fr in enumerate(frames):
            w.write_depth(i, 0, fr.depth)
        parts = np.stack([fr.parts for fr in frames])
        w.write_groundtruth(parts, list(PART_NAMES), parts=parts, part_names=list(PART_NAMES))
    p = ArgumentParser()
    learn_parts.add_arguments(p)
    out = tmp_path / "parts.npz"
    args = p.parse_args(["--data", str(tmp_path / "ds"), "--out", str(out), "--heldout", "0.25",
                         "--json", str(tmp_path / "r.json")])
    assert learn_parts.run(args) == 0
    text = capsys.readouterr().out
    assert "held-out frames" in text and "hand" in text
    model = C.PartClassifier.load(out)
    assert model.label_radius == pytest.approx(0.10)
    import json
    rep = json.loads((tmp_path / "r.json").read_text())["report"]
    assert rep["foot"]["parts"] == 12  # 6 held-out frames x 2 feet
    assert learn_parts.NAME == "learn-parts"


def test_nearest_part_rule_does_not_swap_limbs(body, ep_problem):
    sk, dofs, kin, pm, mesh = body
    x_true, x0, cost, hc, sig = ep_problem
    x_hc, c_hc, _ = hc(x0)
    parts = pm.positions(x_hc)[0]
    # a "foot" detection 20 cm right of the right foot (not explained: beyond the prune radius)
    det = [(parts[4] + [-0.2, 0.0, 0.0], "foot")]
    kw = dict(sigma=5 * sig, chains=part_chains(sk, dofs), lower=dofs.lower, upper=dofs.upper,
              cost_best=c_hc, max_passes=1)
    calls = []

    def spy(x, part=None):  # a real climb; records which foot the IK moved
        moved = np.linalg.norm(pm.positions(x)[0][3:5] - parts[3:5], axis=1)
        calls.append(int(np.argmax(moved)))
        return hc(x)

    evidence_propagation(x_hc, det, pm.part_fns(), PART_CLASSES, cost, spy, **kw)
    assert sorted(calls) == [0, 1]  # both feet were proposed for it ...
    calls.clear()
    evidence_propagation(x_hc, det, pm.part_fns(), PART_CLASSES, cost, spy, nearest=True, **kw)
    assert calls == [1]  # ... now only the right foot, the nearer one


def test_shipped_part_classifier_is_a_package_asset():
    from gltrack import asset_path

    path = asset_path("parts.npz")
    assert path.is_file() and path.parent.name == "assets"
    model = C.PartClassifier.load(path)
    assert model.label_radius > 0


def test_training_ranges_are_disjoint_from_the_bench():
    from gltrack.data.depth_clips import CLIPS, TRAIN_RANGES, bench_range

    assert set(TRAIN_RANGES) == set(CLIPS)
    for clip, ranges in TRAIN_RANGES.items():
        lo, hi = bench_range(clip, 60)
        assert bench_range(clip, 30)[1] < hi
        for a, b in ranges:
            assert 0 <= a < b and (b <= lo or a >= hi), (clip, a, b)
    assert bench_range("hop", 60) == (760, 1000)


def test_learn_parts_mocap_usage_errors(tmp_path, capsys):
    from gltrack.cli import main

    out = str(tmp_path / "m.npz")
    assert main(["learn-parts", "--mocap", str(tmp_path / "missing"), "--out", out]) == 2
    assert "no such folder" in capsys.readouterr().err
    assert main(["learn-parts", "--mocap", str(tmp_path), "--data", str(tmp_path),
                 "--out", out]) == 2
    assert "exclusive" in capsys.readouterr().err
    assert main(["learn-parts", "--mocap", str(tmp_path), "--out", out]) == 2  # no BVH in it
    assert "not found" in capsys.readouterr().err
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.slow
def test_learn_parts_from_mocap_training_ranges(shared, tmp_path, capsys):
    """The shipped model's recipe: held-out frames of real motion are recognised."""
    import json

    from gltrack.cli import main

    if not (shared / "mocap").is_dir():
        pytest.skip(f"{shared / 'mocap'} is absent")
    out = tmp_path / "parts.npz"
    assert main(["-q", "learn-parts", "--mocap", str(shared / "mocap"), "--out", str(out),
                 "--seed", "0", "--json", str(tmp_path / "r.json")]) == 0
    doc = json.loads((tmp_path / "r.json").read_text())
    rep = doc["report"]  # held-out frames of the clips
    assert rep["head"]["recall"] > 0.8 and rep["head"]["precision"] > 0.8
    assert rep["foot"]["recall"] > 0.7 and rep["foot"]["precision"] > 0.8
    gen = doc["report_rendered"]  # held-out random poses: the model stays general
    assert gen["hand"]["recall"] > 0.8 and gen["foot"]["recall"] > 0.8
    assert C.PartClassifier.load(out).label_radius == pytest.approx(0.16)


# ------------------------------------------------------------------------------------------
# UT inverse kinematics


L1, L2 = 0.3, 0.25


def _arm(X):
    X = np.atleast_2d(X)
    a, b = X[:, 0], X[:, 1]
    return np.stack([L1 * np.cos(a) + L2 * np.cos(a + b), L1 * np.sin(a) + L2 * np.sin(a + b)], 1)


def test_ut_ik_two_link_arm_reaches_target_and_matches_map():
    x0 = np.array([0.3, 0.5])
    target = _arm([0.9, 1.2])[0]
    r = ut_ik(x0, _arm, target, 1e-8, np.array([1.0, 1.0]))
    assert r.converged and r.iterations <= 10
    assert np.linalg.norm(r.residual) < 1e-4
    # an independent MAP solver on the same posterior (prior sd 0.5, measurement sd 2 cm)
    sd, ms = np.array([0.5, 0.5]), 0.02
    r2 = ut_ik(x0, _arm, target, ms ** 2, sd)
    ls = least_squares(lambda x: np.r_[(x - x0) / sd, (_arm(x)[0] - target) / ms], x0,
                       xtol=1e-12, ftol=1e-12)
    # the sigma points linearise about the posterior spread, not the tangent at the mode, so
    # the fixed point sits near (not at) the MAP: within 0.015 rad after a 0.6-0.7 rad move
    np.testing.assert_allclose(r2.x, ls.x, atol=0.015)
    assert np.linalg.norm(r2.residual) > 1e-3  # the prior holds it back from the target
    # an uninformative observation leaves the prior mean in place
    r3 = ut_ik(x0, _arm, target, 1e6, sd)
    np.testing.assert_allclose(r3.x, x0, atol=1e-6)


def test_ut_ik_moves_a_hand_20cm_and_nothing_else(body):
    sk, dofs, kin, pm, mesh = body
    x = _pose(dofs, sk, l_shoulder_rz=-1.2, l_elbow_ry=-0.5, r_shoulder_rz=1.0, l_hip_rx=-0.3)
    x_true = x.copy()
    x_true[dofs.index("l_shoulder_rz")] += 0.2
    x_true[dofs.index("l_shoulder_ry")] -= 0.1
    x_true[dofs.index("l_elbow_ry")] -= 0.2
    before = pm.positions(x)[0]
    target = pm.positions(x_true)[0][1]
    assert 0.17 < np.linalg.norm(target - before[1]) < 0.25
    chain = part_chains(sk, dofs)["l_hand"]
    assert "spine_upper_rx" not in [dofs.names[i] for i in chain]
    r = ut_ik(x, pm.part_fn("l_hand"), target, 0.005 ** 2, dofs.sigma_at(30), dofs=chain,
              lower=dofs.lower, upper=dofs.upper)
    after = pm.positions(r.x)[0]
    assert r.converged and r.iterations <= 10
    assert np.linalg.norm(after[1] - target) < 0.02
    others = [i for i in range(dofs.size) if i not in set(chain)]
    np.testing.assert_array_equal(r.x[others], x[others])
    np.testing.assert_allclose(after[[0, 2, 3, 4]], before[[0, 2, 3, 4]], atol=1e-12)
    # with the torso in the chain, the torso takes part of the motion
    full = chain_dofs(sk, dofs, "l_wrist")
    assert len(full) > len(chain) and dofs.index("spine_upper_rz") in full


# ------------------------------------------------------------------------------------------
# evidence propagation


@pytest.fixture(scope="module")
def ep_problem(body):
    """A numpy likelihood with flat tails (a truncated point-distance cost), as a depth cost
    is flat for a limb far from its data; the left arm starts flipped down, truth is up."""
    sk, dofs, kin, pm, mesh = body
    x_true = _pose(dofs, sk, l_shoulder_rz=1.1, l_elbow_ry=-0.6, r_shoulder_rz=1.2, r_knee_rx=0.4)
    x0 = x_true.copy()
    x0[dofs.index("l_shoulder_rz")] = -1.1
    x0[dofs.index("l_elbow_ry")] = -0.1
    tau = 0.08

    def points(X):
        pose = kin.forward(np.atleast_2d(X))
        return np.concatenate([pose.positions, kin.transform_points(pose, pm.bone, pm.local)], 1)

    truth = points(x_true)[0]

    def cost(X):
        d2 = ((points(X) - truth) ** 2).sum(-1)
        return np.minimum(d2, tau ** 2).sum(1)

    sig = dofs.sigma_at(30)

    def hc(x, part=None):
        r = hill_climb(cost, x, list(range(dofs.size)), 2 * sig, levels=3, grid=5,
                       lower=dofs.lower, upper=dofs.upper)
        return r.x, r.cost, r.evaluations

    return x_true, x0, cost, hc, sig


def test_evidence_propagation_recovers_a_flipped_arm(body, ep_problem):
    sk, dofs, kin, pm, mesh = body
    x_true, x0, cost, hc, sig = ep_problem
    truth = pm.positions(x_true)[0]
    x_hc, c_hc, _ = hc(x0)
    x_hc2, c_hc2, _ = hc(x_hc)  # plain hill climbing is stuck, however often it runs
    assert np.linalg.norm(pm.positions(x_hc2)[0][1] - truth[1]) > 1.0
    assert c_hc2 == pytest.approx(c_hc)
    det = Detections(np.array([truth[1], truth[2] + [0.01, 0, 0], [0.5, 1.0, 1.0], truth[1]]),
                     ["hand", "hand", "hand", "foot"])
    res = evidence_propagation(x_hc, det, pm.part_fns(), PART_CLASSES, cost, hc, sigma=5 * sig,
                               chains=part_chains(sk, dofs), lower=dofs.lower, upper=dofs.upper)
    x_ep, c_ep, evals, log = res
    assert c_ep < 0.5 * c_hc
    assert np.linalg.norm(pm.positions(x_ep)[0][1] - truth[1]) < 0.03
    # one correspondence explains it: left hand <- detection 0; the spurious hand, the
    # already-explained right hand and the wrong-class "foot" are not accepted
    assert [(a["part"], a["detection"]) for a in log] == [("l_hand", 0)]
    assert log[0]["cost_before"] == pytest.approx(c_hc) and log[0]["cost_after"] == c_ep
    assert evals > 0


def test_evidence_propagation_without_useful_evidence_keeps_the_pose(body, ep_problem):
    sk, dofs, kin, pm, mesh = body
    x_true, x0, cost, hc, sig = ep_problem
    x_hc, c_hc, _ = hc(x0)
    parts = pm.positions(x_hc)[0]
    # detections at the current parts are pruned: nothing is even tried
    res = evidence_propagation(x_hc, [(parts[0], "head"), (parts[2], "hand")], pm.part_fns(),
                               PART_CLASSES, cost, hc, sigma=5 * sig, cost_best=c_hc)
    assert res.evaluations == 0 and res.accepted == []
    np.testing.assert_array_equal(res.x, x_hc)
    assert prune_explained(np.array([[0, 0, 0], [1, 0, 0]]), np.array([[0.05, 0, 0]]),
                           0.1).tolist() == [False, True]


def test_evidence_layer_never_imports_gl():
    code = ("import sys, gltrack.evidence.associate, gltrack.evidence.classifier, "
            "gltrack.evidence.ik, gltrack.evidence.synthetic; "
            "bad = [m for m in sys.modules if m.startswith('moderngl') "
            "or m == 'gltrack.render.engine']; print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


# ------------------------------------------------------------------------------------------
# reach gate


def test_part_reach_bounds_every_pose(body, rng):
    from gltrack.evidence.ik import part_reach
    from gltrack.evidence.synthetic import random_poses

    sk, dofs, kin, pm, mesh = body
    chains = part_chains(sk, dofs)
    reach = part_reach(kin, chains, slack=0.0)
    assert set(reach) == set(PART_NAMES)
    X = random_poses(rng, sk, dofs, 300)
    parts = pm.positions(X)
    pose = kin.forward(X)
    # the hand's anchor is the outermost joint its chain moves: the clavicle (torso excluded)
    np.testing.assert_allclose(reach["l_hand"][0](X), pose.positions[:, sk.index("l_clavicle")])
    for i, n in enumerate(PART_NAMES):
        fn, r = reach[n]
        d = np.linalg.norm(parts[:, i] - fn(X), axis=1)
        assert d.max() <= r + 1e-9, n
        assert d.max() > 0.7 * r, n  # a bound, but not a loose one
    assert reach["l_hand"][1] == pytest.approx(reach["r_hand"][1])
    assert 0.5 < reach["l_hand"][1] < 1.0 and 0.7 < reach["l_foot"][1] < 1.3
    assert part_reach(kin, chains, slack=0.2)["head"][1] == pytest.approx(reach["head"][1] + 0.2)


def test_reach_gate_skips_unreachable_detections(body, ep_problem):
    from gltrack.evidence.ik import part_reach

    sk, dofs, kin, pm, mesh = body
    x_true, x0, cost, hc, sig = ep_problem
    x_hc, c_hc, _ = hc(x0)
    truth = pm.positions(x_true)[0]
    chains = part_chains(sk, dofs)
    reach = part_reach(kin, chains)
    far = truth[1] + [0.0, 0.0, 2.5]  # 2.5 m in front of the true hand: no arm gets there
    kw = dict(sigma=5 * sig, chains=chains, lower=dofs.lower, upper=dofs.upper, cost_best=c_hc)
    alone = [(far, "hand")]
    free = evidence_propagation(x_hc, alone, pm.part_fns(), PART_CLASSES, cost, hc, **kw)
    gated = evidence_propagation(x_hc, alone, pm.part_fns(), PART_CLASSES, cost, hc, reach=reach,
                                 **kw)
    assert free.evaluations > 0  # both hands were proposed for it ...
    assert gated.evaluations == 0 and not gated.accepted  # ... and now neither is
    # the true detection is within reach and still recovers the arm
    both = evidence_propagation(x_hc, [(far, "hand"), (truth[1], "hand")], pm.part_fns(),
                                PART_CLASSES, cost, hc, reach=reach, **kw)
    assert [(a["part"], a["detection"]) for a in both.accepted] == [("l_hand", 1)]
    assert np.linalg.norm(pm.positions(both.x)[0][1] - truth[1]) < 0.03



def test_speculative_batches_give_the_one_by_one_result(body, ep_problem):
    """``refine_many`` + ``speculate``: the proposals of a pass climb side by side
    (:func:`hill_climb_lanes`) but are accepted in the one-by-one greedy order, so the result is
    the sequential loop's, with fewer cost calls."""
    sk, dofs, kin, pm, mesh = body
    x_true, x0, cost, hc, sig = ep_problem
    truth = pm.positions(x_true)[0]
    x_hc, c_hc, _ = hc(x0)
    det = Detections(np.array([[0.5, 1.0, 1.0], truth[1], truth[2] + [0.01, 0, 0],
                               truth[3] + [0.2, 0.1, 0]]), ["hand", "hand", "hand", "foot"])
    calls = {"seq": 0, "lanes": 0}

    def counting(key):
        def fn(X):
            calls[key] += 1
            return cost(X)
        return fn

    def hc_seq(x, part=None):
        r = hill_climb(counting("seq"), x, list(range(dofs.size)), 2 * sig, levels=3, grid=5,
                       lower=dofs.lower, upper=dofs.upper)
        return r.x, r.cost, r.evaluations

    def many(X, parts=None):
        r = hill_climb_lanes(counting("lanes"), X, list(range(dofs.size)), 2 * sig, levels=3,
                             grid=5, lower=dofs.lower, upper=dofs.upper)
        return r.X, r.cost, r.evaluations, r.calls

    kw = dict(sigma=5 * sig, chains=part_chains(sk, dofs), lower=dofs.lower, upper=dofs.upper,
              cost_best=c_hc, max_passes=1)
    seq = evidence_propagation(x_hc, det, pm.part_fns(), PART_CLASSES, cost, hc_seq, **kw)
    spec = evidence_propagation(x_hc, det, pm.part_fns(), PART_CLASSES, cost, hc_seq,
                                refine_many=many, speculate=True, **kw)
    # two acceptances: the proposals after the first are proposed again from its pose
    assert [(a["part"], a["detection"]) for a in seq.accepted][0] == ("l_hand", 1)
    assert len(seq.accepted) == 2
    assert spec.accepted == seq.accepted
    np.testing.assert_array_equal(spec.x, seq.x)
    assert spec.cost == seq.cost < 0.5 * c_hc
    # a proposal refined before the acceptance and again after it costs evaluations ...
    assert spec.evaluations >= seq.evaluations
    # ... but the proposals of a batch share their calls
    assert 0 < calls["lanes"] < calls["seq"]


@pytest.mark.parametrize("path", ["one by one", "batched", "speculative"])
def test_screen_refines_only_proposals_near_the_best(body, ep_problem, path):
    """``screen``: the proposals are scored as the IK left them and only those within
    ``screen`` of the best pose's cost are refined. The true hand's proposal starts below the
    best (the flipped arm's cost goes) and still wins; the right hand sent to either detection
    starts far above it and is never refined.
    A screen below every proposal refines none."""
    sk, dofs, kin, pm, mesh = body
    x_true, x0, cost, hc, sig = ep_problem
    truth = pm.positions(x_true)[0]
    x_hc, c_hc, _ = hc(x0)
    det = Detections(np.array([[0.5, 1.0, 1.0], truth[1]]), ["hand", "hand"])
    refined = []

    def hc_rec(x, part=None):
        refined.append(1)
        return hc(x, part)

    def many(X, parts=None):
        refined.append(len(X))
        r = hill_climb_lanes(cost, X, list(range(dofs.size)), 2 * sig, levels=3, grid=5,
                             lower=dofs.lower, upper=dofs.upper)
        return r.X, r.cost, r.evaluations, r.calls

    kw = dict(sigma=5 * sig, chains=part_chains(sk, dofs), lower=dofs.lower, upper=dofs.upper,
              cost_best=c_hc, max_passes=1)
    if path != "one by one":
        kw.update(refine_many=many, speculate=path == "speculative")

    def run(screen):
        refined.clear()
        res = evidence_propagation(x_hc, det, pm.part_fns(), PART_CLASSES, cost, hc_rec,
                                   screen=screen, **kw)
        return res, sum(refined)

    free, n_free = run(None)
    screened, n_screened = run(0.0)
    assert [a["part"] for a in screened.accepted] == [a["part"] for a in free.accepted]
    assert "l_hand" in [a["part"] for a in screened.accepted]
    np.testing.assert_array_equal(screened.x, free.x)
    assert n_screened == 1 and n_free >= 3, (n_screened, n_free)
    none, n_none = run(-10.0)
    assert n_none == 0 and none.accepted == [] and none.evaluations > 0
    np.testing.assert_array_equal(none.x, x_hc)
