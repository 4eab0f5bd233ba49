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
from gltrack.eval import overlay
from gltrack.eval.overlay import (GROUNDTRUTH_BGR, OUTLINE_BGR, PART_GROUPS, TRACKED_BGR,
                                  OverlayRenderer, depth_to_bgr, part_colour, render_overlay,
                                  tile)
from gltrack.render import reference as ref
from trackdata import smooth_motion

N = 5
TEXT_BOX = (slice(0, 40), slice(0, 130))  # rows, cols of the frame / error text


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


def _read_video(path):
    """(frames, fourcc) of a video file, every frame decoded."""
    cap = cv2.VideoCapture(str(path))
    assert cap.isOpened()
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode(errors="replace")
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    cap.release()
    return frames, fourcc.lower()


#: FOURCCs OpenCV reads back for each codec render_overlay reports
READ_FOURCC = {"h264": ("h264", "avc1"), "mpeg4": ("fmp4", "mp4v"), "mjpeg": ("mjpg",)}


def test_mp4_video_frames(scene, tmp_path):
    out = render_overlay(scene["res"], scene["ds"], tmp_path / "v.mp4", cameras=0, progress=False,
                         min_height=0)
    assert out.path == tmp_path / "v.mp4" and out.frames == N
    frames, fourcc = _read_video(out.path)
    assert fourcc in READ_FOURCC[out.codec], (out, fourcc)
    assert len(frames) == N
    # the camera (176 x 144) above the legend strip, the height padded to even
    assert frames[0].shape[1] == 176 and frames[0].shape[0] > 144 + 20
    assert (out.size[1], out.size[0]) == frames[0].shape[:2]
    k = 3
    with OverlayRenderer(scene["res"], scene["ds"], cameras=0) as r:
        raw = depth_to_bgr(r.dataset.depth(k, 0), *r.depth_range["cam0"])
    inside, far = _regions(_silhouette(scene, scene["Q"][k], scene["cams"][0]))
    diff = np.abs(frames[k][:144].astype(float) - raw.astype(float)).mean(axis=-1)
    # lossy coding: far from the body only coding noise, on the body the model colours
    assert diff[far].mean() < 4.0
    assert diff[inside].mean() > 25.0


def test_video_codec_is_reported_and_read_back(scene, tmp_path, monkeypatch, caplog):
    """H.264 when an encoder is at hand (checked by reading the file back, with its index
    first), else MPEG-4 Part 2 with a warning saying browsers will not play it."""
    import logging

    if overlay.ffmpeg_h264() is not None or overlay.h264_available():
        out = render_overlay(scene["res"], scene["ds"], tmp_path / "h.mp4", cameras=0,
                             progress=False, max_frames=3)
        assert out.codec == "h264" and out.frames == 3
        frames, fourcc = _read_video(out.path)
        assert fourcc in READ_FOURCC["h264"] and len(frames) == 3
        assert frames[0].shape[:2] == (out.size[1], out.size[0])
        if out.encoder.startswith("ffmpeg"):
            data = out.path.read_bytes()
            assert 0 < data.find(b"moov") < data.find(b"mdat"), "+faststart: the index first"
    # no H.264 encoder: mp4v, and a warning that says so and how to get one
    monkeypatch.setattr(overlay, "_FFMPEG", None)
    monkeypatch.setattr(overlay, "_H264", False)
    with caplog.at_level(logging.INFO, logger="gltrack.eval.overlay"):
        out = render_overlay(scene["res"], scene["ds"], tmp_path / "m.mp4", cameras=0,
                             progress=False, max_frames=2)
    assert (out.codec, out.encoder, out.frames) == ("mpeg4", "OpenCV mp4v", 2)
    frames, fourcc = _read_video(out.path)
    assert fourcc in READ_FOURCC["mpeg4"] and len(frames) == 2
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("browsers" in m and "imageio-ffmpeg" in m for m in warned), warned
    assert any("mpeg4 by OpenCV mp4v" in r.getMessage() for r in caplog.records)
    # an ffmpeg that does not run: OpenCV's encoder instead, said in a warning
    monkeypatch.setattr(overlay, "_FFMPEG", (str(tmp_path / "no-ffmpeg"), "PATH"))
    caplog.clear()
    out = render_overlay(scene["res"], scene["ds"], tmp_path / "n.mp4", cameras=0,
                         progress=False, max_frames=1)
    assert out.codec == "mpeg4" and len(_read_video(out.path)[0]) == 1
    assert any("no-ffmpeg" in r.getMessage() for r in caplog.records)


def _turbo_index(pixels):
    """Index into the TURBO map of each (N, 3) BGR pixel that is exactly one of its colours,
    -1 for the others."""
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[None], cv2.COLORMAP_TURBO)[0]
    key = lambda a: (a[..., 0].astype(np.int64) << 16) | (a[..., 1].astype(np.int64) << 8) \
        | a[..., 2]  # noqa: E731
    table = dict(zip(key(lut).tolist(), range(256)))
    return np.array([table.get(v, -1) for v in key(pixels).tolist()])


def test_legend_and_depth_colour_bar(scene):
    with OverlayRenderer(scene["res"], scene["ds"]) as r:
        plain = r.frame(0, legend=False)
        img = r.frame(0)
        near, far = r.depth_range["cam0"]
    with OverlayRenderer(scene["res"], scene["ds"], cameras="cam1") as r:
        colour_only = r.frame(0)
    # the legend is a strip below the cameras, which are unchanged
    assert img.shape[1] == plain.shape[1] and img.shape[0] > plain.shape[0] + 30
    np.testing.assert_array_equal(img[:plain.shape[0]], plain)
    strip = img[plain.shape[0]:]
    colours = {tuple(int(v) for v in c) for c in np.unique(strip.reshape(-1, 3), axis=0)}
    for label, k in PART_GROUPS:
        assert part_colour(k) in colours, label
    for bgr in (OUTLINE_BGR, TRACKED_BGR, GROUNDTRUTH_BGR):
        assert tuple(bgr) in colours
    assert len({part_colour(k) for _, k in PART_GROUPS}) == len(PART_GROUPS)
    # the depth colour bar: rows whose pixels are nearly all TURBO colours, their indices falling
    # monotonically from near (255, left) to far (0, right)
    idx = np.stack([_turbo_index(row) for row in strip])
    bar_rows = np.flatnonzero((idx >= 0).mean(axis=1) > 0.5)
    assert len(bar_rows) >= 5
    for y in bar_rows:
        v = idx[y][idx[y] >= 0]
        assert v[0] >= 250 and v[-1] <= 5 and np.all(np.diff(v) <= 0), y
        assert len(np.unique(v)) > 100  # a gradient, not a few blocks
    # ... which the colour camera alone does not get
    with OverlayRenderer(scene["res"], scene["ds"], cameras="cam1") as r:
        h = r.frame(0, legend=False).shape[0]
    cidx = np.stack([_turbo_index(row) for row in colour_only[h:]])
    assert not np.any((cidx >= 0).mean(axis=1) > 0.5)
    assert near < far


def test_depth_body_coloured_by_part(scene):
    """In a depth overlay each part shows its own colour: the thighs of the two sides differ,
    and each is nearer its own part colour than the other side's."""
    from gltrack.body.mesh import PARTS

    k, c = 2, 0
    cam, body = scene["cams"][c], scene["body"]
    with OverlayRenderer(scene["res"], scene["ds"], cameras=c) as r:
        img = r.camera_frame(k, c, scale=3)[1::3, 1::3]  # the centre of each enlarged pixel
        raw = r.input_image(k, c)
    posed = ref.skin_vertices(body.mesh, body.skinning(scene["Q"][k][None]))[0]
    pc = ref.world_to_camera(posed, cam.R, cam.t)
    _, tri = ref.rasterize(pc, body.mesh.faces, cam.K, cam.width, cam.height)
    part = np.where(tri >= 0, body.mesh.part[body.mesh.faces[np.maximum(tri, 0), 0]], -1)
    mean = {}
    for name in ("l_thigh", "r_thigh", "torso"):
        m = cv2.erode((part == PARTS.index(name)).astype(np.uint8), np.ones((3, 3), np.uint8))
        m = m.astype(bool)
        assert m.sum() >= 10, name
        mean[name] = np.median(img[m].astype(float), axis=0)
        assert np.abs(mean[name] - np.median(raw[m].astype(float), axis=0)).sum() > 60, name

    def unit(v):
        v = np.asarray(v, float)
        return v / np.linalg.norm(v)

    assert np.abs(mean["l_thigh"] - mean["r_thigh"]).sum() > 80
    for own, other in (("l_thigh", "r_thigh"), ("r_thigh", "l_thigh")):
        got = unit(mean[own])
        assert got @ unit(part_colour(PARTS.index(own))) \
            > got @ unit(part_colour(PARTS.index(other))), own


def test_tiled_cameras_and_avi_via_cli(scene, tmp_path, capsys):
    with OverlayRenderer(scene["res"], scene["ds"]) as r:
        both = r.frame(0, legend=False)
        left, right = r.camera_frame(0, 0), r.camera_frame(0, 1)
    assert both.shape == (144, 352, 3)
    np.testing.assert_array_equal(both[:, :176], left)
    scaled = cv2.resize(right, (176, 132), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(both[:132, 176:], scaled)
    assert not both[132:, 176:].any()

    out = tmp_path / "c.avi"
    capsys.readouterr()
    assert main(["-q", "render", str(scene["res"]), str(scene["ds"]), "--out", str(out),
                 "--camera", "cam1", "--max-frames", "2"]) == 0
    assert "mjpeg, 2 frames" in capsys.readouterr().out
    with OverlayRenderer(scene["res"], scene["ds"], cameras="cam1") as r:
        k = r.upscale_for(overlay.MIN_HEIGHT)
        expect = r.frame(0, scale=k).shape
    assert k == 4  # 121 rows -> 484, at least MIN_HEIGHT
    cap = cv2.VideoCapture(str(out))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    cap.release()
    # 161 x 121 enlarged 4 times, the legend below, padded to even
    assert n == 2 and size == (644, expect[0] + expect[0] % 2) and expect[1] == 644


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
    frames, _ = _read_video(out)
    k = 3  # the 2 x 96 rows of the grid enlarged to at least MIN_HEIGHT
    assert len(frames) == 3 and frames[0].shape[1] == 2 * 128 * k
    assert frames[0].shape[0] > 2 * 96 * k + 15  # the legend below
    with OverlayRenderer(tmp_path / "res", ds) as r:
        assert [r.frame_iou(1, c) for c in range(4)] == ious[1]
        raw = [r.input_image(1, c) for c in range(4)]
    for c, cam in enumerate(cams):
        cell = frames[1][96 * k * (c // 2):96 * k * (c // 2 + 1),
                         128 * k * (c % 2):128 * k * (c % 2 + 1)][1::k, 1::k]
        inside, far = _regions(_silhouette({"body": body}, P[1], cam), far_px=8)
        assert inside.sum() > 50 and far.sum() > 2000
        diff = np.abs(cell.astype(float) - raw[c].astype(float)).mean(axis=-1)
        # lossy video of a random-texture background: about 6 grey levels of coding noise far
        # from the body, about 90 on it
        assert diff[far].mean() < 12.0 and diff[inside].mean() > 40.0, c
        assert np.any(diff[TEXT_BOX] > 50)  # frame, camera and IoU printed


def test_mask_view_colours_model_against_the_foreground(tmp_path, capsys):
    """``masks=True`` (``render --masks``): where the dataset's mask and the model agree the
    frame is blended with MASK_BOTH_BGR, where only the mask is with MASK_ONLY_BGR, where only
    the model is with MODEL_ONLY_BGR; the regions are the CPU rasteriser's silhouettes of the
    true pose (the masks) and of a pose moved 0.2 m sideways (the result)."""
    from gltrack.bench.multiview import RING, render_dataset
    from gltrack.bench.rigs import ring_cameras
    from gltrack.eval.overlay import ALPHA, MASK_BOTH_BGR, MASK_ONLY_BGR, MODEL_ONLY_BGR

    body = BodyModel.build()
    P = smooth_motion(body, 2, np.random.default_rng(4))
    pelvis = body.joints(P[:1])[0, 0]
    # two cameras large enough that the skeletons drawn over the body cover little of it
    cams = ring_cameras((pelvis[0], 0.9, pelvis[2]), n=2, width=320, height_px=240,
                        **dict(RING, radius=3.0, fov_y_deg=45.0))
    ds = render_dataset(tmp_path / "ds", body, P, cams, 15.0, np.random.default_rng(5), noise=0.0)
    Q = P.copy()
    Q[:, 0] += 0.2
    with ResultsWriter(tmp_path / "res", "hps", body.skeleton.names, body.markers.names) as w:
        for f in range(2):
            w.append(f, Q[f], body.joints(Q[f:f + 1])[0], body.marker_positions(Q[f:f + 1])[0])
        w.finish()
    with OverlayRenderer(tmp_path / "res", ds, masks=True) as r, \
            OverlayRenderer(tmp_path / "res", ds) as plain:
        for view in (r, plain):  # the skeletons' lines and halos would cover much of the body
            view._draw_skeleton = lambda *a, **k: None
        for c, cam in enumerate(cams):
            img, raw = r.camera_frame(1, c), r.input_image(1, c)
            fg = r.foreground(1, c)
            truth = _silhouette({"body": body}, P[1], cam)
            assert (fg == truth).mean() > 0.99  # the dataset's mask is the true silhouette
            model = _silhouette({"body": body}, Q[1], cam)
            k = np.ones((5, 5), np.uint8)  # off the anti-aliased outline

            def core(m):
                out = cv2.erode(m.astype(np.uint8), k).astype(bool)
                out[TEXT_BOX] = False
                return out
            regions = [(core(fg & model), MASK_BOTH_BGR), (core(fg & ~model), MASK_ONLY_BGR),
                       (core(model & ~fg), MODEL_ONLY_BGR)]
            for region, bgr in regions:
                assert region.sum() > 10, (c, bgr)
                want = (1 - ALPHA) * raw[region].astype(float) + ALPHA * np.array(bgr, float)
                assert np.abs(img[region] - want).max() <= 1.0, (c, bgr)
            # the plain view leaves the mask-only pixels alone
            base = plain.camera_frame(1, c)
            np.testing.assert_array_equal(base[regions[1][0]], raw[regions[1][0]])
    # the CLI flag
    out = tmp_path / "m.mp4"
    assert main(["-q", "render", str(tmp_path / "res"), str(ds), "--out", str(out),
                 "--masks"]) == 0
    assert len(_read_video(out)[0]) == 2


def test_the_datasets_keypoints_are_drawn_where_they_project(scene, tmp_path):
    """With ``keypoints.npz`` the triangulated keypoints are drawn (white, thin) where the
    camera projects them, and listed in the legend; without it nothing white is drawn there."""
    import shutil

    from gltrack.observe.keypoints import BODY_JOINTS, LANDMARKS, NAMES
    from gltrack.eval.overlay import KEYPOINT_BGR

    ds = tmp_path / "ds"
    shutil.copytree(scene["ds"], ds)
    body, P = scene["body"], scene["P"]
    J = body.joints(P)
    points = np.full((N, 33, 3), np.nan)
    for j in BODY_JOINTS:  # 15 cm beside the true joints: apart from both skeletons
        points[:, LANDMARKS[j]] = J[:, body.skeleton.names.index(j)] + [0.15, 0.0, 0.0]
    c = 2
    np.savez(ds / "keypoints.npz", uv=np.zeros((N, c, 33, 2)), visibility=np.ones((N, c, 33)),
             points=points, residual=np.zeros((N, c, 33)), names=np.array(NAMES))
    cam = scene["cams"][1]
    with OverlayRenderer(scene["res"], ds, cameras="cam1") as r, \
            OverlayRenderer(scene["res"], scene["ds"], cameras="cam1") as plain:
        img, ref_img = r.camera_frame(2, 1), plain.camera_frame(2, 1)
        legend, plain_legend = r.legend(400), plain.legend(400)
    white = np.all(img == KEYPOINT_BGR, axis=-1) & ~np.all(ref_img == KEYPOINT_BGR, axis=-1)
    assert white.sum() > 20  # the corner text is white in both
    uv = np.round(cam.project(points[2, [LANDMARKS[j] for j in BODY_JOINTS]],
                              distort=False)).astype(int)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    # (the tracked skeleton, drawn last, may cover a few)
    near = [white[max(v - 1, 0):v + 2, max(u - 1, 0):u + 2].any() for u, v in uv[inside]]
    assert inside.sum() >= 6 and np.mean(near) >= 0.75, near
    assert legend.shape[0] >= plain_legend.shape[0] and not np.array_equal(
        legend[:, :plain_legend.shape[1]][:plain_legend.shape[0]], plain_legend)
