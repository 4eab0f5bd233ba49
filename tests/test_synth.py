"""The sensor simulator (`gltrack synth`): noise effects, masks, occluder, determinism, errors.

pyrender (PyOpenGL on EGL) must not share a process with the session's moderngl context, so
every synthesis here runs in a child process (the CLI, or a multiprocessing spawn child).
"""
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from gltrack.body.model import BodyModel, body_from_meta
from gltrack.data.dataset import Dataset
from gltrack.data.scene import DISTRACTOR_SIZE, Room, make_room
from gltrack.data.sim_depth import TofNoise, apply_tof_noise, depth_edges
from gltrack.data.sim_multiview import iou
from gltrack.motion.bvh import write_bvh
from gltrack.export.bvh import params_to_bvh

from trackdata import DAZ

REPO = Path(__file__).resolve().parents[1]
FPS = 30


def _motion(T=12):
    """A slow walk-like motion of the default body: (BodyModel, params (T, D))."""
    body = BodyModel.build()
    d = body.dofs
    p = np.tile(d.zero(body.skeleton), (T, 1))
    t = np.arange(T) / FPS
    p[:, 2] += 0.4 * t
    p[:, d.index("pelvis_ry")] = 0.3
    for side, sign in (("l", 1), ("r", -1)):
        p[:, d.index(f"{side}_hip_rx")] = sign * 0.35 * np.sin(2 * np.pi * t)
        p[:, d.index(f"{side}_knee_rx")] = 0.3 + 0.2 * np.sin(2 * np.pi * t + sign)
        p[:, d.index(f"{side}_shoulder_rz")] = -sign * 1.1
    return body, p


def _write_clip(path, T=12):
    body, p = _motion(T)
    bvh = params_to_bvh(body, p, FPS)
    bvh.names = [DAZ[n] for n in bvh.names]
    bvh.end_sites = {DAZ[k]: v for k, v in bvh.end_sites.items()}
    write_bvh(path, bvh)
    return path


def _env():
    return dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _synth_all(runs):
    """Run ``gltrack synth ARGS`` for every ARGS in one child process (one interpreter start)."""
    script = ("import sys, json\nfrom gltrack.cli import main\n"
              "for args in json.loads(sys.argv[1]):\n"
              "    rc = main(['synth'] + args)\n"
              "    assert rc == 0, (rc, args)\n")
    import json

    r = subprocess.run([sys.executable, "-c", script,
                        json.dumps([[str(a) for a in args] for args in runs])],
                       capture_output=True, text=True, timeout=600, env=_env())
    assert r.returncode == 0, r.stderr


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return _write_clip(tmp_path_factory.mktemp("clip") / "walk_daz.bvh")


@pytest.fixture(scope="module")
def runs(clip, tmp_path_factory):
    """All datasets the tests read, synthesised in one child process.

    depth a / a2 / clean: same seed and scene (table, distractor), default noise twice and
    noise none; mv a / a2: multiview twice with the same seed; plain: depth without props.
    """
    root = tmp_path_factory.mktemp("synth")
    depth = ["--motion", clip, "--rig", "depth", "--frames", "2:6", "--seed", 3,
             "--occluder", "table", "--distractor", "box"]
    mv = ["--motion", clip, "--rig", "multiview", "--frames", "0:4", "--seed", 5,
          "--cameras", 3, "--size", "160x120", "--occluder", "table", "--distractor", "box"]
    _synth_all([depth + ["--out", root / "depth_a"], depth + ["--out", root / "depth_a2"],
                depth + ["--noise", "none", "--out", root / "depth_clean"],
                mv + ["--out", root / "mv_a"], mv + ["--out", root / "mv_a2"],
                ["--motion", clip, "--rig", "depth", "--frames", "0:2", "--out", root / "plain"]])
    return root


@pytest.fixture(scope="module")
def depth_runs(runs):
    return runs / "depth_a", runs / "depth_a2", runs / "depth_clean"


@pytest.fixture(scope="module")
def mv_runs(runs):
    return runs / "mv_a", runs / "mv_a2"


def _pngs(folder):
    return sorted(p.relative_to(folder) for p in Path(folder).rglob("*.png"))


def _assert_identical(a, b):
    files = _pngs(a)
    assert files and files == _pngs(b)
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    for name in ("calibration.json", "environment.json", "meta.json"):
        assert (a / name).read_text() == (b / name).read_text()


# ---- depth rig ---------------------------------------------------------------------------------
def test_depth_dataset_opens_with_plausible_depth_and_groundtruth(depth_runs):
    ds = Dataset.open(depth_runs[0])
    assert ds.rig == "depth" and ds.frames == 4 and ds.fps == FPS
    cam = ds.cameras[0]
    assert (cam.kind, cam.width, cam.height) == ("depth", 176, 144)
    gt = ds.groundtruth()
    body, p = _motion()
    assert gt["joints"].shape == (4, 19, 3) and gt["markers"].shape == (4, 23, 3)
    assert str(gt["preset"]) == "full" and len(gt["marker_names"]) == 23
    # the source frames 2:6 of the clip, recovered through BVH and retargeting
    np.testing.assert_allclose(gt["joints"], body.joints(p[2:6]), atol=2e-3)
    # the body recorded in meta.json rebuilds the same skeleton
    rebuilt = body_from_meta(ds.body)
    np.testing.assert_allclose(rebuilt.joints(gt["params"]), gt["joints"], atol=1e-9)
    # subject 2-4 m in front of the camera, and that is what the image shows
    dist = np.linalg.norm(gt["joints"][:, 0] - cam.center, axis=1)
    assert np.all((dist > 1.9) & (dist < 4.3)), dist
    for f in range(ds.frames):
        z, m = ds.depth(f), ds.gtmask(f)
        assert m.sum() > 150
        assert 1.8 < np.median(z[m & (z > 0)]) < 4.5
    bg = ds.background()
    assert bg.shape == (144, 176) and np.mean(bg > 0) > 0.95
    assert bg.max() > np.median(z[m & (z > 0)])  # the room is behind the subject


def test_same_seed_gives_byte_identical_depth_dataset(depth_runs):
    _assert_identical(depth_runs[0], depth_runs[1])


def test_noise_none_is_the_clean_render_quantised(depth_runs):
    """Body pixels equal an independent CPU rasteriser's depth to the millimetre quantisation."""
    from gltrack.render.reference import render_candidates

    ds = Dataset.open(depth_runs[2])
    cam = ds.cameras[0]
    body = body_from_meta(ds.body)
    gt = ds.groundtruth()
    ref, _ = render_candidates(body.mesh, body.skinning(gt["params"]), cam.K, cam.R, cam.t,
                               cam.width, cam.height)
    for f in range(ds.frames):
        z = ds.depth(f)
        assert np.all(z > 0)  # no dropouts without noise
        inner = cv2.erode(ds.gtmask(f).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        inner &= ref[f] > 0
        assert inner.sum() > 100
        assert np.abs(z[inner] - ref[f][inner]).max() < 1.5e-3
        assert np.all(np.abs(z * 1000 - np.round(z * 1000)) < 1e-3)  # whole millimetres


def test_default_noise_has_gaussian_noise_dropouts_and_flying_pixels_at_edges(depth_runs):
    noisy, clean = Dataset.open(depth_runs[0]), Dataset.open(depth_runs[2])
    model = TofNoise()
    n_drop = n_fly = 0
    for f in range(noisy.frames):
        zn, zc = noisy.depth(f).astype(np.float64), clean.depth(f).astype(np.float64)
        both = (zn > 0) & (zc > 0)
        diff = zn - zc
        assert np.mean(diff[both] != 0) > 0.5
        edges = cv2.dilate(depth_edges(zc, model.jump).astype(np.uint8),
                           np.ones((3, 3), np.uint8)).astype(bool)
        # away from edges the error is Gaussian with the documented sigma(z)
        flat = both & ~edges & (zc < 4.0)
        ratio = diff[flat] / model.sigma(zc[flat])
        assert 0.8 < np.std(ratio) < 1.25
        outlier = both & (np.abs(diff) > 6 * model.sigma(zc) + 0.003)
        assert not np.any(outlier & ~edges)  # flying pixels only at discontinuities
        n_fly += outlier.sum()
        n_drop += np.sum((zn == 0) & (zc > 0))
    assert n_fly > 20 and n_drop > 20


def test_tof_noise_model_levels_and_dependencies(rng):
    K = np.array([[220.0, 0, 87.5], [0, 231.0, 71.5], [0, 0, 1]])
    z = np.full((144, 176), 4.0)
    z[:, :88] = 2.0
    refl = np.full(z.shape, 0.9)
    out, eff = apply_tof_noise(z, refl, K, rng, TofNoise.preset("none"))
    assert np.array_equal(out, z.astype(np.float32)) and not eff["flying"].any()
    out, eff = apply_tof_noise(z, refl, K, rng, TofNoise.preset("default"))
    near = (out[:, 5:80] - 2.0)[out[:, 5:80] > 0]
    far = (out[:, 100:170] - 4.0)[out[:, 100:170] > 0]
    assert 0.009 < near.std() < 0.011 and 0.036 < far.std() < 0.044  # 1 cm at 2 m, x4 at 4 m
    edges = depth_edges(z)
    assert eff["flying"].any() and not np.any(eff["flying"] & ~edges)
    mixed = out[eff["flying"]]
    assert np.all((mixed > 2.0 + 0.05) & (mixed < 4.0 - 0.05) | (np.abs(mixed - 3) > 0.8))
    # dark surfaces drop out more than bright ones; heavy noise is noisier than default
    _, dark = apply_tof_noise(z, np.full(z.shape, 0.05), K, rng, TofNoise())
    assert dark["dropout"].mean() > 5 * eff["dropout"].mean()
    heavy, _ = apply_tof_noise(z, refl, K, rng, TofNoise.preset("heavy"))
    h = (heavy[:, 5:80] - 2.0)[heavy[:, 5:80] > 0]
    assert h.std() > 2 * near.std()


# ---- multiview rig -----------------------------------------------------------------------------
def _distractor_masks(cam, centre):
    s = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) \
        * np.array(DISTRACTOR_SIZE) / 2
    uv = cam.project(centre + s, distort=False).astype(np.float32)
    hull = cv2.convexHull(uv).reshape(-1, 2)
    m = np.zeros((cam.height, cam.width), np.uint8)
    cv2.fillPoly(m, [np.round(hull).astype(np.int32)], 1)
    inner = cv2.erode(m, np.ones((3, 3), np.uint8)).astype(bool)
    outer = cv2.dilate(m, np.ones((5, 5), np.uint8)).astype(bool)
    return inner, outer


def test_multiview_masks_from_background_subtraction(mv_runs):
    ds = Dataset.open(mv_runs[0])
    assert ds.rig == "multiview" and len(ds.cameras) == 3 and ds.frames == 4
    gt = ds.groundtruth()
    ious, dist_fg, dist_area = [], 0, 0
    for c, cam in enumerate(ds.cameras):
        assert cam.kind == "colour" and (cam.width, cam.height) == (160, 120)
        assert len(ds.backgrounds(c)) >= 5
        for f in range(ds.frames):
            mask, g = ds.mask(f, c), ds.gtmask(f, c)
            inner, outer = _distractor_masks(cam, gt["distractor_centre"][f])
            ious.append(iou(mask & ~outer, g & ~outer))
            box = inner & ~cv2.dilate(g.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
            dist_fg += np.sum(mask & box)
            dist_area += np.sum(box)
    assert np.mean(ious) > 0.7, ious
    # the distractor corrupts the masks but is no part of the ground-truth masks
    assert dist_area > 100 and dist_fg > 0.7 * dist_area


def test_same_seed_gives_byte_identical_multiview_dataset(mv_runs):
    _assert_identical(*mv_runs)


def test_clothing_changes_colour_images_not_geometry(mv_runs):
    ds = Dataset.open(mv_runs[0])
    for c in range(len(ds.cameras)):
        col, g = ds.colour(0, c).astype(np.float64), ds.gtmask(0, c)
        bg = ds.background(c).astype(np.float64)
        # where the body stands the image differs clearly from the empty scene
        assert np.abs(col[g] - bg[g]).sum(-1).mean() > 40
        assert np.median(np.abs(col[~g] - bg[~g]).sum(-1)) < 25  # noise, shadows, distractor


def _table_hides_an_ankle(ds):
    gt = ds.groundtruth()
    ankles = [gt["joint_names"].index(n) for n in ("l_ankle", "r_ankle")]
    hidden = 0
    for c, cam in enumerate(ds.cameras):
        block = ds.blocking_mask(c)
        for f in range(ds.frames):
            g = ds.gtmask(f, c)
            for a in ankles:
                u, v = np.round(cam.project(gt["joints"][f, a][None], distort=False)[0]).astype(int)
                if 1 <= u < cam.width - 1 and 1 <= v < cam.height - 1 and block[v, u] \
                        and not g[v - 1:v + 2, u - 1:u + 2].any():
                    hidden += 1
    return hidden


def test_table_occluder_polygons_and_hidden_legs(depth_runs, mv_runs):
    for path in (depth_runs[0], mv_runs[0]):
        ds = Dataset.open(path)
        env = ds.environment()
        assert "cam0" in env and len(env["cam0"][0]) >= 3
        assert ds.blocking_mask("cam0").mean() > 0.02
        assert _table_hides_an_ankle(ds) > 0, path
        corners = ds.groundtruth()["table_corners"]
        # the polygon is the table's outline: its corners' projections lie on or inside it
        cam = ds.cameras[0]
        uv = cam.project(corners, distort=False)
        poly = env["cam0"][0].astype(np.float32)
        inside = [cv2.pointPolygonTest(poly, (float(x), float(y)), True) > -1.0 for x, y in uv
                  if -0.5 <= x <= cam.width - 0.5 and -0.5 <= y <= cam.height - 0.5]
        assert inside and all(inside)


def test_without_props_no_environment(runs):
    ds = Dataset.open(runs / "plain")
    assert ds.environment() is None and "distractor_centre" not in ds.groundtruth()


# ---- Python API and errors ---------------------------------------------------------------------
def test_python_api_synthesises_procedural_motion(tmp_path):
    from gltrack.data.simulate import synthesize_in_subprocess

    body, p = _motion(3)
    out = synthesize_in_subprocess(p, body.skeleton, body.dofs, FPS, "multiview", tmp_path / "m",
                                   seed=1, size=(64, 48), n_cameras=2, noise="heavy",
                                   progress=False, timeout=300)
    ds = Dataset.open(out)
    assert ds.frames == 3 and len(ds.cameras) == 2
    np.testing.assert_allclose(ds.groundtruth()["joints"], body.joints(p), atol=1e-9)
    assert ds.body["preset"] == "full" and ds.body["mesh"] == "procedural"


def test_bad_input_errors(clip, tmp_path, capsys):
    from gltrack.cli import main

    # every error below is raised before any rendering, so this runs in the test process
    assert main(["synth", "--motion", str(clip), "--rig", "depth", "--frames", "0:50",
                 "--out", str(tmp_path / "x")]) == 1
    err = capsys.readouterr().err
    assert "12 frames" in err and "0:50" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("mine")
    assert main(["synth", "--motion", str(clip), "--rig", "depth", "--out", str(full)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert [p.name for p in full.iterdir()] == ["keep.txt"]
    assert main(["synth", "--motion", str(clip), "--rig", "depth", "--size", "big",
                 "--out", str(tmp_path / "y")]) == 2
    assert "--size" in capsys.readouterr().err
    assert main(["synth", "--motion", str(clip), "--rig", "depth", "--cameras", "3",
                 "--out", str(tmp_path / "y")]) == 2
    assert "multiview" in capsys.readouterr().err
    assert main(["synth", "--motion", str(tmp_path / "nope.bvh"), "--rig", "depth",
                 "--out", str(tmp_path / "z")]) == 1
    assert "nope.bvh" in capsys.readouterr().err
    assert "pyrender" not in sys.modules


def test_scene_is_reproducible_from_the_seed():
    room = Room(np.zeros(3), np.array([0.0, 0.0, 1.0]), (-3, 3), (-3, 4), 0.0)
    a = make_room(room, np.random.default_rng(7))
    b = make_room(room, np.random.default_rng(7))
    c = make_room(room, np.random.default_rng(8))
    assert len(a) == len(b) and all(np.array_equal(x.vertices, y.vertices)
                                    and np.array_equal(x.colours, y.colours) for x, y in zip(a, b))
    assert len(a) != len(c) or any(not np.array_equal(x.colours, y.colours) for x, y in zip(a, c))
    floor = a[0]
    assert np.allclose(floor.normals, [0, 1, 0]) and np.allclose(floor.vertices[:, 1], 0)


# ---- real motion capture -----------------------------------------------------------------------
def test_depth_rig_from_every_shared_clip(shared, tmp_path):
    clips = sorted((shared / "mocap").glob("*.bvh"))
    if not clips:
        pytest.skip(f"{shared / 'mocap'} holds no BVH clips")
    script = ("import sys\nfrom gltrack.cli import main\n"
              "for i, c in enumerate(sys.argv[2:]):\n"
              "    rc = main(['synth', '--motion', c, '--rig', 'depth', '--frames', '10:30',\n"
              "               '--out', f'{sys.argv[1]}/{i}'])\n"
              "    assert rc == 0, c\n")
    r = subprocess.run([sys.executable, "-c", script, str(tmp_path), *map(str, clips)],
                       capture_output=True, text=True, timeout=600, env=_env())
    assert r.returncode == 0, r.stderr
    for i, c in enumerate(clips):
        ds = Dataset.open(tmp_path / str(i))
        assert ds.frames == 5, c  # 20 frames at 120 fps -> 5 at 30 fps
        cam = ds.cameras[0]
        pelvis = ds.groundtruth()["joints"][:, 0]
        assert np.all(np.linalg.norm(pelvis - cam.center, axis=1) < 4.5), c
        z, m = ds.depth(2), ds.gtmask(2)
        assert m.sum() > 100, c
        assert 1.5 < np.median(z[m & (z > 0)]) < 4.5, c
