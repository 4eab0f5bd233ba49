"""``gltrack ingest``: videos + calibration -> dataset (gltrack.data.ingest, gltrack.cli.ingest).

Every video here is written by the test itself with cv2.VideoWriter (tiny, a few frames); frame
``i`` of a video is filled with grey level ``LEVEL * i + BASE`` so the frame that arrived in the
dataset can be read back from its mean intensity despite the codec.
"""
from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from gltrack.camera import look_at_camera, save_calibration
from gltrack.cli import main
from gltrack.data.calibration import save_pose2sim_toml
from gltrack.data.dataset import Dataset, DatasetWriter
from gltrack.data.ingest import fit_camera, ingest, match_videos, select_frames
from gltrack.data.world import detect_up, internal_from_user

LEVEL, BASE = 15, 10


def _video(path, n, size=(64, 48), fps=10.0, start=0):
    """An mp4 of ``n`` flat frames ``size = (W, H)``; frame i has level LEVEL*(start+i)+BASE."""
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    assert w.isOpened(), "OpenCV cannot write mp4v here"
    for i in range(n):
        img = np.full((size[1], size[0], 3), LEVEL * (start + i) + BASE, np.uint8)
        w.write(img)
    w.release()
    return Path(path)


def _level(img):
    return int(round((float(img.mean()) - BASE) / LEVEL))


def _rig(sizes, names=None):
    """Cameras in a Z-up world (floor z = 0), 2.5 m around the origin, looking at the middle."""
    cams = []
    for i, (W, H) in enumerate(sizes):
        a = 2 * np.pi * i / len(sizes)
        name = names[i] if names else f"cam_{i + 1:02d}"
        cams.append(look_at_camera(name, [2.5 * np.cos(a), 2.5 * np.sin(a), 1.6],
                                   [0.0, 0.0, 0.9], W, H, 50.0, up=(0, 0, 1)))
    return cams


def _no_leftovers(out: Path):
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]


# ---------------------------------------------------------------------------------------------
# end to end through the command line
# ---------------------------------------------------------------------------------------------
def test_ingest_end_to_end(tmp_path, caplog, capsys):
    # exact landscape, exact portrait, 8 px of encoder padding, a half-size video
    cams = _rig([(64, 48), (48, 64), (200, 112), (128, 96)])
    calib = tmp_path / "Calib.toml"
    save_pose2sim_toml(calib, cams)
    videos = [_video(tmp_path / "CAM-1.mp4", 8), _video(tmp_path / "cam02.mp4", 8, (48, 64)),
              _video(tmp_path / "cam_3.mp4", 8, (192, 112)), _video(tmp_path / "Cam04.mp4", 8)]
    out = tmp_path / "ds"
    with caplog.at_level(logging.WARNING):
        rc = main(["-q", "ingest", "--calibration", str(calib), "--video",
                   *map(str, videos[::-1]), "--out", str(out), "--frames", "1:6",
                   "--scale", "0.5", "--masks", "none"])
    assert rc == 0, capsys.readouterr().err
    assert "cam_3.mp4: 192x112 but camera cam_03" in caplog.text  # padding: a warning
    ds = Dataset.open(out)
    assert ds.frames == 5 and ds.fps == 10 and ds.rig == "multiview"
    assert [c.name for c in ds.cameras] == ["cam_01", "cam_02", "cam_03", "cam_04"]
    assert [(c.width, c.height) for c in ds.cameras] == [(32, 24), (24, 32), (96, 56), (32, 24)]
    for k in range(4):
        assert [_level(ds.colour(j, k)) for j in range(5)] == [1, 2, 3, 4, 5]
    meta = json.loads((out / "meta.json").read_text())
    assert meta["world"]["up"] == "z" and meta["source"]["scale"] == 0.5
    assert meta["world"]["floor"] == 0.0  # auto: every camera 1.6 m above the origin plane
    assert meta["source"]["calibration_format"] == "pose2sim"
    assert meta["source"]["videos"]["cam_03"]["frames"] == [1, 2, 3, 4, 5]
    assert meta["source"]["videos"]["cam_01"]["path"] == str(videos[0].resolve())
    # the internal +Y-up cameras see user-frame points where the user's cameras (resized) do
    np.testing.assert_allclose(ds.user_frame(), internal_from_user("z").T)
    X = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 1.0], [0.0, 0.4, 1.7]])
    padded = dataclasses.replace(cams[2], width=192)  # K kept, the right 8 columns cut
    halved = cams[3].scaled(64, 48)
    for cam, user in zip(ds.cameras, [cams[0], cams[1], padded, halved]):
        want = user.scaled(cam.width, cam.height).project(X)
        np.testing.assert_allclose(cam.project(ds.from_user_frame(X)), want, atol=1e-9)
    # internal +Y up: the user's floor (z = 0) is the internal y = 0 plane
    np.testing.assert_allclose(ds.from_user_frame([[1.0, 2.0, 0.0]]), [[1.0, 0.0, -2.0]])
    np.testing.assert_allclose(ds.to_user_frame(ds.from_user_frame(X)), X, atol=1e-15)
    assert "wrote" in capsys.readouterr().out



def _ball_videos(folder, cams, n):
    """Videos of a ball (0.25 m) moving over a fixed textured background; the drawn discs."""
    rng = np.random.default_rng(3)
    truth, paths = [], []
    for k, cam in enumerate(cams):
        W, H = cam.width, cam.height
        bg = cv2.GaussianBlur(rng.uniform(40, 200, (H, W, 3)), (0, 0), 3).astype(np.uint8)
        w = cv2.VideoWriter(str(folder / f"cam0{k + 1}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"),
                            10.0, (W, H))
        discs = []
        for i in range(n):
            X = np.array([[0.5 * np.cos(0.5 * i), 0.5 * np.sin(0.5 * i), 0.9]])
            (u, v), = cam.project(X)
            r = 50.0 * 0.25 / cam.depth_of(X)[0] * W / 36.0  # 50 mm lens on a 36 mm sensor
            img = bg.copy()
            cv2.circle(img, (int(round(u)), int(round(v))), int(round(r)), (20, 230, 240), -1)
            disc = np.zeros((H, W), np.uint8)
            cv2.circle(disc, (int(round(u)), int(round(v))), int(round(r)), 1, -1)
            discs.append(disc.astype(bool))
            w.write(img)
        w.release()
        truth.append(discs)
        paths.append(folder / f"cam0{k + 1}.mp4")
    return paths, truth


def test_ingest_estimates_foreground_masks(tmp_path, capsys):
    cams = _rig([(120, 90)] * 4)
    save_pose2sim_toml(tmp_path / "Calib.toml", cams)
    videos, truth = _ball_videos(tmp_path, cams, 12)
    out = tmp_path / "ds"
    assert main(["-q", "ingest", "--calibration", str(tmp_path / "Calib.toml"), "--video",
                 *map(str, videos), "--out", str(out)]) == 0
    assert "foreground masks (sequence-foreground" in capsys.readouterr().out
    ds = Dataset.open(out)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["masks"]["method"] == "sequence-foreground" and meta["masks"]["passes"] == 2
    assert meta["masks"]["scene_trim"] is False
    # the floor is known (cameras 1.6 m above z = 0) and the ball floats: the support cue runs
    # and finds nothing of the ball's colour on the floor under it
    assert meta["world"]["floor"] == 0.0 and "support" in meta["masks"]["cues"]
    assert len(meta["masks"]["foreground_fraction"]) == 4
    if meta.get("keypoints"):
        # the landmark model "finds a person" in most of these ball frames (0.58-0.83 of
        # them shaped the masks before views had to be confirmed); its points mostly do not
        # triangulate, so the segmentation stays out of most frames
        k = meta["keypoints"]
        assert np.mean(k["confirmed"]) < 0.5 * np.mean(k["found"]), k
        assert max(meta["masks"]["prior_fraction"]) <= 0.5, meta["masks"]
    assert not list(out.glob("*_background.png"))  # not an empty-scene frame: not written
    ious = []
    for k in range(4):
        for j in range(ds.frames):
            m = ds.mask(j, k)
            assert m.shape == (90, 120)
            t = truth[k][j]
            ious.append((m & t).sum() / max((m | t).sum(), 1))
    assert np.mean(ious) > 0.6, np.round(ious, 2)


def test_scene_trim_flag_reaches_the_masks(tmp_path, capsys):
    """``--scene-trim`` is recorded in meta.json and said; without a person prior (no
    landmark model here) it changes no mask."""
    cams = _rig([(120, 90)] * 4)
    save_pose2sim_toml(tmp_path / "Calib.toml", cams)
    videos, _ = _ball_videos(tmp_path, cams, 6)
    args = ["-q", "ingest", "--calibration", str(tmp_path / "Calib.toml"), "--video",
            *map(str, videos), "--keypoints", "none"]
    assert main([*args, "--out", str(tmp_path / "plain")]) == 0
    assert "--scene-trim" not in capsys.readouterr().out
    assert main([*args, "--out", str(tmp_path / "trim"), "--scene-trim"]) == 0
    assert "trimmed where they show the scene (--scene-trim)" in capsys.readouterr().out
    metas = [json.loads((tmp_path / d / "meta.json").read_text())["masks"]
             for d in ("plain", "trim")]
    assert [m["scene_trim"] for m in metas] == [False, True]
    a, b = Dataset.open(tmp_path / "plain"), Dataset.open(tmp_path / "trim")
    assert all(np.array_equal(a.mask(j, k), b.mask(j, k)) for j in range(6) for k in range(4))


def test_default_scale_fps_and_order_matching(tmp_path, caplog):
    cams = _rig([(64, 48), (64, 48)], names=["left", "right"])
    calib = tmp_path / "calibration.json"
    save_calibration(calib, cams)
    videos = [_video(tmp_path / "a.mp4", 8), _video(tmp_path / "b.mp4", 8, start=3)]
    with caplog.at_level(logging.WARNING):
        r = ingest(calib, videos, tmp_path / "ds", fps=5, progress=False, masks="none",
                   floor=None)
    assert "matched by order" in caplog.text
    assert r["floor"] is None
    assert json.loads((tmp_path / "ds" / "meta.json").read_text())["world"]["floor"] is None
    assert r["scale"] == 1.0 and r["fps"] == 5.0 and r["frames"] == 4  # 64 px: never upscaled
    ds = Dataset.open(tmp_path / "ds")
    assert [_level(ds.colour(j, 0)) for j in range(4)] == [0, 2, 4, 6]
    assert [_level(ds.colour(j, 1)) for j in range(4)] == [3, 5, 7, 9]


def test_frame_counts_differ_are_cut_with_a_warning(tmp_path, caplog):
    cams = _rig([(64, 48), (64, 48)])
    calib = tmp_path / "Calib.toml"
    save_pose2sim_toml(calib, cams)
    videos = [_video(tmp_path / "cam01.mp4", 6), _video(tmp_path / "cam02.mp4", 4)]
    with caplog.at_level(logging.WARNING):
        r = ingest(calib, videos, tmp_path / "ds", progress=False, masks="none")
    assert r["frames"] == 4 and "cut to the common 4 frames" in caplog.text


def test_caliscope_timestamps_synchronise(tmp_path, caplog):
    cams = _rig([(64, 48), (64, 48)], names=["cam0", "cam1"])
    lines = []
    for i, c in enumerate(cams):
        lines += [f"[cameras.{i}]", f"cam_id = {i}", f"size = [{c.width}, {c.height}]",
                  f"matrix = {json.dumps(c.K.tolist())}", f"distortions = {[0.0] * 5}",
                  f"rotation = {json.dumps(c.R.tolist())}",
                  f"translation = {json.dumps(c.t.tolist())}", ""]
    (tmp_path / "camera_array.toml").write_text("\n".join(lines))
    _video(tmp_path / "cam_0.mp4", 8)
    _video(tmp_path / "cam_1.mp4", 8)
    # clips cut from a longer recording (frame_index starts at 26, as in caliscope's sample);
    # cam1's frames are one frame_index late against cam0's
    # (its first frame, 26, has sync_index 25, which cam0 lacks; sync_index 33 lacks cam1)
    rows = ["sync_index,cam_id,frame_index,frame_time"]
    for s in range(25, 34):
        if s > 25:
            rows.append(f"{s},0,{s},{100 + 0.1 * s:.3f}")
        if s < 33:
            rows.append(f"{s},1,{s + 1},{100.001 + 0.1 * s:.3f}")
    (tmp_path / "timestamps.csv").write_text("\n".join(rows) + "\n")
    with caplog.at_level(logging.WARNING):
        r = ingest(tmp_path / "camera_array.toml",
                   [tmp_path / "cam_1.mp4", tmp_path / "cam_0.mp4"], tmp_path / "ds",
                   progress=False, masks="none")
    assert "2 of 9 sync indices miss a camera" in caplog.text
    assert r["sync"].endswith("timestamps.csv") and r["frames"] == 7 and r["fps"] == 10
    ds = Dataset.open(tmp_path / "ds")
    assert [c.name for c in ds.cameras] == ["cam0", "cam1"]
    assert [_level(ds.colour(j, 0)) for j in range(7)] == [0, 1, 2, 3, 4, 5, 6]
    assert [_level(ds.colour(j, 1)) for j in range(7)] == [1, 2, 3, 4, 5, 6, 7]
    # --timestamps none: frame order instead
    r = ingest(tmp_path / "camera_array.toml", [tmp_path / "cam_0.mp4", tmp_path / "cam_1.mp4"],
               tmp_path / "ds2", timestamps=False, progress=False, masks="none")
    assert r["sync"] == "frame order" and r["frames"] == 8


# ---------------------------------------------------------------------------------------------
# bad input: one line naming the file, nothing left behind
# ---------------------------------------------------------------------------------------------
def _bad_case(tmp_path, case):
    cams = _rig([(64, 48)] * 3)
    calib = tmp_path / "Calib.toml"
    save_pose2sim_toml(calib, cams)
    videos = [_video(tmp_path / f"cam0{i}.mp4", 4) for i in (1, 2, 3)]
    if case == "extra video":
        videos.append(_video(tmp_path / "cam04.mp4", 4))
        return calib, videos, "cam04.mp4: matches no camera of"
    if case == "missing video":
        return calib, videos[:2], "camera cam_03 has no video"
    if case == "extra video by order":
        videos = [_video(tmp_path / f"v{i}.mp4", 4) for i in range(4)]
        return calib, videos, "v3.mp4: 4 videos for the 3 cameras"
    if case == "undecodable video":
        videos[1].write_bytes(b"this is not a video" * 100)
        return calib, videos, "cam02.mp4: "
    if case == "absent video":
        videos[2].unlink()
        return calib, videos, "cam03.mp4: no such video file"
    if case == "size mismatch":
        videos[0] = _video(tmp_path / "cam01.mp4", 4, (40, 40))
        return calib, videos, "cam01.mp4: frames are 40x40 but camera cam_01"
    if case == "rotated video":
        videos[0] = _video(tmp_path / "cam01.mp4", 4, (48, 64))
        return calib, videos, "cam01.mp4: .*rotated by 90 degrees"
    if case == "millimetres":
        save_pose2sim_toml(calib, [dataclasses.replace(c, t=c.t * 1000) for c in cams])
        return calib, videos, "Calib.toml: translation: .*millimetres"
    if case == "frames past the end":
        return calib, videos + ["--frames", "2:9"], "asks for frame 8, but .* have 4 frames"
    if case == "upsampling":
        return calib, videos + ["--fps", "30"], "fps 30 is above the videos' 10"
    raise AssertionError(case)


@pytest.mark.parametrize("case", ["extra video", "missing video", "extra video by order",
                                  "undecodable video", "absent video", "size mismatch",
                                  "rotated video", "millimetres", "frames past the end",
                                  "upsampling"])
def test_bad_input_is_one_line_naming_the_file(tmp_path, capsys, case):
    calib, videos, message = _bad_case(tmp_path, case)
    out = tmp_path / "ds"
    rc = main(["-q", "ingest", "--calibration", str(calib), "--out", str(out), "--video",
               *map(str, videos), "--masks", "none"])
    err = capsys.readouterr().err.strip()
    assert rc == 1
    assert "\n" not in err and err.startswith("gltrack ingest: error: ")
    import re

    assert re.search(message, err), err
    _no_leftovers(out)


def test_a_failure_while_writing_leaves_nothing(tmp_path, monkeypatch):
    import gltrack.data.ingest as mod

    cams = _rig([(64, 48)] * 2)
    save_pose2sim_toml(tmp_path / "Calib.toml", cams)
    videos = [_video(tmp_path / f"cam0{i}.mp4", 4) for i in (1, 2)]
    real = mod._read_frames

    def failing(path, wanted):
        for j, img in enumerate(real(path, wanted)):
            if Path(path).name == "cam02.mp4" and j == 2:
                raise ValueError(f"{path}: cannot decode frame {wanted[j]}")
            yield img

    monkeypatch.setattr(mod, "_read_frames", failing)
    with pytest.raises(ValueError, match="cam02.mp4: cannot decode frame 2"):
        ingest(tmp_path / "Calib.toml", videos, tmp_path / "ds", progress=False,
               masks="none")
    _no_leftovers(tmp_path / "ds")
    monkeypatch.setattr(mod, "_read_frames", real)  # the rerun works
    assert ingest(tmp_path / "Calib.toml", videos, tmp_path / "ds", progress=False,
               masks="none")["frames"] == 4


def test_existing_output_needs_overwrite(tmp_path, capsys):
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "x").write_text("keep")
    rc = main(["-q", "ingest", "--calibration", "c.toml", "--video", "a.mp4", "--out",
               str(tmp_path / "ds")])
    assert rc == 2 and "--overwrite" in capsys.readouterr().err
    assert (tmp_path / "ds" / "x").read_text() == "keep"


# ---------------------------------------------------------------------------------------------
# the pieces
# ---------------------------------------------------------------------------------------------
def test_match_videos_by_name_and_order(caplog):
    cams = _rig([(64, 48)] * 3)
    got = match_videos(cams, ["x/CAM-3.MP4", "x/cam01.mp4", "x/Cam_0002.avi"], "C.toml")
    assert [p.name for p in got] == ["cam01.mp4", "Cam_0002.avi", "CAM-3.MP4"]
    with caplog.at_level(logging.WARNING):
        got = match_videos(cams, ["x/c.mp4", "x/a.mp4", "x/b.mp4"], "C.toml")
    assert [p.name for p in got] == ["c.mp4", "a.mp4", "b.mp4"] and "by order" in caplog.text
    with pytest.raises(ValueError, match="x/a.mp4: given twice"):
        match_videos(cams, ["x/a.mp4", "x/a.mp4", "x/b.mp4"], "C.toml")


def test_fit_camera_sizes():
    (cam,) = _rig([(1088, 1920)])
    assert fit_camera(cam, 1088, 1920, "v", "c") is cam
    half = fit_camera(cam, 544, 960, "v", "c")  # a scaling: K scales
    np.testing.assert_allclose(half.K, cam.scaled(544, 960).K)
    pad = fit_camera(cam, 1080, 1920, "v", "c")  # padding: K kept
    assert (pad.width, pad.height) == (1080, 1920)
    np.testing.assert_array_equal(pad.K, cam.K)
    both = fit_camera(cam, 540, 960, "v", "c")  # half size of the padded video
    np.testing.assert_allclose(both.K, cam.scaled(544, 960).K)
    assert (both.width, both.height) == (540, 960)
    with pytest.raises(ValueError, match="v: frames are 1000x1920"):
        fit_camera(cam, 1000, 1920, "v", "c")


def test_select_frames():
    np.testing.assert_array_equal(select_frames(10, 60.0)[0], np.arange(10))
    rows, fps = select_frames(100, 60.0, (10, 20), 20.0)
    np.testing.assert_array_equal(rows, [10, 13, 16, 19]) and fps == 20.0
    rows, fps = select_frames(100, 30.0, None, 12.0)  # 2.5 frames apart: nearest frames
    np.testing.assert_array_equal(rows[:5], [0, 2, 5, 8, 10])
    with pytest.raises(ValueError, match="give fps"):
        select_frames(10, 0.0)


def test_up_axis_detection_and_rotations():
    zup = _rig([(64, 48)] * 3)
    assert detect_up(zup)[0] == "z"
    for up in ("x", "y", "z", "-x", "-y", "-z"):
        M = internal_from_user(up)
        assert np.allclose(M @ M.T, np.eye(3)) and np.isclose(np.linalg.det(M), 1)
        v = np.zeros(3)
        v["xyz".index(up[-1])] = -1 if up[0] == "-" else 1
        np.testing.assert_allclose(M @ v, [0, 1, 0])
    yup = _rig([(64, 48)] * 3)
    M = internal_from_user("z")
    from gltrack.data.world import to_internal

    assert detect_up(to_internal(yup, M.T))[0] == "y"  # after rotating the cameras: +Y up


def test_floor_is_the_origin_plane_only_when_every_camera_is_above_it():
    from gltrack.data.world import FLOOR_CAMERA_MIN, detect_floor, to_internal

    M = internal_from_user("z")
    rig = to_internal(_rig([(64, 48)] * 3), M.T)  # cameras 1.6 m above z = 0
    assert detect_floor(rig) == 0.0
    # the same rig with the origin on a desk 1.3 m up: cameras 0.3 m above it, the floor unknown
    low = [look_at_camera(c.name, c.center - [0, 1.3, 0], [0.0, -0.4, 0.0], c.width, c.height,
                          50.0) for c in rig]
    assert min(c.center[1] for c in low) < FLOOR_CAMERA_MIN and detect_floor(low) is None


def test_dataset_user_frame_is_validated(tmp_path):
    cams = _rig([(16, 12)])
    with DatasetWriter(tmp_path / "a", "multiview", 10, cams) as w:
        w.write_colour(0, 0, np.zeros((12, 16, 3), np.uint8))
    ds = Dataset.open(tmp_path / "a")
    np.testing.assert_array_equal(ds.user_frame(), np.eye(3))  # old datasets: internal frame
    assert ds.up_axis() == "y"
    meta = json.loads((tmp_path / "a" / "meta.json").read_text())
    meta["world"] = {"up": "z", "R_user_from_internal": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}
    (tmp_path / "a" / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"meta.json: field 'world.R_user_from_internal' must "
                                         r"be a rotation"):
        Dataset.open(tmp_path / "a")
    meta["world"] = {"up": "z", "R_user_from_internal": [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
                     "floor": "low"}
    (tmp_path / "a" / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"meta.json: field 'world.floor' must be a finite "
                                         r"number or null"):
        Dataset.open(tmp_path / "a")


# ---------------------------------------------------------------------------------------------
# the shared Pose2Sim take (a few frames, small)
# ---------------------------------------------------------------------------------------------
def test_ingest_shared_pose2sim_take(shared, tmp_path):
    folder = shared / "video" / "pose2sim_balancing_4cam"
    if not folder.is_dir():
        pytest.skip(f"{folder} absent")
    videos = [folder / f"cam0{i}.mp4" for i in (1, 2, 3, 4)]
    r = ingest(folder / "Calib.qca.txt", videos, tmp_path / "p2s", frames=(0, 3), scale=0.1,
               progress=False, masks="none")
    assert r["up"] == "z" and r["calibration_format"] == "qualisys" and r["frames"] == 3
    ds = Dataset.open(tmp_path / "p2s")
    # cam01/cam02 are 1080 wide (encoder padding of the 1088-wide calibration)
    assert [(c.width, c.height) for c in ds.cameras] == [(108, 192)] * 2 + [(109, 192)] * 2
    # the world origin (a corner of the force plate, on the floor) is seen by every camera
    origin = ds.from_user_frame([[0.0, 0.0, 0.0]])
    for cam in ds.cameras:
        (u, v), = cam.project(origin)
        assert cam.depth_of(origin)[0] > 1 and 0 < u < cam.width and 0 < v < cam.height
    assert ds.colour(2, 3).shape == (192, 109, 3)


def test_ingest_shared_caliscope_take_uses_its_timestamps(shared, tmp_path):
    folder = shared / "video" / "caliscope_4cam"
    if not folder.is_dir():
        pytest.skip(f"{folder} absent")
    videos = [folder / f"cam_{i}.mp4" for i in (3, 2, 1, 0)]  # matched by name, not order
    r = ingest(folder / "camera_array.toml", videos, tmp_path / "cal", frames=(0, 3), scale=0.1,
               progress=False, masks="none")
    assert r["sync"].endswith("timestamps.csv") and r["fps"] == 6 and r["frames"] == 3
    assert r["cameras"] == ["cam0", "cam1", "cam2", "cam3"] and r["up"] == "z"
    meta = json.loads((tmp_path / "cal" / "meta.json").read_text())
    # frame_index 26.. of clips that start at frame_index 26: video frames 0, 1, 2
    assert all(v["frames"] == [0, 1, 2] for v in meta["source"]["videos"].values())
    assert [(c.width, c.height) for c in Dataset.open(tmp_path / "cal").cameras] == [(128, 72)] * 4
