"""Body keypoints (:mod:`gltrack.observe.keypoints`): the robust triangulation, the landmark
model on real frames (OpenCV's DNN; skipped without the model or ../shared), ``keypoints.npz``
in a dataset, ``gltrack ingest`` writing it, and the multi-view tracker's keypoint cost."""
import json

import cv2
import numpy as np
import pytest

from gltrack.camera import look_at_camera, triangulate
from gltrack.observe.keypoints import (BODY_JOINTS, DISTANCE_CAP, INPUT, LANDMARKS, MIRROR,
                                       NAMES, Detection, PoseLandmarker, confirmed_views,
                                       detect_sequence, keypoint_distance, segmentation_size,
                                       triangulate_keypoints)

from conftest import REPO
from test_triangulate import rig as _rig  # four distorted cameras round a person
from trackdata import landmark_model

LABELS = REPO / "scripts" / "data" / "pose2sim_balancing_keypoints.json"


def _model():
    return landmark_model()


def test_mirror_is_the_left_right_exchange():
    assert sorted(MIRROR) == list(range(33)) and (MIRROR[MIRROR] == np.arange(33)).all()
    for name, i in LANDMARKS.items():
        other = name.replace("l_", "r_") if name.startswith("l_") else name.replace("r_", "l_")
        assert MIRROR[i] == LANDMARKS[other] and NAMES[i] == name
    assert set(BODY_JOINTS) <= set(LANDMARKS)


def test_triangulation_undoes_exchanged_sides_and_drops_a_wrong_view():
    cams = _rig()
    rng = np.random.default_rng(0)
    X = rng.uniform([-0.5, 0.0, -0.5], [0.5, 1.9, 0.5], size=(33, 3))
    uv = np.stack([c.project(X) for c in cams])
    bad = uv.copy()
    bad[1] = bad[1, MIRROR]            # view 1 took left for right
    bad[2, 27] += (120.0, -40.0)       # view 2's left ankle is somewhere else
    P, r, swapped = triangulate_keypoints(cams, bad)
    assert swapped.tolist() == [False, True, False, False]
    np.testing.assert_allclose(P, X, atol=1e-6)
    assert np.isnan(r[2, 27]) and np.nanmax(r) < 1e-4
    # the plain triangulation of the same views is far off: the check is what mends it
    P0, _ = triangulate(cams, bad)
    assert np.nanmedian(np.linalg.norm(P0 - X, axis=1)) > 0.05
    # observations the model did not believe in are left out; one view is not enough
    vis = np.ones((4, 33))
    vis[1:, 5] = 0.2
    vis[2, 6] = 0.2
    P, r, _ = triangulate_keypoints(cams, uv, vis)
    assert np.isnan(P[5]).all() and np.isnan(r[2, 6])
    np.testing.assert_allclose(P[6], X[6], atol=1e-6)
    # a view that found nobody (NaN) takes no part
    none = uv.copy()
    none[3] = np.nan
    P, r, swapped = triangulate_keypoints(cams, none)
    np.testing.assert_allclose(P, X, atol=1e-6)
    assert not swapped[3] and np.isnan(r[3]).all()
    with pytest.raises(ValueError, match=r"uv must be \(4, 33, 2\)"):
        triangulate_keypoints(cams, uv[:, :12])


def test_confirmed_views_need_enough_points_that_fit():
    cams = [look_at_camera(f"c{i}", (3.0 * np.sin(a), 1.5, 3.0 * np.cos(a)), (0, 1, 0), 640,
                           360, 50.0) for i, a in enumerate((0.0, 1.6, 3.1))]
    res = np.full((2, 3, 33), 4.0)  # 4 px of 640: fits (the limit is 10 px)
    res[0, 1] = 20.0  # a view whose points do not fit the others
    res[1, 2, 7:] = np.nan  # 7 points used: too few to say
    res[1, 0, :20] = 30.0  # 20 of 33 off: the median is off
    ok = confirmed_views(cams, res)
    assert ok.tolist() == [[True, False, True], [False, True, False]]
    assert confirmed_views(cams, np.full((1, 3, 33), np.nan)).tolist() == [[False] * 3]


def test_keypoint_distance_is_the_mean_capped_distance():
    targets = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [np.nan, np.nan, np.nan]])
    joints = np.zeros((3, 3, 3))
    joints[:, 1] = [1.0, 0.0, 0.0]
    joints[1, 0] = [0.05, 0.0, 0.0]
    joints[2, 0] = [5.0, 0.0, 0.0]     # far off: counts as the cap
    joints[:, 2] = 9.0                 # no target: left out
    np.testing.assert_allclose(keypoint_distance(joints, targets), [0.0, 0.025, DISTANCE_CAP / 2])
    assert np.isnan(keypoint_distance(joints, np.full((3, 3), np.nan))).all()


def test_person_probability_maps_the_crop_back_to_the_image():
    """The segmentation of a rotated, scaled crop goes back where the crop came from: a square
    of "person" logits in the crop lands on the image pixels that map into that square, at
    the image's size and at a smaller one."""
    H, W = 90, 120
    a, s = np.radians(30), 2.0  # crop pixels per image pixel, and the crop's rotation
    A = s * np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
    M = np.hstack([A, (np.array([INPUT / 2, INPUT / 2]) - A @ np.array([60.0, 45.0]))[:, None]])
    logits = np.full((INPUT, INPUT), -20.0, np.float32)
    logits[100:160, 90:150] = 20.0
    det = Detection(np.zeros((33, 2)), np.ones(33), 1.0, logits, M)
    p = det.person_probability((H, W))
    assert p.shape == (H, W) and p.dtype == np.float32
    v, u = np.mgrid[0:H, 0:W]
    cx, cy = np.moveaxis(np.tensordot(M[:, :2], np.stack([u, v]), 1), 0, -1).transpose(2, 0, 1) \
        + M[:, 2][:, None, None]
    inside = (cx >= 91) & (cx <= 148) & (cy >= 101) & (cy <= 158)
    outside = (cx < 88) | (cx > 151) | (cy < 98) | (cy > 161)
    assert inside.sum() > 500 and np.all(p[inside] > 0.99) and np.all(p[outside] < 0.01)
    # a smaller output is the same picture
    w, h = segmentation_size(W, H, 60)
    assert (w, h) == (60, 45)
    small = det.person_probability((H, W), (w, h))
    back = cv2.resize(small, (W, H), interpolation=cv2.INTER_LINEAR) > 0.5
    assert np.mean(back != (p > 0.5)) < 0.02
    # the output follows the logits; nothing found is all zeros
    logits[100:160, 90:150] = -20.0
    assert det.person_probability((H, W)).max() < 0.01
    assert Detection.empty().person_probability((H, W)).max() == 0.0
    assert segmentation_size(W, H, None) == (W, H) and segmentation_size(W, H, 500) == (W, H)


def _labelled_frame(shared, frame=50, cam="cam_01"):
    video = shared / "video" / "pose2sim_balancing_4cam" / f"{cam.replace('_', '')}.mp4"
    if not video.is_file():
        pytest.skip(f"{video} absent")
    cap = cv2.VideoCapture(str(video))
    cap.set(cv2.CAP_PROP_POS_FRAMES, frame)
    ok, img = cap.read()
    cap.release()
    assert ok
    labels = json.loads(LABELS.read_text())["frames"][str(frame)][cam]
    return img, labels


def test_the_model_finds_the_joints_a_person_labelled(shared):
    """MediaPipe's landmarks in a real frame of the Pose2Sim take, against the hand labels: the
    crop is found from a rough box (the labels' box, 30 % wider) and then from the model's own
    alignment points; the median error is what the take measured (16 px of 1920)."""
    landmarker = PoseLandmarker(_model())
    img, labels = _labelled_frame(shared)
    pts = np.array([v[:2] for v in labels.values()])
    lo, hi = pts.min(0), pts.max(0)
    pad = 0.15 * (hi - lo)
    det, xy = landmarker.detect(img, box=(*(lo - pad), *(hi + pad)))
    assert det.presence > 0.9 and xy.shape == (39, 2)
    err = [np.hypot(*(det.uv[LANDMARKS[j]] - v[:2])) for j, v in labels.items() if j != "nose"]
    assert np.median(err) < 30, err
    # the next frame's crop from these points finds the same joints without a box
    det2, _ = landmarker.detect(img, previous=xy, passes=1)
    err2 = [np.hypot(*(det2.uv[LANDMARKS[j]] - v[:2])) for j, v in labels.items() if j != "nose"]
    assert np.median(err2) < 30, err2
    # a mirrored image gives mirrored points: the output follows the input
    flipped, _ = landmarker.detect(img[:, ::-1].copy(), box=(img.shape[1] - 1 - hi[0] - pad[0],
                                                            lo[1] - pad[1],
                                                            img.shape[1] - 1 - lo[0] + pad[0],
                                                            hi[1] + pad[1]))
    assert np.median(np.abs(flipped.uv[:, 0] - det.uv[:, 0])) > 50
    # the person's segmentation holds the labelled joints and not much more than the person
    prob = det.person_probability(img.shape[:2])
    on = [prob[int(round(v[1])), int(round(v[0]))] > 0.5 for v in labels.values()]
    assert np.mean(on) >= 0.8, on
    assert 0.03 < np.mean(prob > 0.5) < 0.3
    # nobody in the picture: nothing found
    blank, none = landmarker.detect(np.full_like(img, 128))
    assert blank.presence == 0.0 and none is None and np.isnan(blank.uv).all()
    assert blank.person_probability(img.shape[:2]).max() == 0.0


def test_detect_sequence_starts_from_the_mask_and_follows(shared):
    landmarker = PoseLandmarker(_model())
    img, labels = _labelled_frame(shared)
    pts = np.array([v[:2] for v in labels.values()])
    mask = np.zeros(img.shape[:2], bool)
    # a silhouette's box reaches past the labelled joints: the head above, the feet below
    pad = 0.15 * (pts.max(0) - pts.min(0))
    lo, hi = (pts.min(0) - pad).astype(int), (pts.max(0) + pad).astype(int)
    mask[lo[1]:hi[1], lo[0]:hi[0]] = True
    mask[:40, :40] = True  # a small blob elsewhere: the largest one places the crop
    small = cv2.resize(mask.astype(np.uint8), (mask.shape[1] // 4, mask.shape[0] // 4)) > 0
    calls = []
    uv, vis, pres, seg = detect_sequence(landmarker, [img, img], [small, small],
                                         progress=lambda: calls.append(1), segment=480)
    assert uv.shape == (2, 33, 2) and vis.shape == (2, 33) and len(calls) == 2
    assert seg.shape == (2, 480, 270) and seg.dtype == np.uint8 and (seg > 127).mean() > 0.03
    assert (pres > 0.9).all()
    err = [np.hypot(*(uv[1, LANDMARKS[j]] - v[:2])) for j, v in labels.items() if j != "nose"]
    assert np.median(err) < 30


def _tiny_dataset(path, frames=2, keypoints=True):
    from gltrack.data.dataset import DatasetWriter

    cams = [look_at_camera(f"c{k}", (3 * np.cos(a), 1.5, 3 * np.sin(a)), (0, 1, 0), 32, 24, 50)
            for k, a in enumerate((0.0, 2.0, 4.0))]
    with DatasetWriter(path, "multiview", 30, cams) as w:
        for f in range(frames):
            for k in range(3):
                w.write_colour(f, k, np.zeros((24, 32, 3), np.uint8))
        uv = np.random.default_rng(0).uniform(0, 20, (frames, 3, 33, 2))
        if keypoints:
                w.write_keypoints(uv, np.ones((frames, 3, 33)), np.zeros((frames, 33, 3)),
                              np.zeros((frames, 3, 33)), NAMES)
    return uv


def test_dataset_keypoints_round_trip_and_bad_files(tmp_path):
    from gltrack.data.dataset import Dataset

    uv = _tiny_dataset(tmp_path / "ds")
    kp = Dataset.open(tmp_path / "ds").keypoints()
    np.testing.assert_allclose(kp["uv"], uv, rtol=1e-6)
    assert kp["points"].shape == (2, 33, 3) and kp["names"] == list(NAMES)
    with np.load(tmp_path / "ds" / "keypoints.npz") as z:
        arrays = dict(z)
    arrays["points"] = arrays["points"][:1]
    np.savez(tmp_path / "ds" / "keypoints.npz", **arrays)
    with pytest.raises(ValueError, match=r"keypoints\.npz: points must be float \(2, 33, 3\)"):
        Dataset.open(tmp_path / "ds")
    del arrays["residual"]
    np.savez(tmp_path / "ds" / "keypoints.npz", **arrays)
    with pytest.raises(ValueError, match=r"keypoints\.npz: missing residual"):
        Dataset.open(tmp_path / "ds")
    _tiny_dataset(tmp_path / "none", 1, keypoints=False)
    assert Dataset.open(tmp_path / "none").keypoints() is None


def test_detect_sequence_searches_back_for_the_frames_it_missed(shared):
    """The labelled frame at half size in the middle of a black canvas six times that: the
    whole canvas is too coarse a crop to find the person, so frame 0 (no mask) is missed at
    first; frame 1 is found from its mask, and frame 0 again from frame 1's crop. A blank
    frame stays empty."""
    landmarker = PoseLandmarker(_model())
    img, labels = _labelled_frame(shared)
    img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
    H, W = img.shape[:2]
    canvas = np.zeros((6 * H, 6 * W, 3), np.uint8)
    oy, ox = 5 * H // 2, 5 * W // 2
    canvas[oy:oy + H, ox:ox + W] = img
    pts = 0.5 * np.array([v[:2] for v in labels.values()]) + [ox, oy]
    # a silhouette's box reaches past the labelled joints: the head above, the feet below
    pad = 0.15 * (pts.max(0) - pts.min(0))
    lo, hi = (pts.min(0) - pad).astype(int), (pts.max(0) + pad).astype(int)
    mask = np.zeros(canvas.shape[:2], bool)
    mask[lo[1]:hi[1], lo[0]:hi[0]] = True
    first, _ = landmarker.detect(canvas)
    assert first.presence < 0.5  # what the forward pass alone leaves in frame 0
    uv, vis, pres = detect_sequence(landmarker, [canvas, canvas], [None, mask])
    assert (pres > 0.9).all()
    # as close to the hand labels as a full-size frame's detection (30 px at full size)
    err = [np.hypot(*(uv[0, LANDMARKS[j]] - (0.5 * np.array(v[:2]) + [ox, oy])))
           for j, v in labels.items() if j != "nose"]
    assert np.median(err) < 15, err
    blank = np.zeros_like(canvas)
    uv, vis, pres = detect_sequence(landmarker, [blank, canvas], [None, mask])
    assert pres[0] == 0.0 and np.isnan(uv[0]).all() and pres[1] > 0.9


def test_ingest_writes_the_keypoints_of_the_shared_take(shared, tmp_path, monkeypatch):
    """Three labelled-neighbourhood frames of the Pose2Sim take: every camera finds the person,
    the triangulated joints are within 10 cm of the hand labels' triangulation, and
    ``keypoints="none"`` writes none."""
    import importlib.util

    from gltrack.data.calibration import load_any_calibration
    from gltrack.data.dataset import Dataset
    from gltrack.data.ingest import ingest

    model = _model()
    folder = shared / "video" / "pose2sim_balancing_4cam"
    if not folder.is_dir():
        pytest.skip(f"{folder} absent")
    videos = [folder / f"cam0{i}.mp4" for i in (1, 2, 3, 4)]
    r = ingest(folder / "Calib_qualisys.toml", videos, tmp_path / "p2s", frames=(49, 52),
               scale=0.25, progress=False, keypoints=str(model))
    k = r["keypoints"]
    assert k["model"] == "pose_landmark_full.tflite" and k["found"] == [1.0] * 4
    ds = Dataset.open(tmp_path / "p2s")
    meta = json.loads((tmp_path / "p2s" / "meta.json").read_text())
    assert meta["keypoints"] == k
    # at a quarter of the size (480 px) a view's points are confirmed in most frames (at the
    # default 640 px, in all 100 frames of every camera); the confirmed views' segmentation
    # shaped the masks (the "prior" cue)
    assert min(k["confirmed"]) > 0 and np.mean(k["confirmed"]) >= 0.75, k
    assert "prior" in meta["masks"]["cues"] and max(meta["masks"]["prior_fraction"]) == 1.0
    kp = ds.keypoints()
    body = [LANDMARKS[j] for j in BODY_JOINTS]
    assert np.isfinite(kp["points"][:, body]).all()
    spec = importlib.util.spec_from_file_location("labelled_reference",
                                                  REPO / "scripts" / "labelled_reference.py")
    lr = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(lr)
    hand = lr.load_labels(LABELS)
    frames, P, _ = lr.reference_points(hand, load_any_calibration(folder / "Calib_qualisys.toml"))
    ref = P[list(frames).index(50)]
    ours = ds.to_user_frame(kp["points"][1])  # dataset frame 1 = video frame 50
    d = [np.linalg.norm(ours[LANDMARKS[j]] - ref[hand["joints"].index(j)]) for j in BODY_JOINTS]
    assert np.median(d) < 0.10, np.round(d, 3)
    r = ingest(folder / "Calib_qualisys.toml", videos, tmp_path / "none", frames=(49, 50),
               scale=0.1, progress=False, masks="none", keypoints="none")
    assert r["keypoints"] is None and not (tmp_path / "none" / "keypoints.npz").exists()
    monkeypatch.setenv("GLTRACK_POSE_MODEL", str(tmp_path / "missing.tflite"))
    with pytest.raises(FileNotFoundError, match="missing.tflite: no pose landmark model"):
        ingest(folder / "Calib_qualisys.toml", videos, tmp_path / "bad", frames=(49, 50),
               scale=0.1, progress=False, masks="none")
    assert not (tmp_path / "bad").exists()


def test_the_tracker_adds_the_keypoints_distance_to_its_cost(tmp_path, ctx):
    """A rendered dataset with keypoints on the true joints: the keypoint cost is 0 at the true
    pose and grows away from it, the weights rank by silhouette error plus that cost, a step
    reports the estimate's distance, and ``keypoints = 0`` (or a dataset without the file)
    leaves the silhouette weights alone."""
    from gltrack.body.model import BodyModel
    from gltrack.sample import bandouch_weights
    from gltrack.track.multiview import HpsOptions, HPSTracker
    from trackdata import keypoint_dataset

    body = BodyModel.build()
    d = body.dofs
    P = np.repeat(d.zero(body.skeleton)[None], 3, axis=0)
    P[:, 2] = [0.0, 0.05, 0.1]
    P[:, d.index("l_shoulder_rz")] = [-1.2, -1.0, -0.8]
    P = d.validate(P)
    ds, _ = keypoint_dataset(tmp_path / "ds", body, P)
    rng = np.random.default_rng(5)
    X = np.repeat(P[2][None], 6, axis=0)
    X[1:] += rng.normal(0.0, 0.1, X[1:].shape) * np.arange(1, 6)[:, None]
    X = d.validate(X)
    for opt, with_kp in ((HpsOptions(particles=12), True), (HpsOptions(particles=12, keypoints=0), False)):
        tr = HPSTracker(ds, body, ctx, opt, np.random.default_rng(0))
        try:
            tr.start(0, P[0])
            tr.observe(2)
            tr.observe_keypoints(2)
            e_s, c_a = tr.scores(X)
            w = tr.weights(X)
            if not with_kp:
                assert tr.kp_target is None and tr.keypoint_cost(X) == 0.0
                np.testing.assert_allclose(w, bandouch_weights(e_s, c_a, 0.7, 0.3))
                continue
            dist = tr.keypoint_distance(X)
            assert dist[0] < 1e-9 and (dist[1:] > 0.01).all()
            cost = tr.keypoint_cost(X)
            np.testing.assert_allclose(cost, tr.area * dist / 0.15)
            np.testing.assert_allclose(w, bandouch_weights(e_s + cost, c_a, 0.7, 0.3))
            # another frame's keypoints move the cost of the same poses
            tr.observe_keypoints(0)
            assert not np.allclose(tr.keypoint_distance(X), dist)
            est = tr.step(1)
            assert 0.0 <= est.info["keypoint_m"] < 0.1
        finally:
            tr.close()
