"""gltrack render / render_overlay: overlay frames and videos of a result on its dataset."""
import cv2
import numpy as np
import pytest

from gltrack.body.model import BodyModel, body_to_meta
from gltrack.camera import depth_camera_sr4000, look_at_camera
from gltrack.cli import main
from gltrack.data.dataset import DatasetWriter
from gltrack.data.results import ResultsWriter, load_results
from gltrack.eval.metrics import EVAL_JOINTS
from gltrack.eval.overlay import (GROUNDTRUTH_BGR, TRACKED_BGR, OverlayRenderer, depth_to_bgr,
                                  render_overlay, tile)
from gltrack.render import reference as ref
from trackdata import smooth_motion

N = 5
TEXT_BOX = (slice(0, 36), slice(0, 110))  # rows, cols of the frame / error text


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("overlay")
    rng = np.random.default_rng(3)
    body = BodyModel.build()
    P = smooth_motion(body, N, rng)
    depth_cam = depth_camera_sr4000((0.3, 1.0, 3.2), (0.0, 0.9, 0.0), name="cam0")
    # odd size: the video must be padded to even dimensions
    colour_cam = look_at_camera("cam1", (1.5, 1.2, 1.5), (0.0, 0.9, 0.0), 161, 121, 60.0)
    z, _ = ref.render_candidates(body.mesh, body.skinning(P), depth_cam.K, depth_cam.R,
                                 depth_cam.t, depth_cam.width, depth_cam.height)
    yy, xx = np.mgrid[0:121, 0:161]
    background = np.stack([(xx * 1.5) % 256, (yy * 2) % 256, ((xx + yy) * 3) % 256], -1)
    with DatasetWriter(root / "ds", "depth", 30.0, [depth_cam, colour_cam],
                       body=body_to_meta(body.skeleton)) as w:
        for f in range(N):
            zf = z[f].copy()
            zf[zf == 0] = 4.0  # a back wall, so "far from the body" has non-black pixels
            w.write_depth(f, 0, zf)
            w.write_colour(f, 1, (background + 7 * f).astype(np.uint8))
        w.write_groundtruth(body.joints(P), list(body.skeleton.names), body.marker_positions(P), P)
    Q = body.dofs.validate(P + rng.normal(size=P.shape) * 0.03)
    with ResultsWriter(root / "res", "test", body.skeleton.names, body.markers.names) as w:
        J, M = body.joints(Q), body.marker_positions(Q)
        for f in range(N):
            w.append(f, Q[f], J[f], M[f])
        w.finish()
    return {"root": root, "ds": root / "ds", "res": root / "res", "body": body, "P": P, "Q": Q,
            "cams": [depth_cam, colour_cam]}


def _silhouette(scene, params, cam):
    body = scene["body"]
    z, _ = ref.render_candidates(body.mesh, body.skinning(params[None]), cam.K, cam.R, cam.t,
                                 cam.width, cam.height)
    return z[0] > 0


def _regions(sil, far_px=12):
    """(inside, far): the eroded silhouette, and pixels >= far_px from it outside the text box."""
    k = np.ones((5, 5), np.uint8)
    inside = cv2.erode(sil.astype(np.uint8), k).astype(bool)
    dist = cv2.distanceTransform((~sil).astype(np.uint8), cv2.DIST_L2, 5)
    far = dist >= far_px
    far[TEXT_BOX] = False
    return inside, far


def test_depth_to_bgr_maps_near_far_and_invalid():
    z = np.array([[1.0, 3.0, 0.0, np.nan, 2.0]])
    img = depth_to_bgr(z, 1.0, 3.0)
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[None], cv2.COLORMAP_TURBO)[0]
    np.testing.assert_array_equal(img[0, 0], lut[255])
    np.testing.assert_array_equal(img[0, 1], lut[0])
    np.testing.assert_array_equal(img[0, 2:4], 0)
    np.testing.assert_array_equal(img[0, 4], lut[128])
    with pytest.raises(ValueError):
        depth_to_bgr(z, 2.0, 1.0)


def test_colour_frame_exact_outside_and_drawn_inside(scene):
    k = 2
    with OverlayRenderer(scene["res"], scene["ds"], cameras="cam1") as r:
        img = r.camera_frame(k, 1)
        raw = r.dataset.colour(k, 1)
    cam = scene["cams"][1]
    sil = _silhouette(scene, scene["Q"][k], cam)
    inside, far = _regions(sil)
    assert inside.sum() > 200 and far.sum() > 5000
    np.testing.assert_array_equal(img[far], raw[far])
    changed = np.any(img != raw, axis=-1)
    assert changed[inside].mean() > 0.95
    # both skeletons are drawn in their colours
    assert np.any(np.all(img == TRACKED_BGR, axis=-1))
    assert np.any(np.all(img == GROUNDTRUTH_BGR, axis=-1))
    # the text corner is written
    assert np.any(img[TEXT_BOX] != raw[TEXT_BOX])


def test_overlay_follows_the_pose(scene):
    result = load_results(scene["res"])
    moved = dict(result)
    moved["params"] = result["params"].copy()
    moved["params"][:, 0] += 0.4  # 40 cm to the subject's left
    with OverlayRenderer(result, scene["ds"], cameras=0) as a, \
            OverlayRenderer(moved, scene["ds"], cameras=0) as b:
        fa, fb = a.camera_frame(1, 0), b.camera_frame(1, 0)
        raw = a.input_image(1, 0)
    cam = scene["cams"][0]
    sil_a = _silhouette(scene, result["params"][1], cam)
    only_b = _silhouette(scene, moved["params"][1], cam) & _regions(sil_a, far_px=6)[1]
    assert only_b.sum() > 100
    # where only the moved body is, the first overlay shows the input and the second does not
    np.testing.assert_array_equal(fa[only_b], raw[only_b])
    assert np.any(fb != raw, axis=-1)[only_b].mean() > 0.9


def test_frame_error_matches_independent_computation(scene):
    with OverlayRenderer(scene["res"], scene["ds"]) as r:
        errs = [r.frame_error(i) for i in range(N)]
    body = scene["body"]
    idx = [body.skeleton.index(n) for n in EVAL_JOINTS]
    expect = np.linalg.norm(body.joints(scene["Q"])[:, idx] - body.joints(scene["P"])[:, idx],
                            axis=-1).mean(axis=1)
    np.testing.assert_allclose(errs, expect, rtol=1e-9)
    assert np.all(expect > 0.005)


def test_mp4_video_frames(scene, tmp_path):
    out = render_overlay(scene["res"], scene["ds"], tmp_path / "v.mp4", cameras=0, progress=False)
    assert out == tmp_path / "v.mp4"
    cap = cv2.VideoCapture(str(out))
    assert cap.isOpened()
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    cap.release()
    assert len(frames) == N
    assert frames[0].shape == (144, 176, 3)
    k = 3
    with OverlayRenderer(scene["res"], scene["ds"], cameras=0) as r:
        raw = depth_to_bgr(r.dataset.depth(k, 0), *r.depth_range["cam0"])
    inside, far = _regions(_silhouette(scene, scene["Q"][k], scene["cams"][0]))
    diff = np.abs(frames[k].astype(float) - raw.astype(float)).mean(axis=-1)
    # MPEG-4 is lossy: far from the body only coding noise, on the body the model colours
    assert diff[far].mean() < 4.0
    assert diff[inside].mean() > 25.0


def test_tiled_cameras_and_avi_via_cli(scene, tmp_path):
    with OverlayRenderer(scene["res"], scene["ds"]) as r:
        both = r.frame(0)
        left, right = r.camera_frame(0, 0), r.camera_frame(0, 1)
    assert both.shape == (144, 352, 3)
    np.testing.assert_array_equal(both[:, :176], left)
    scaled = cv2.resize(right, (176, 132), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(both[:132, 176:], scaled)
    assert not both[132:, 176:].any()

    out = tmp_path / "c.avi"
    assert main(["-q", "render", str(scene["res"]), str(scene["ds"]), "--out", str(out),
                 "--camera", "cam1", "--max-frames", "2"]) == 0
    cap = cv2.VideoCapture(str(out))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    cap.release()
    assert n == 2 and size == (162, 122)  # 161 x 121 padded to even


def test_tile_grid():
    imgs = [np.full((10, 20, 3), v, np.uint8) for v in (50, 100, 150)]
    g = tile(imgs)
    assert g.shape == (20, 40, 3)
    assert (g[:10, :20] == 50).all() and (g[:10, 20:] == 100).all()
    assert (g[10:, :20] == 150).all() and not g[10:, 20:].any()
    assert tile(imgs[:1]) is imgs[0]


def test_render_cli_errors(scene, tmp_path, capsys):
    res, ds = str(scene["res"]), str(scene["ds"])
    assert main(["render", res, ds, "--out", str(tmp_path / "v.gif")]) == 2
    assert main(["render", res, ds, "--out", str(tmp_path / "v.mp4"), "--camera", "cam9"]) == 1
    assert "cam9" in capsys.readouterr().err
    assert not (tmp_path / "v.mp4").exists()
    assert main(["render", res, str(tmp_path / "nods"), "--out", str(tmp_path / "v.mp4")]) == 1


def test_distorted_camera_input_is_undistorted(scene):
    from dataclasses import replace

    k = 1
    with OverlayRenderer(scene["res"], scene["ds"], cameras="cam1") as r:
        raw = r.dataset.colour(k, 1)
        plain = r.camera_frame(k, 1)
        r.dataset.cameras[1] = cam = replace(r.dataset.cameras[1],
                                             dist=np.array([-0.2, 0.05, 0.0, 0.0, 0.0]))
        img = r.camera_frame(k, 1)
    _, far = _regions(_silhouette(scene, scene["Q"][k], cam))
    expect = cam.undistort_image(raw)
    np.testing.assert_array_equal(img[far], expect[far])
    assert np.any(img[far] != plain[far])


def test_multiview_grid_video_with_iou(tmp_path):
    """Four colour cameras: a 2x2 grid video of the grid's size, the model drawn where it is,
    the input elsewhere, and each camera's IoU from frames.jsonl in its corner."""
    from gltrack.bench.multiview import RING, render_dataset
    from gltrack.bench.rigs import ring_cameras

    body = BodyModel.build()
    P = smooth_motion(body, 3, np.random.default_rng(1))
    pelvis = body.joints(P[1:2])[0, 0]
    cams = ring_cameras((pelvis[0], 0.9, pelvis[2]), **dict(RING, radius=3.0))
    ds = render_dataset(tmp_path / "ds", body, P, cams, 15.0, np.random.default_rng(2), noise=0.0)
    ious = [[0.9, 0.8, 0.55, 0.7]] * 3
    with ResultsWriter(tmp_path / "res", "hps", body.skeleton.names, body.markers.names) as w:
        for f in range(3):
            w.append(f, P[f], body.joints(P[f:f + 1])[0], body.marker_positions(P[f:f + 1])[0],
                     info={"iou": ious[f]})
        w.finish()
    out = tmp_path / "grid.mp4"
    assert main(["-q", "render", str(tmp_path / "res"), str(ds), "--out", str(out)]) == 0
    cap = cv2.VideoCapture(str(out))
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    cap.release()
    assert len(frames) == 3 and frames[0].shape == (2 * 96, 2 * 128, 3)
    with OverlayRenderer(tmp_path / "res", ds) as r:
        assert [r.frame_iou(1, c) for c in range(4)] == ious[1]
        raw = [r.input_image(1, c) for c in range(4)]
    for c, cam in enumerate(cams):
        cell = frames[1][96 * (c // 2):96 * (c // 2 + 1), 128 * (c % 2):128 * (c % 2 + 1)]
        inside, far = _regions(_silhouette({"body": body}, P[1], cam), far_px=8)
        assert inside.sum() > 50 and far.sum() > 2000
        diff = np.abs(cell.astype(float) - raw[c].astype(float)).mean(axis=-1)
        # lossy video of a random-texture background: about 6 grey levels of coding noise far
        # from the body, about 90 on it
        assert diff[far].mean() < 12.0 and diff[inside].mean() > 40.0, c
        assert np.any(diff[TEXT_BOX] > 50)  # frame, camera and IoU printed
