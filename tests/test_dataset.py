"""Dataset folder: writer -> reader round trips, validation errors, atomic writes, video input."""
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from gltrack.camera import Camera
from gltrack.data.dataset import Dataset, DatasetWriter, VideoFile, open_images

W, H = 16, 12


def _shared():
    env = os.environ.get("GLTRACK_SHARED")
    p = Path(env) if env else Path(__file__).resolve().parents[1].parent / "shared"
    return p if p.is_dir() else None


def cam(name, kind, w=W, h=H, tx=0.0):
    K = [[20.0, 0, (w - 1) / 2], [0, 20.0, (h - 1) / 2], [0, 0, 1]]
    return Camera(name, kind, w, h, K, np.zeros(5), np.eye(3), np.array([tx, 0.0, 3.0]))


def gt_arrays(n, rng):
    names = ["pelvis", "neck", "head", "l_wrist"]
    joints = rng.normal(size=(n, len(names), 3))
    markers = rng.normal(size=(n, 5, 3))
    params = rng.normal(size=(n, 7))
    return joints, names, markers, params


def make_depth(path, rng, n=3, **kw):
    c = cam("cam0", "depth")
    depths = rng.uniform(0.5, 5.0, size=(n, H, W))
    with DatasetWriter(path, "depth", 30, [c], body={"height": 1.8}, **kw) as w:
        for f in range(n):
            w.write_depth(f, 0, depths[f])
            w.write_mask(f, "cam0", depths[f] < 2.0)
            w.write_gtmask(f, "cam0", depths[f] < 3.0)
        w.write_background(0, np.full((H, W), 4.0))
        w.write_environment({"cam0": [[[2, 2], [6, 2], [6, 5], [2, 5]]]})
        j, names, m, p = gt_arrays(n, rng)
        w.write_groundtruth(j, names, m, p, marker_names=[f"m{i}" for i in range(5)])
    return depths, (j, names, m, p)


def make_multiview(path, rng, n=3, **kw):
    cams = [cam("cam0", "colour"), cam("cam1", "colour", tx=1.0)]
    imgs = rng.integers(0, 256, size=(n, 2, H, W, 3), dtype=np.uint8)
    with DatasetWriter(path, "multiview", 25, cams, **kw) as w:
        for f in range(n):
            for k in range(2):
                w.write_colour(f, k, imgs[f, k])
                w.write_mask(f, k, imgs[f, k, :, :, 0] > 128)
        for i in range(min(3, n)):
            w.write_background("cam1", imgs[i, 1], index=i)
    return imgs


# ---- round trips -------------------------------------------------------------------------------
def test_depth_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    depths, (j, names, m, p) = make_depth(tmp_path / "ds", rng)
    ds = Dataset.open(tmp_path / "ds")
    assert (ds.frames, ds.fps, ds.rig, ds.body) == (3, 30.0, "depth", {"height": 1.8})
    assert [c.name for c in ds.cameras] == ["cam0"]
    for f in range(3):
        z = ds.depth(f)
        assert z.dtype == np.float32 and z.shape == (H, W)
        np.testing.assert_allclose(z, depths[f], atol=0.0005 + 1e-6)  # 1 mm quantisation
        np.testing.assert_array_equal(ds.mask(f), depths[f] < 2.0)
        np.testing.assert_array_equal(ds.gtmask(f, "cam0"), depths[f] < 3.0)
    assert not np.array_equal(ds.depth(0), ds.depth(1))
    np.testing.assert_allclose(ds.background(0), 4.0)
    block = ds.blocking_mask("cam0")
    expect = np.zeros((H, W), bool)
    expect[2:6, 2:7] = True  # fillPoly includes the polygon's edge pixels
    np.testing.assert_array_equal(block, expect)
    gt = ds.groundtruth()
    np.testing.assert_array_equal(gt["joints"], j)
    np.testing.assert_array_equal(gt["markers"], m)
    np.testing.assert_array_equal(gt["params"], p)
    assert gt["joint_names"] == names and gt["marker_names"] == [f"m{i}" for i in range(5)]
    with pytest.raises(IndexError):
        ds.depth(3)
    with pytest.raises(ValueError, match="not colour"):
        ds.colour(0)


def test_depth_encoding_invalid_values(tmp_path):
    c = cam("cam0", "depth")
    z = np.full((H, W), 1.2345)
    z[0, 0], z[0, 1], z[0, 2], z[0, 3], z[0, 4] = np.nan, 70.0, -1.0, 65.535, np.inf
    with DatasetWriter(tmp_path / "d", "depth", 30, [c]) as w:
        w.write_depth(0, 0, z)
    raw = cv2.imread(str(tmp_path / "d" / "cam0" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    assert raw[0, :5].tolist() == [0, 0, 0, 65535, 0]
    assert raw[5, 5] == 1234 or raw[5, 5] == 1235
    ds = Dataset.open(tmp_path / "d")
    assert ds.depth(0)[0, 3] == pytest.approx(65.535)
    assert ds.depth(0)[0, 1] == 0.0


def test_multiview_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    imgs = make_multiview(tmp_path / "mv", rng)
    ds = Dataset.open(tmp_path / "mv")
    assert (ds.rig, ds.fps, ds.frames) == ("multiview", 25.0, 3)
    for f in range(3):
        for k, name in enumerate(["cam0", "cam1"]):
            np.testing.assert_array_equal(ds.colour(f, name), imgs[f, k])
            np.testing.assert_array_equal(ds.mask(f, k), imgs[f, k, :, :, 0] > 128)
    assert ds.gtmask(0, 0) is None
    assert ds.background(0) is None
    assert len(ds.backgrounds(1)) == 3
    np.testing.assert_array_equal(ds.background(1),
                                  np.median(imgs[:3, 1], axis=0).round().astype(np.uint8))
    assert ds.environment() is None and not ds.blocking_mask(1).any()
    assert ds.groundtruth() is None
    with pytest.raises(ValueError, match="not depth"):
        ds.depth(0, 1)


def test_prefetched_frames_are_the_frames(tmp_path):
    """Images read ahead in the background are the images; a broken file read ahead is still
    an error naming it when the frame is taken; out of range is ignored."""
    rng = np.random.default_rng(4)
    imgs = make_multiview(tmp_path / "mv", rng, n=4)
    ds = Dataset.open(tmp_path / "mv")
    ds.prefetch(99)  # out of range: nothing to do
    for f in range(4):
        ds.prefetch(f, masks=True)
        stream = ds._stream(ds.cameras[0])
        assert f in stream._ahead
        for k in range(2):
            np.testing.assert_array_equal(ds.colour(f, k), imgs[f, k])
            np.testing.assert_array_equal(ds.mask(f, k), imgs[f, k, :, :, 0] > 128)
        assert f not in stream._ahead  # taken, not held
    bad = tmp_path / "mv" / "cam1" / "000002.png"
    bad.write_bytes(b"not a png")
    ds.prefetch(2)
    with pytest.raises(ValueError, match="000002.png: not a readable image"):
        ds.colour(2, 1)
    np.testing.assert_array_equal(ds.colour(2, 0), imgs[2, 0])


def test_video_camera_sequential_and_backwards(tmp_path):
    rng = np.random.default_rng(2)
    make_multiview(tmp_path / "mv", rng, n=6)
    # Replace cam0/ with a video of distinct flat-colour frames (robust to lossy coding).
    w, h = 32, 24
    cams = [cam("cam0", "colour", w, h)]
    ds_path = tmp_path / "vid"
    ds_path.mkdir()
    from gltrack.camera import save_calibration
    save_calibration(ds_path / "calibration.json", cams)
    (ds_path / "meta.json").write_text(json.dumps(
        {"format": "gltrack-dataset", "version": 1, "fps": 10, "frames": 6, "rig": "multiview"}))
    vw = cv2.VideoWriter(str(ds_path / "cam0.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (w, h))
    assert vw.isOpened()
    levels = [20, 60, 100, 140, 180, 220]
    for v in levels:
        vw.write(np.full((h, w, 3), v, np.uint8))
    vw.release()
    ds = Dataset.open(ds_path)
    got = [float(ds.colour(f).mean()) for f in range(6)]
    np.testing.assert_allclose(got, levels, atol=3)
    assert abs(float(ds.colour(1).mean()) - 60) < 3  # backwards: reopen and decode forward
    assert abs(float(ds.colour(4).mean()) - 180) < 3  # forward skip
    ds.close()
    # A meta.json claiming more frames than the video holds is rejected.
    (ds_path / "meta.json").write_text(json.dumps(
        {"format": "gltrack-dataset", "version": 1, "fps": 10, "frames": 7, "rig": "multiview"}))
    with pytest.raises(ValueError, match="cam0.avi: 6 frames"):
        Dataset.open(ds_path)


def test_open_images_natural_order(tmp_path):
    for i in (10, 2, 1):
        cv2.imwrite(str(tmp_path / f"img{i}.png"), np.full((4, 5), i, np.uint8))
    (tmp_path / "notes.txt").write_text("x")
    imgs = open_images(tmp_path)
    assert len(imgs) == 3
    assert [int(imgs[i][0, 0]) for i in range(3)] == [1, 2, 10]


def test_real_video_smoke():
    shared = _shared()
    if shared is None:
        pytest.skip("reference data not found: set GLTRACK_SHARED or put shared/ next to the repo")
    vids = sorted((shared / "video" / "caliscope_4cam").rglob("*.mp4"))
    if not vids:
        pytest.skip("no caliscope mp4 in the shared folder")
    v = VideoFile(vids[0])
    assert len(v) >= 100
    a, b = v[3], v[4]
    assert a.shape == (720, 1280, 3) and a.dtype == np.uint8
    assert not np.array_equal(a, b)
    np.testing.assert_array_equal(v[3], a)  # backwards read is exact
    v.close()


# ---- validation --------------------------------------------------------------------------------
def _meta(path):
    return json.loads((path / "meta.json").read_text())


def _set_meta(path, **changes):
    meta = _meta(path)
    meta.update(changes)
    (path / "meta.json").write_text(json.dumps(meta))


BREAKS = {
    "no_meta": (lambda p: (p / "meta.json").unlink(), r"meta.json: missing"),
    "no_calibration": (lambda p: (p / "calibration.json").unlink(), r"calibration.json: missing"),
    "bad_json": (lambda p: (p / "meta.json").write_text("{"), r"meta.json: not valid JSON"),
    "format": (lambda p: _set_meta(p, format="other"), r"meta.json: field 'format'"),
    "version": (lambda p: _set_meta(p, version=2), r"meta.json: field 'version' 2"),
    "rig": (lambda p: _set_meta(p, rig="stereo"), r"meta.json: field 'rig'"),
    "fps": (lambda p: _set_meta(p, fps=0), r"meta.json: field 'fps'"),
    "frames_meta": (lambda p: _set_meta(p, frames=4), r"cam0: 3 frames.*'frames' is 4"),
    "frames_missing": (lambda p: (p / "cam0" / "000002.png").unlink(), r"cam0: 2 frames"),
    "mask_count": (lambda p: (p / "cam0_mask" / "000001.png").unlink(), r"cam0_mask: 2 masks"),
    "size": (lambda p: cv2.imwrite(str(p / "cam0" / "000000.png"), np.zeros((H, W + 1), np.uint16)),
             r"000000.png: image is 17x12 .* 16x12"),
    "depth_8bit": (lambda p: cv2.imwrite(str(p / "cam0" / "000000.png"), np.zeros((H, W), np.uint8)),
                   r"000000.png: depth image must be 16-bit"),
    "mask_16bit": (lambda p: cv2.imwrite(str(p / "cam0_mask" / "000000.png"),
                                         np.zeros((H, W), np.uint16)),
                   r"cam0_mask/000000.png: mask must be uint8 single-channel"),
    "gtmask_rgb": (lambda p: cv2.imwrite(str(p / "cam0_gtmask" / "000000.png"),
                                         np.zeros((H, W, 3), np.uint8)),
                   r"cam0_gtmask/000000.png: gtmask must be uint8 single-channel"),
    "background_size": (lambda p: cv2.imwrite(str(p / "cam0_background.png"),
                                              np.zeros((H + 1, W), np.uint16)),
                        r"cam0_background.png: image is"),
    "env_camera": (lambda p: (p / "environment.json").write_text(
        json.dumps({"cameras": {"cam9": []}})), r"environment.json: field 'cameras.cam9'"),
    "env_polygon": (lambda p: (p / "environment.json").write_text(
        json.dumps({"cameras": {"cam0": [[[0, 0], [1, 1]]]}})), r"environment.json: cameras.cam0\[0\]"),
    "gt_shape": (lambda p: np.savez(p / "groundtruth.npz", joints=np.zeros((3, 4, 2)),
                                    joint_names=np.array(list("abcd"))),
                 r"groundtruth.npz: field 'joints'"),
    "gt_frames": (lambda p: np.savez(p / "groundtruth.npz", joints=np.zeros((5, 4, 3)),
                                     joint_names=np.array(list("abcd"))),
                  r"groundtruth.npz: field 'joints' has 5 frames"),
    "gt_names": (lambda p: np.savez(p / "groundtruth.npz", joints=np.zeros((3, 4, 3)),
                                    joint_names=np.array(list("abc"))),
                 r"groundtruth.npz: field 'joint_names'"),
    "gt_pickle": (lambda p: np.savez(p / "groundtruth.npz", joints=np.zeros((3, 4, 3)),
                                     joint_names=np.array([{"a": 1}] * 4, dtype=object)),
                  r"groundtruth.npz: unreadable"),
    "rig_without_depth_camera": (
        lambda p: (p / "calibration.json").write_text(
            (p / "calibration.json").read_text().replace('"depth"', '"colour"')),
        r"calibration.json: rig 'depth'"),
    "camera_name_path": (
        lambda p: (p / "calibration.json").write_text(
            (p / "calibration.json").read_text().replace('"cam0"', '"../cam0"')),
        r"calibration.json: cameras\[0\].name '../cam0'"),
    "gt_markers": (lambda p: np.savez(p / "groundtruth.npz", joints=np.zeros((3, 4, 3)),
                                      joint_names=np.array(list("abcd")),
                                      markers=np.zeros((2, 4, 3))),
                   r"groundtruth.npz: field 'markers' has 2 frames"),
}


@pytest.mark.parametrize("case", sorted(BREAKS))
def test_validation_errors_name_file_and_field(tmp_path, case):
    rng = np.random.default_rng(3)
    make_depth(tmp_path / "ds", rng)
    Dataset.open(tmp_path / "ds")  # valid before the break
    breaker, pattern = BREAKS[case]
    breaker(tmp_path / "ds")
    with pytest.raises(ValueError, match=pattern):
        Dataset.open(tmp_path / "ds")


def test_colour_format_errors(tmp_path):
    rng = np.random.default_rng(4)
    make_multiview(tmp_path / "mv", rng)
    p = tmp_path / "mv" / "cam1" / "000000.png"
    cv2.imwrite(str(p), np.zeros((H, W), np.uint8))
    with pytest.raises(ValueError, match=r"cam1/000000.png: colour image must be 8-bit 3-channel"):
        Dataset.open(tmp_path / "mv")
    cv2.imwrite(str(p), np.zeros((H, W, 3), np.uint16))
    with pytest.raises(ValueError, match=r"cam1/000000.png: colour image must be 8-bit 3-channel"):
        Dataset.open(tmp_path / "mv")
    # A bad file later in the sequence is reported when it is read.
    cv2.imwrite(str(p), np.zeros((H, W, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "mv" / "cam0" / "000002.png"), np.zeros((H, W, 4), np.uint8))
    ds = Dataset.open(tmp_path / "mv")
    ds.colour(1, 0)
    with pytest.raises(ValueError, match=r"cam0/000002.png: colour image"):
        ds.colour(2, 0)


def test_missing_camera_stream(tmp_path):
    rng = np.random.default_rng(5)
    make_multiview(tmp_path / "mv", rng)
    import shutil
    shutil.rmtree(tmp_path / "mv" / "cam1")
    with pytest.raises(ValueError, match=r"no frames for camera cam1"):
        Dataset.open(tmp_path / "mv")


# ---- atomic writing ----------------------------------------------------------------------------
def _siblings(tmp_path):
    return sorted(p.name for p in tmp_path.iterdir())


def test_exception_leaves_no_target(tmp_path):
    c = cam("cam0", "depth")
    with pytest.raises(RuntimeError, match="boom"):
        with DatasetWriter(tmp_path / "ds", "depth", 30, [c]) as w:
            w.write_depth(0, 0, np.ones((H, W)))
            assert any(n.startswith(".ds.partial-") for n in _siblings(tmp_path))
            raise RuntimeError("boom")
    assert _siblings(tmp_path) == []


def test_inconsistent_frames_rejected_at_close(tmp_path):
    cams = [cam("cam0", "colour"), cam("cam1", "colour")]
    img = np.zeros((H, W, 3), np.uint8)
    with pytest.raises(ValueError, match="camera cam1 has 1 frames"):
        with DatasetWriter(tmp_path / "ds", "multiview", 30, cams) as w:
            w.write_colour(0, 0, img)
            w.write_colour(1, 0, img)
            w.write_colour(0, 1, img)
    assert _siblings(tmp_path) == []


def test_existing_target_refused_or_overwritten(tmp_path):
    rng = np.random.default_rng(6)
    make_depth(tmp_path / "ds", rng, n=2)
    with pytest.raises(FileExistsError):
        DatasetWriter(tmp_path / "ds", "depth", 30, [cam("cam0", "depth")])
    imgs = make_multiview(tmp_path / "ds", rng, n=4, overwrite=True)
    ds = Dataset.open(tmp_path / "ds")
    assert (ds.rig, ds.frames) == ("multiview", 4)
    np.testing.assert_array_equal(ds.colour(3, 1), imgs[3, 1])
    assert not (tmp_path / "ds" / "groundtruth.npz").exists()  # nothing of the old dataset left
    assert _siblings(tmp_path) == ["ds"]
    # An empty existing folder is fine without overwrite.
    (tmp_path / "empty").mkdir()
    make_multiview(tmp_path / "empty", rng, n=1)
    assert Dataset.open(tmp_path / "empty").frames == 1


def test_writer_rejects_bad_input(tmp_path):
    c = cam("cam0", "depth")
    with pytest.raises(ValueError, match="rig"):
        DatasetWriter(tmp_path / "a", "stereo", 30, [c])
    w = DatasetWriter(tmp_path / "a", "depth", 30, [c])
    with pytest.raises(ValueError, match=r"must be \(12, 16\)"):
        w.write_depth(0, 0, np.ones((H + 1, W)))
    with pytest.raises(ValueError, match="not colour"):
        w.write_colour(0, 0, np.zeros((H, W, 3), np.uint8))
    with pytest.raises(ValueError, match="field 'markers'"):
        w.write_groundtruth(np.zeros((2, 3, 3)), ["a", "b", "c"], markers=np.zeros((3, 2, 3)))
    w.abort()
    assert _siblings(tmp_path) == []
