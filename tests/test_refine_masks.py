"""``gltrack refine-masks``: a dataset's sequence masks refined with a tracked model's silhouettes.

The dataset is rendered with the CPU reference rasteriser (4 cameras 128x96); its masks are then
spoilt the way a sequence's temporal background spoils them: the still torso is missing and a
"ghost" blob sits away from the person. Refined with the true poses (a perfect track), the torso
comes back and the ghost goes."""
import json

import cv2
import numpy as np
import pytest

from gltrack.bench.multiview import RING, render_dataset
from gltrack.bench.rigs import ring_cameras
from gltrack.body.mesh import PARTS
from gltrack.body.model import BodyModel
from gltrack.cli import main
from gltrack.data.dataset import Dataset
from gltrack.data.refine_masks import SEQUENCE_SUFFIX
from gltrack.data.results import ResultsWriter
from gltrack.observe.model_masks import model_silhouette, refine_with_model
from gltrack.render import reference as ref

N = 3


def _iou(a, b):
    return np.count_nonzero(a & b) / max(np.count_nonzero(a | b), 1)


@pytest.fixture(scope="module")
def spoilt(tmp_path_factory):
    """(dataset path, body, poses): masks without the torso, with a ghost in a corner."""
    body = BodyModel.build()
    d = body.dofs
    P = np.repeat(d.zero(body.skeleton)[None], N, axis=0)
    P[:, 1] = 0.98
    P[:, d.index("l_shoulder_rz")] = [-1.2, -0.8, -0.4]
    P[:, d.index("r_elbow_ry")] = [0.2, 0.8, 1.4]
    root = tmp_path_factory.mktemp("refine")
    cams = ring_cameras((0.0, 0.9, 0.0), **dict(RING, radius=3.0))
    path = render_dataset(root / "ds", body, P, cams, 15.0, np.random.default_rng(5))
    torso = body.mesh.without_parts([p for p in PARTS if p not in ("torso", "pelvis")])
    ds = Dataset.open(path)
    for f in range(N):
        posed = ref.skin_vertices(torso, body.skinning(P[f][None]))[0]
        for c, cam in enumerate(ds.cameras):
            gt = ds.gtmask(f, c)
            seq = gt & ~model_silhouette(cam, posed, torso.faces)
            seq[2:14, 2:14] = True  # the ghost, far from the person
            cv2.imwrite(str(path / f"{cam.name}_mask" / f"{f:06d}.png"),
                        np.where(seq, 255, 0).astype(np.uint8))
    return path, body, P


def _result(path, body, P, out):
    from gltrack.body.model import body_record

    w = ResultsWriter(out, "hps", list(body.skeleton.names), list(body.markers.names),
                      body=body_record(body, "dataset"))
    for f, p in enumerate(P):
        w.append(f, p, body.joints(p[None])[0], body.marker_positions(p[None])[0])
    w.finish()
    w.close()
    return out


def test_model_silhouette_covers_what_the_rasteriser_draws():
    """The silhouette by filled projected triangles against the reference rasteriser (no lens
    distortion; at 512x384, where the two sampling rules, half a pixel's area and the pixel's
    centre, differ on few pixels), and it follows the pose."""
    body = BodyModel.build()
    cam = ring_cameras((0.0, 0.9, 0.0), n=1, radius=3.0)[0].scaled(512, 384)
    x = body.dofs.zero(body.skeleton)
    x[1] = 0.98
    S = body.skinning(x[None])
    _, tri = ref.render_candidates(body.mesh, S, cam.K, cam.R, cam.t, cam.width, cam.height)
    sil = model_silhouette(cam, ref.skin_vertices(body.mesh, S)[0], body.mesh.faces)
    assert _iou(sil, tri[0] >= 0) > 0.93
    x[0] += 0.3
    moved = model_silhouette(cam, ref.skin_vertices(body.mesh, body.skinning(x[None]))[0],
                             body.mesh.faces)
    assert _iou(moved, sil) < 0.7


def test_refine_masks_brings_back_the_still_torso_and_drops_the_ghost(spoilt, tmp_path, capsys):
    path, body, P = spoilt
    res = _result(path, body, P, tmp_path / "res")
    ds = Dataset.open(path)
    seq = [[ds.mask(f, c) for c in range(4)] for f in range(N)]
    assert main(["refine-masks", str(path), str(res)]) == 0
    assert "refined" in capsys.readouterr().out
    ds = Dataset.open(path)
    before, after = [], []
    for f in range(N):
        for c in range(4):
            gt, new = ds.gtmask(f, c), ds.mask(f, c)
            before.append(_iou(seq[f][c], gt))
            after.append(_iou(new, gt))
            assert not new[2:14, 2:14].any(), "the ghost is dropped"
            assert np.count_nonzero(gt & ~new) < 0.05 * gt.sum(), "the torso is back"
            # GrabCut may take a background block of the trousers' colour within the band
            assert _iou(new, gt) > 0.7, (f, c, _iou(new, gt))
    assert np.mean(after) > np.mean(before) + 0.3, (np.mean(before), np.mean(after))
    # the sequence's masks are kept, and recorded in meta.json
    kept = path / f"{ds.cameras[0].name}_mask_sequence" / "000000.png"
    np.testing.assert_array_equal(cv2.imread(str(kept), 0) > 127, seq[0][0])
    rec = json.loads((path / "meta.json").read_text())["masks"]["refined"]
    assert rec["frames"] == N and rec["result"] == str(res.resolve())
    # a second refinement starts again from the sequence's masks: the same output; with
    # --frames, the frames outside get the sequence's masks back
    first = [ds.mask(f, 1) for f in range(N)]
    assert main(["-q", "refine-masks", str(path), str(res)]) == 0
    ds = Dataset.open(path)
    for f in range(N):
        np.testing.assert_array_equal(ds.mask(f, 1), first[f])
    assert main(["-q", "refine-masks", str(path), str(res), "--frames", "1:3"]) == 0
    ds = Dataset.open(path)
    np.testing.assert_array_equal(ds.mask(0, 1), seq[0][1])
    np.testing.assert_array_equal(ds.mask(2, 1), first[2])
    assert not list(path.glob(".*refining*"))


def test_refine_with_model_keeps_the_mask_where_the_model_is_out_of_view():
    img = np.full((40, 50, 3), 128, np.uint8)
    mask = np.zeros((40, 50), bool)
    mask[10:20, 10:20] = True
    out = refine_with_model(img, mask, np.zeros_like(mask), band_px=3, reach_px=6, core_px=1)
    np.testing.assert_array_equal(out, mask)
    with pytest.raises(ValueError, match="same size"):
        refine_with_model(img, mask[:-1], mask[:-1], band_px=3, reach_px=6, core_px=1)


def test_refine_masks_bad_input(spoilt, tmp_path, capsys):
    path, body, P = spoilt
    assert main(["refine-masks", str(path), str(tmp_path / "nothing")]) == 1
    assert "nothing" in capsys.readouterr().err
    assert main(["refine-masks", str(path), str(tmp_path), "--band", "0"]) == 2
    assert "--band" in capsys.readouterr().err
    res = _result(path, body, P, tmp_path / "res")
    assert main(["refine-masks", str(path), str(res), "--frames", "5:9"]) == 1
    assert "no frame in 5:9" in capsys.readouterr().err


@pytest.fixture(scope="module")
def still(tmp_path_factory):
    """(dataset path, body, poses): a subject that stands still for 5 frames (arm moving) and
    is 1.2 m to the side in the sixth, masks by the sequence foreground as ``ingest`` makes
    them: the still body is in the temporal background, so it is missed in frames 0-4, and its
    ghost is foreground in frame 5."""
    from gltrack.observe.foreground import estimate_foreground

    T = 6
    body = BodyModel.build()
    d = body.dofs
    P = np.repeat(d.zero(body.skeleton)[None], T, axis=0)
    P[:, 1] = 0.98
    P[:, d.index("l_shoulder_rz")] = np.linspace(-1.2, -0.4, T)
    P[-1, 0] = 1.2
    cams = [c.scaled(256, 192) for c in ring_cameras((0.0, 0.9, 0.0), **dict(RING, radius=3.0))]
    path = render_dataset(tmp_path_factory.mktemp("still") / "ds", body, P, cams, 15.0,
                          np.random.default_rng(5))
    ds = Dataset.open(path)
    res = estimate_foreground([[ds.colour(f, c) for f in range(T)] for c in range(4)],
                              ds.cameras)
    for f in range(T):
        for c, cam in enumerate(ds.cameras):
            cv2.imwrite(str(path / f"{cam.name}_mask" / f"{f:06d}.png"),
                        np.where(res.masks[c][f], 255, 0).astype(np.uint8))
    return path, body, P


def test_refine_masks_background_takes_the_model_out_of_the_temporal_background(still, tmp_path):
    """``--method background``: with the (true) model left out of the background statistics,
    the still body is foreground again and the ghost goes; the sequence masks it starts from
    are poor (IoU < 0.3 in every frame and camera). The masks do not get near the truth here:
    GrabCut's colour models, which the chain ends with, overgrow the candidates (IoU ~0.8)
    into this background of random coloured blocks (IoU ~0.5), so the test asks for the gain
    and for the model's part in it."""
    path, body, P = still
    T = len(P)
    ds = Dataset.open(path)
    seq = np.array([[_iou(ds.mask(f, c), ds.gtmask(f, c)) for c in range(4)] for f in range(T)])
    assert seq.max() < 0.3, seq
    res = _result(path, body, P, tmp_path / "res")
    assert main(["-q", "refine-masks", str(path), str(res), "--method", "background"]) == 0
    ds = Dataset.open(path)
    new = np.array([[_iou(ds.mask(f, c), ds.gtmask(f, c)) for c in range(4)] for f in range(T)])
    assert new.mean() > seq.mean() + 0.25 and new.min() > 0.25, (seq, new)
    rec = json.loads((path / "meta.json").read_text())["masks"]["refined"]
    assert rec["method"] == "background" and rec["frames"] == T
    # the model, not just any second pass, does it: a result 1 m off the subject leaves the
    # subject in the background
    off = P.copy()
    off[:, 2] += 1.0
    res_off = _result(path, body, off, tmp_path / "off")
    assert main(["-q", "refine-masks", str(path), str(res_off), "--method", "background"]) == 0
    ds = Dataset.open(path)
    bad = np.array([[_iou(ds.mask(f, c), ds.gtmask(f, c)) for c in range(4)] for f in range(T)])
    assert bad.mean() < new.mean() - 0.15, (new, bad)


@pytest.fixture(scope="module")
def spilt(tmp_path_factory):
    """(dataset path, body, poses, true masks): a subject walking 1.2 m across the view over 10
    frames, its masks the true silhouettes plus a band of static background beside the body
    (what GrabCut takes in where the background has the subject's colours)."""
    T = 10
    body = BodyModel.build()
    d = body.dofs
    P = np.repeat(d.zero(body.skeleton)[None], T, axis=0)
    P[:, 1] = 0.98
    P[:, 0] = np.linspace(-0.6, 0.6, T)
    P[:, d.index("l_shoulder_rz")] = np.linspace(-1.2, -0.4, T)
    cams = ring_cameras((0.0, 0.9, 0.0), **dict(RING, radius=3.5))
    path = render_dataset(tmp_path_factory.mktemp("spill") / "ds", body, P, cams, 15.0,
                          np.random.default_rng(7))
    ds = Dataset.open(path)
    truth = {}
    for f in range(T):
        for c, cam in enumerate(ds.cameras):
            gt = ds.gtmask(f, c)
            spill = np.roll(gt, 6, axis=1) & ~gt  # 6 px of background on one side
            truth[f, c] = gt
            cv2.imwrite(str(path / f"{cam.name}_mask" / f"{f:06d}.png"),
                        np.where(gt | spill, 255, 0).astype(np.uint8))
    return path, body, P, truth


def test_refine_masks_scene_drops_static_background_beside_the_body(spilt, tmp_path):
    """``--method scene``: the band of static background goes, the subject stays, nothing is
    added. A result 1 m off the subject removes the band too and keeps most of the subject (its
    pixels differ from their temporal background: only scene pixels are ever removed), but
    not the subject's pixels that happen to match the background there, which the true model
    keeps."""
    path, body, P, truth = spilt
    T = len(P)
    ds = Dataset.open(path)
    seq = {k: ds.mask(*k) for k in truth}
    before = np.mean([_iou(seq[k], truth[k]) for k in truth])
    assert before < 0.85
    kept_by = {}
    for tag, poses in (("true", P), ("off", P + np.eye(P.shape[1])[2] * 1.0)):
        res = _result(path, body, poses, tmp_path / tag)
        assert main(["-q", "refine-masks", str(path), str(res), "--method", "scene"]) == 0
        ds = Dataset.open(path)
        new = {k: ds.mask(*k) for k in truth}
        after = np.mean([_iou(new[k], truth[k]) for k in truth])
        kept = sum(np.count_nonzero(new[k] & truth[k]) for k in truth) / \
            sum(np.count_nonzero(seq[k] & truth[k]) for k in truth)
        kept_by[tag] = kept
        assert after > before + 0.08 and kept > (0.97 if tag == "true" else 0.85), \
            (tag, before, after, kept)
        assert all(not np.any(new[k] & ~seq[k]) for k in truth), tag
        rec = json.loads((path / "meta.json").read_text())["masks"]["refined"]
        assert rec["method"] == "scene" and rec["frames"] == T
    assert kept_by["off"] < kept_by["true"] - 0.02, kept_by


def test_scene_pixels_are_the_static_background_not_the_moving_subject(spilt):
    """:meth:`SequenceForeground.scene_pixels`: far from the walking subject nearly every pixel
    is scene, on it almost none (it differs from its background); with the frames' true masks
    left out of the statistics the background is known everywhere the subject left."""
    from gltrack.observe.foreground import SequenceForeground, dilate_mask

    path, body, P, truth = spilt
    ds = Dataset.open(path)
    T = len(P)
    est = SequenceForeground([[ds.colour(f, c) for f in range(T)] for c in range(4)],
                             ds.cameras)
    for c in range(4):
        masks = np.stack([truth[f, c] for f in range(T)])
        scene = est.scene_pixels(c, masks)
        assert scene.shape == masks.shape
        far = ~np.stack([dilate_mask(m, 8) for m in masks])
        assert scene[far].mean() > 0.95 and scene[masks].mean() < 0.25, \
            (c, scene[far].mean(), scene[masks].mean())
    with pytest.raises(ValueError, match="frames"):
        est.scene_pixels(0, masks[:3])


def test_eval_iou_now_scores_against_the_refined_masks(spilt, tmp_path, capsys):
    """``gltrack eval R DS --iou-now`` recomputes the silhouette IoU against the masks as they
    are now: on the spilt masks it is what the masks' own overlap with the true silhouettes
    says, after ``refine-masks --method scene`` it is higher; a dataset whose masks alone
    changed is accepted with --iou-now and refused without it (pointing at --iou-now)."""
    import shutil

    from gltrack.data.provenance import check_same_dataset, dataset_fingerprint

    src, body, P, truth = spilt
    path = tmp_path / "ds"
    shutil.copytree(src, path, ignore=shutil.ignore_patterns("*_mask_sequence"))
    for (f, c), gt in truth.items():  # the spilt masks again (an earlier test refined src's)
        name = Dataset.open(path).cameras[c].name
        spill = np.roll(gt, 6, axis=1) & ~gt
        cv2.imwrite(str(path / f"{name}_mask" / f"{f:06d}.png"),
                    np.where(gt | spill, 255, 0).astype(np.uint8))
    run = {"dataset": dataset_fingerprint(path)}
    res = _result(path, body, P, tmp_path / "res")
    ds = Dataset.open(path)
    want = np.mean([[_iou(ds.mask(f, c), truth[f, c]) for c in range(4)] for f in range(len(P))],
                   axis=0)
    j = tmp_path / "q.json"
    assert main(["-q", "eval", str(res), str(path), "--iou-now", "--json", str(j)]) == 0
    out = capsys.readouterr().out
    assert "recomputed against the dataset's masks" in out and "fg covered" in out
    q = json.loads(j.read_text())["quality"]
    np.testing.assert_allclose(q["iou_mean"], want, atol=0.03)
    # the true pose's silhouette lies on the masks (edge pixels of 128 x 96 images aside)
    assert min(q["model_on_fg_mean"]) > 0.9
    assert main(["-q", "refine-masks", str(path), str(res), "--method", "scene"]) == 0
    assert main(["-q", "eval", str(res), str(path), "--iou-now", "--json", str(j)]) == 0
    q2 = json.loads(j.read_text())["quality"]
    assert min(np.subtract(q2["iou_mean"], q["iou_mean"])) > 0.05, (q, q2)
    # the fingerprint check: only the masks (and meta.json's record of them) changed
    check_same_dataset(run, path, "res", masks_may_differ=True)
    with pytest.raises(ValueError, match="--iou-now"):
        check_same_dataset(run, path, "res")


# -- refined while tracking (``mask_refine``) -------------------------------------------------

def _spoilt_copy(spoilt, tmp_path):
    """A copy of the ``spoilt`` dataset with its spoilt masks (a refine-masks test above may
    have refined the fixture's in place, keeping them in ``camN_mask_sequence``)."""
    import shutil

    path, body, P = spoilt
    out = tmp_path / "spoilt"
    shutil.copytree(path, out)
    for kept in out.glob(f"*{SEQUENCE_SUFFIX}"):
        mask = out / kept.name.replace(SEQUENCE_SUFFIX, "_mask")
        shutil.rmtree(mask)
        kept.rename(mask)
    return out, body, P


def test_observation_refines_its_masks_with_the_model_it_is_given(spoilt, tmp_path):
    """``MultiviewObservation.model``: each mask is refined with the posed mesh before it is
    undistorted; without a model it is the dataset's mask; the files are not changed."""
    from gltrack.observe.multiview import MultiviewObservation

    path, body, P = _spoilt_copy(spoilt, tmp_path)
    ds = Dataset.open(path)
    obs = MultiviewObservation(ds, "dataset")
    _, plain = obs(1)
    for c in range(4):
        np.testing.assert_array_equal(plain[c], ds.mask(1, c))  # no lens distortion here
    obs.model = (ref.skin_vertices(body.mesh, body.skinning(P[1][None]))[0], body.mesh.faces)
    _, refined = obs(1)
    obs.model = None
    for c in range(4):
        gt = ds.gtmask(1, c)
        assert _iou(refined[c], gt) > _iou(plain[c], gt) + 0.2, c
        assert np.count_nonzero(gt & ~refined[c]) < 0.05 * gt.sum(), "the torso is back"
        np.testing.assert_array_equal(Dataset.open(path).mask(1, c), plain[c])
    # a model somewhere else gives other masks: the refinement follows the model
    far = P[1].copy()
    far[0] += 0.5
    obs.model = (ref.skin_vertices(body.mesh, body.skinning(far[None]))[0], body.mesh.faces)
    _, moved = obs(1)
    assert sum(np.count_nonzero(a != b) for a, b in zip(moved, refined)) > 100


def test_grabcut_on_a_shrunk_box_agrees_with_full_resolution():
    """``max_pixels``: GrabCut on its box scaled down (labels scaled back) finds nearly the
    mask of the full-resolution run, at a real footage's size (640x480, a figure 300 px tall
    whose sequence mask lacks the still torso)."""
    rng = np.random.default_rng(3)
    img = rng.integers(90, 170, (480, 640, 3)).astype(np.uint8)  # textured grey background
    person = np.zeros((480, 640), np.uint8)
    cv2.rectangle(person, (270, 150), (370, 330), 1, -1)    # torso
    cv2.circle(person, (320, 120), 30, 1, -1)                # head
    cv2.rectangle(person, (230, 160), (265, 300), 1, -1)     # arms
    cv2.rectangle(person, (375, 160), (410, 300), 1, -1)
    cv2.rectangle(person, (280, 335), (360, 440), 1, -1)     # legs
    person = person.astype(bool)
    img[person] = (40, 60, 150)
    img[person] = np.clip(img[person].astype(int) + rng.integers(-15, 16, (person.sum(), 3)),
                          0, 255).astype(np.uint8)
    torso = np.zeros_like(person)
    torso[150:331, 270:371] = True
    seq = person & ~torso
    model = np.zeros((480, 640), np.uint8)
    cv2.rectangle(model, (265, 100), (375, 440), 1, -1)      # a coarse model of the figure
    model = model.astype(bool)
    kw = dict(band_px=20, reach_px=80, core_px=4)
    full = refine_with_model(img, seq, model, **kw)
    small = refine_with_model(img, seq, model, max_pixels=30000, **kw)
    assert _iou(full, person) > 0.9 and _iou(small, person) > 0.9
    assert _iou(small, full) > 0.95, _iou(small, full)
    assert _iou(seq, person) < 0.7  # the input lacked the torso


def test_tracker_refines_the_masks_of_tracked_frames_only(spoilt, ctx, tmp_path):
    """With ``mask_refine = "grabcut"`` a tracked frame is scored against masks refined with
    the last estimate; the start scores the dataset's masks, and no model is left set."""
    from gltrack.track.multiview import HpsOptions, HPSTracker

    path, body, P = _spoilt_copy(spoilt, tmp_path)
    ds = Dataset.open(path)
    masks = {}
    for mode in ("none", "grabcut"):
        tr = HPSTracker(ds, body, ctx, HpsOptions(particles=12, layers=1, mask_refine=mode),
                        np.random.default_rng(0))
        assert tr.refines_masks == (mode == "grabcut")
        tr.start(0, P[0])
        est = tr.step(1)
        assert tr.obs.model is None
        assert est.info.get("masks_refined", False) == (mode == "grabcut")
        masks[mode] = [f.copy() for f in tr.likelihood._fgs]
        tr.close()
    for c in range(4):
        gt = ds.gtmask(1, c)
        assert _iou(masks["grabcut"][c], gt) > _iou(masks["none"][c], gt) + 0.1, c


def test_mask_refine_auto_is_for_upper_body_runs_on_sequence_masks():
    from gltrack.track.multiview import MultiviewOptions, resolve_mask_refine

    seq = {"masks": {"method": "sequence-foreground"}}
    assert resolve_mask_refine("auto", "upper", seq, "dataset") == "grabcut"
    assert resolve_mask_refine("auto", "full", seq, "dataset") == "none"
    assert resolve_mask_refine("auto", "upper", {}, "dataset") == "none"
    assert resolve_mask_refine("auto", "upper", seq, "background") == "none"
    assert resolve_mask_refine("grabcut", "full", {}, "background") == "grabcut"
    assert resolve_mask_refine("none", "upper", seq, "dataset") == "none"
    assert MultiviewOptions().mask_refine == "auto"
    with pytest.raises(ValueError, match="mask_refine"):
        MultiviewOptions(mask_refine="always").validate()


def test_wide_dilation_and_erosion_by_distance_match_the_morphology():
    """From :data:`DISTANCE_RADIUS` on, masks grow and shrink by thresholding the distance
    transform: the same disk as the morphology but for its rounded rim (under 1 % of the
    pixels), including a shape that touches the image border."""
    from gltrack.observe.foreground import DISTANCE_RADIUS, _disk, dilate_mask, erode_mask

    m = np.zeros((360, 640), np.uint8)
    cv2.rectangle(m, (0, 100), (400, 359), 1, -1)
    cv2.circle(m, (520, 120), 50, 1, -1)
    cv2.circle(m, (450, 300), 8, 1, -1)
    for r in (DISTANCE_RADIUS, 100, 300):
        grown, shrunk = dilate_mask(m, r), erode_mask(m, r)
        ref_grown = cv2.dilate(m, _disk(r)).astype(bool)
        ref_shrunk = cv2.erode(m, _disk(r)).astype(bool)
        assert np.count_nonzero(grown != ref_grown) < 0.01 * ref_grown.sum(), r
        assert np.count_nonzero(shrunk != ref_shrunk) <= 0.01 * max(ref_shrunk.sum(), 1), r
        assert grown[m > 0].all() and not shrunk[m == 0].any()
    assert dilate_mask(np.zeros((20, 30), bool), 50).sum() == 0
    assert erode_mask(np.ones((20, 30), bool), 50).all()  # the border counts as inside


def test_model_silhouette_drops_triangles_far_outside_the_lens():
    """Strong barrel distortion folds points far outside the image back into it (k1 = -0.6:
    a point 1.5 focal lengths off the axis lands on the other side). A triangle out there is
    not drawn; one inside the image still is, and nothing overflows."""
    from dataclasses import replace

    cam = ring_cameras((0.0, 0.9, 0.0), n=1, radius=3.0)[0].scaled(256, 192)
    cam = replace(cam, dist=np.array([-0.6, 0.0, 0.0, 0.0, 0.0]))
    d = 2.0  # metres in front of the camera
    faces = np.array([[0, 1, 2]])

    def triangle(x, y):  # normalised image coordinates of its corner, a 0.05-wide triangle
        local = np.array([[x, y, 1.0], [x + 0.05, y, 1.0], [x, y + 0.05, 1.0]]) * d
        return (local - cam.t) @ cam.R  # camera -> world
    from gltrack.observe.model_masks import lens_radius_limit

    assert lens_radius_limit(cam.dist) == pytest.approx(1 / np.sqrt(1.8), abs=1e-3)
    assert lens_radius_limit(np.zeros(5)) == np.inf
    far = triangle(1.5, 0.0)
    assert (np.abs(cam.project(far) - [cam.width / 2, cam.height / 2]) < cam.width).all(), \
        "the lens folds it into the image"
    with np.errstate(all="raise"):
        assert not model_silhouette(cam, far, faces).any()
        assert model_silhouette(cam, triangle(0.0, 0.0), faces).any()
        assert not model_silhouette(cam, triangle(1e9, 0.0), faces).any()


def test_a_refining_track_off_what_moved_is_lost(spoilt, ctx, tmp_path):
    """With refined masks the silhouette error follows the model, so the tracker also checks
    the estimate against the sequence masks: on the person it covers most of them (quality as
    usual); moved 3 m away it covers none, and the frame counts as lost (quality 1)."""
    from gltrack.track.multiview import HpsOptions, HPSTracker

    path, body, P = _spoilt_copy(spoilt, tmp_path)
    ds = Dataset.open(path)
    infos = {}
    for name, dx in (("on", 0.0), ("off", 3.0)):
        x0 = P[0].copy()
        x0[0] += dx
        tr = HPSTracker(ds, body, ctx, HpsOptions(particles=12, layers=1, mask_refine="grabcut"),
                        np.random.default_rng(0))
        tr.start(0, x0)
        infos[name] = tr.step(1).info
        tr.close()
    on, off = infos["on"], infos["off"]
    assert min(on["sequence_covered"]) > 0.3 and on["quality"] < 0.5, on  # a ghost blob too
    assert max(off["sequence_covered"]) < HPSTracker.min_sequence_covered, off
    assert off["quality"] >= 1.0
    # without refinement there is nothing to check it against, and nothing is recorded
    tr = HPSTracker(ds, body, ctx, HpsOptions(particles=12, layers=1, mask_refine="none"),
                    np.random.default_rng(0))
    tr.start(0, P[0])
    assert "sequence_covered" not in tr.step(1).info
    tr.close()
