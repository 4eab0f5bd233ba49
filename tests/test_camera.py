"""Tests for gltrack.camera: projection, OpenCV <-> GL convention, resizing, undistortion, files."""
from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from gltrack.camera import (
    Camera,
    depth_camera_sr4000,
    linearize_gl_depth,
    load_calibration,
    load_caliscope_toml,
    load_cameras,
    load_opencv_yaml,
    look_at_camera,
    save_calibration,
    save_opencv_yaml,
)

REPO = Path(__file__).resolve().parents[1]


def _shared() -> Path | None:
    env = os.environ.get("GLTRACK_SHARED")
    for cand in ([Path(env)] if env else []) + [REPO.parent / "shared"]:
        if cand.is_dir():
            return cand
    return None


def _caliscope_file() -> Path:
    shared = _shared()
    path = shared / "video" / "caliscope_4cam" / "camera_array.toml" if shared else None
    if path is None or not path.is_file():
        pytest.skip("shared reference data (video/caliscope_4cam) not found: set GLTRACK_SHARED "
                    "or place it at ../shared")
    return path


def _random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _random_camera(rng, name="cam0", distort=True) -> Camera:
    W, H = int(rng.integers(160, 1300)), int(rng.integers(120, 1000))
    f = rng.uniform(0.6, 1.5) * W
    K = np.array([[f, 0, W / 2 + rng.uniform(-20, 20)],
                  [0, f * rng.uniform(0.95, 1.05), H / 2 + rng.uniform(-20, 20)],
                  [0, 0, 1]])
    dist = (rng.uniform(-0.1, 0.1, 5) * [2, 1, 0.05, 0.05, 0.5]) if distort else np.zeros(5)
    R = _random_rotation(rng)
    t = rng.uniform(-2, 2, 3)
    return Camera(name, "colour", W, H, K, dist, R, t)


def _points_in_front(cam, rng, n=200, spread=0.35):
    """World points at 1-5 m depth within roughly +-spread (normalised) of the optical axis."""
    xy = rng.uniform(-spread, spread, (n, 2))
    z = rng.uniform(1, 5, n)
    Xc = np.column_stack([xy * z[:, None], z])
    return (Xc - cam.t) @ cam.R  # R^T (Xc - t), row-wise


def _same(a: Camera, b: Camera) -> bool:
    return (a.name == b.name and a.kind == b.kind and (a.width, a.height) == (b.width, b.height)
            and all(np.array_equal(getattr(a, f), getattr(b, f)) for f in "K dist R t".split()))


def _blob_image(W, H, centres, sigma):
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    img = np.zeros((H, W))
    for u, v in centres:
        img += np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * sigma ** 2))
    return img.astype(np.float32)


def _centroid(img, u, v, r):
    """Intensity centroid of img in the window of radius r around (u, v)."""
    u0, v0 = int(round(u)), int(round(v))
    win = img[v0 - r:v0 + r + 1, u0 - r:u0 + r + 1].astype(np.float64)
    yy, xx = np.mgrid[v0 - r:v0 + r + 1, u0 - r:u0 + r + 1]
    return np.array([(win * xx).sum(), (win * yy).sum()]) / win.sum()


# ---------------------------------------------------------------------------------------------
# projection
# ---------------------------------------------------------------------------------------------
def test_project_matches_cv2_projectpoints():
    rng = np.random.default_rng(0)
    for _ in range(20):
        cam = _random_camera(rng)
        X = _points_in_front(cam, rng)
        rvec = cv2.Rodrigues(cam.R)[0]
        ref, _ = cv2.projectPoints(X, rvec, cam.t, cam.K, cam.dist)
        np.testing.assert_allclose(cam.project(X), ref.reshape(-1, 2), rtol=0, atol=1e-6)
        ref0, _ = cv2.projectPoints(X, rvec, cam.t, cam.K, np.zeros(5))
        np.testing.assert_allclose(cam.project(X, distort=False), ref0.reshape(-1, 2),
                                   rtol=0, atol=1e-6)
        # the distortion must actually do something, or the first comparison proves little
        assert np.abs(cam.project(X) - cam.project(X, distort=False)).max() > 0.5


def test_project_by_hand_and_shapes():
    K = np.array([[500.0, 0, 320], [0, 400.0, 240], [0, 0, 1]])
    cam = Camera("c", "colour", 640, 480, K, np.zeros(5), np.eye(3), np.array([0.0, 0.0, 1.0]))
    X = np.array([[0.2, -0.1, 1.0], [0.0, 0.0, 3.0]])  # camera z = 2 and 4
    np.testing.assert_allclose(cam.project(X), [[320 + 500 * 0.1, 240 - 400 * 0.05], [320, 240]])
    np.testing.assert_allclose(cam.depth_of(X), [2.0, 4.0])
    np.testing.assert_allclose(cam.center, [0, 0, -1])
    assert cam.project(np.zeros((2, 5, 3)) + [0, 0, 1]).shape == (2, 5, 2)

    # k1 alone scales the normalised radius by (1 + k1 r^2)
    distorted = dataclasses.replace(cam, dist=np.array([0.1, 0, 0, 0, 0]))
    x, y = 0.1, -0.05
    s = 1 + 0.1 * (x * x + y * y)
    np.testing.assert_allclose(distorted.project(X[:1]), [[320 + 500 * x * s, 240 + 400 * y * s]])


def test_geometry_is_consistent():
    rng = np.random.default_rng(1)
    cam = _random_camera(rng)
    np.testing.assert_allclose(cam.to_camera(cam.center[None]), 0, atol=1e-12)
    X = _points_in_front(cam, rng, 50)
    np.testing.assert_allclose(cam.depth_of(X), cam.to_camera(X)[:, 2], atol=1e-12)
    assert np.all(cam.depth_of(X) > 0.9)


def test_backproject_inverts_project():
    rng = np.random.default_rng(5)
    for distort in (False, True):
        cam = _random_camera(rng, distort=distort)
        X = _points_in_front(cam, rng)
        uv, z = cam.project(X), cam.depth_of(X)
        np.testing.assert_allclose(cam.backproject(uv, z), X, rtol=0, atol=1e-6)
        np.testing.assert_allclose(cam.backproject(uv, z, frame="camera"), cam.to_camera(X),
                                   rtol=0, atol=1e-6)
        np.testing.assert_allclose(cam.backproject(cam.project(X, distort=False), z,
                                                   distort=False), X, rtol=0, atol=1e-9)
        np.testing.assert_allclose(cam.to_world(cam.to_camera(X)), X, rtol=0, atol=1e-12)
        # the output follows the input: twice the depth is twice as far along the same ray,
        # another pixel is another point
        np.testing.assert_allclose(cam.backproject(uv, 2 * z), cam.center + 2 * (X - cam.center),
                                   rtol=0, atol=1e-6)
        moved = cam.backproject(uv + [5.0, 0.0], z)
        assert np.all(np.linalg.norm(moved - X, axis=1) > 1e-3)
    assert cam.backproject(np.zeros((2, 4, 2)), np.ones((2, 4))).shape == (2, 4, 3)
    with pytest.raises(ValueError, match="frame"):
        cam.backproject(uv, z, frame="image")


def test_arrays_are_copied_and_read_only():
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    cam = Camera("c", "depth", 640, 480, K, np.zeros(5), np.eye(3), np.zeros(3))
    K[0, 0] = 1.0
    assert cam.K[0, 0] == 500.0
    with pytest.raises(ValueError):
        cam.K[0, 0] = 2.0


# ---------------------------------------------------------------------------------------------
# synthetic rigs
# ---------------------------------------------------------------------------------------------
def test_look_at_camera_orientation():
    cam = look_at_camera("front", eye=[0, 1, 4], target=[0, 1, 0], width=640, height=480,
                         fov_y_deg=60)
    np.testing.assert_allclose(cam.center, [0, 1, 4], atol=1e-12)
    np.testing.assert_allclose(cam.project([[0, 1, 0]]), [[319.5, 239.5]], atol=1e-9)
    np.testing.assert_allclose(cam.depth_of([[0, 1, 0]]), [4.0])
    up, left = cam.project([[0, 2, 0], [1, 1, 0]])
    assert up[1] < 239.5 - 50  # world +Y is image up (smaller row)
    assert left[0] > 319.5 + 50  # camera faces the subject: subject's left (+X) is image right
    # a point on the upper field-of-view edge lands on the top image edge (v = -0.5)
    top = np.array([0, 1 + 4 * np.tan(np.radians(30)), 0])
    np.testing.assert_allclose(cam.project(top[None])[0, 1], -0.5, atol=1e-9)
    with pytest.raises(ValueError, match="parallel"):
        look_at_camera("down", [0, 3, 0], [0, 0, 0], 64, 48, 60)


def test_sr4000_field_of_view():
    cam = depth_camera_sr4000(eye=[0, 1, 3], target=[0, 1, 0])
    assert (cam.width, cam.height, cam.kind) == (176, 144, "depth")
    # rays along the horizontal / vertical half-FOV hit the image edges
    for axis, half_deg, edge in ((0, 21.8, 175.5), (1, 17.3, -0.5)):
        d = np.zeros(3)
        d[axis] = np.tan(np.radians(half_deg)) * (1 if axis == 0 else -1)
        d[2] = 1
        Xw = cam.center + cam.R.T @ d
        assert cam.project(Xw[None])[0, axis] == pytest.approx(edge, abs=1e-9)


# ---------------------------------------------------------------------------------------------
# OpenCV -> GL
# ---------------------------------------------------------------------------------------------
def _gl_window(cam, X, near, far):
    clip = np.column_stack([X, np.ones(len(X))]) @ (cam.gl_projection(near, far) @ cam.gl_view()).T
    ndc = clip[:, :3] / clip[:, 3:]
    win = (ndc[:, :2] + 1) / 2 * [cam.width, cam.height]
    return win, ndc[:, 2], clip[:, 3]


def test_gl_matrices_match_project():
    rng = np.random.default_rng(2)
    for _ in range(10):
        cam = _random_camera(rng)
        X = _points_in_front(cam, rng)
        win, ndc_z, w = _gl_window(cam, X, 0.5, 10.0)
        np.testing.assert_allclose(win, cam.project(X, distort=False) + 0.5, rtol=0, atol=1e-9)
        np.testing.assert_allclose(w, cam.depth_of(X), atol=1e-12)
        order = np.argsort(cam.depth_of(X))
        assert np.all(np.diff(ndc_z[order]) > 0)  # NDC z increases with depth
        np.testing.assert_allclose(linearize_gl_depth((ndc_z + 1) / 2, 0.5, 10.0),
                                   cam.depth_of(X), rtol=1e-12)
    # near plane -> -1, far plane -> +1
    cam = look_at_camera("c", [0, 0, 0], [0, 0, 1], 64, 48, 50)
    _, z, _ = _gl_window(cam, np.array([[0, 0, 0.5], [0, 0, 10.0]]), 0.5, 10.0)
    np.testing.assert_allclose(z, [-1, 1], atol=1e-12)
    with pytest.raises(ValueError, match="near"):
        cam.gl_projection(0.0, 1.0)


def test_gl_render_rows_and_depth(ctx):
    """Points drawn with P @ view land on framebuffer pixel (u, v), read back row 0 first."""
    K = np.array([[90.0, 0, 37.0], [0, 80.0, 21.0], [0, 0, 1]])  # off-centre principal point
    cam = Camera("c", "depth", 80, 50, K, np.zeros(5), _random_rotation(np.random.default_rng(3)),
                 np.array([0.1, -0.2, 0.3]))
    pix = np.array([[0, 0], [79, 0], [0, 49], [5, 40], [60, 7], [37, 21]], dtype=np.float64)
    z = np.array([1.0, 2.0, 3.0, 1.5, 4.0, 2.5])
    Xc = np.column_stack([(pix - K[:2, 2]) / K[[0, 1], [0, 1]] * z[:, None], z])
    Xw = (Xc - cam.t) @ cam.R
    np.testing.assert_allclose(cam.project(Xw), pix, atol=1e-9)

    near, far = 0.5, 8.0
    mvp = (cam.gl_projection(near, far) @ cam.gl_view()).astype("f4")
    prog = ctx.program(
        vertex_shader="#version 330\nuniform mat4 mvp; in vec3 pos; flat out int id;\n"
                      "void main(){ gl_Position = mvp * vec4(pos, 1.0); id = gl_VertexID; }",
        fragment_shader="#version 330\nflat in int id; out vec4 col;\n"
                        "void main(){ col = vec4(float(id + 1) / 255.0, 0.0, 0.0, 1.0); }")
    prog["mvp"].write(mvp.T.tobytes())  # GLSL mat4 is column-major
    vbo = ctx.buffer(Xw.astype("f4").tobytes())
    vao = ctx.vertex_array(prog, [(vbo, "3f", "pos")])
    fbo = ctx.framebuffer(color_attachments=[ctx.texture((cam.width, cam.height), 4)],
                          depth_attachment=ctx.depth_texture((cam.width, cam.height)))
    try:
        fbo.use()
        ctx.viewport = (0, 0, cam.width, cam.height)
        ctx.enable(ctx.DEPTH_TEST)
        fbo.clear(0, 0, 0, 0, depth=1.0)
        vao.render(mode=ctx.POINTS)
        img = np.frombuffer(fbo.read(components=4), np.uint8).reshape(cam.height, cam.width, 4)
        depth = np.frombuffer(fbo.read(components=1, attachment=-1, dtype="f4"), np.float32)
        depth = depth.reshape(cam.height, cam.width)
    finally:
        from gltrack.gl.context import park_framebuffer

        park_framebuffer(ctx)
        for obj in (fbo, vao, vbo, prog):
            obj.release()
        ctx.disable(ctx.DEPTH_TEST)
    vs, us = np.nonzero(img[..., 0])
    found = {int(img[v, u, 0]) - 1: (u, v) for u, v in zip(us, vs)}
    assert found == {i: (int(u), int(v)) for i, (u, v) in enumerate(pix)}
    lin = linearize_gl_depth(depth[pix[:, 1].astype(int), pix[:, 0].astype(int)], near, far)
    np.testing.assert_allclose(lin, z, rtol=1e-4)
    assert ctx.error == "GL_NO_ERROR"


# ---------------------------------------------------------------------------------------------
# derived cameras
# ---------------------------------------------------------------------------------------------
def test_scaled_keeps_pixel_centres():
    rng = np.random.default_rng(4)
    cam = _random_camera(rng)
    # a point whose ray goes through the centre of pixel (0, 0) at full resolution
    ray = np.linalg.solve(cam.K, [0.0, 0.0, 1.0]) * 2.5
    X = (cam.R.T @ (ray - cam.t))[None]
    np.testing.assert_allclose(cam.project(X, distort=False), [[0, 0]], atol=1e-9)
    for W2, H2 in ((cam.width // 2, cam.height // 2), (cam.width * 3, cam.height * 2)):
        small = cam.scaled(W2, H2)
        sx, sy = W2 / cam.width, H2 / cam.height
        np.testing.assert_allclose(small.project(X, distort=False),
                                   [[0.5 * sx - 0.5, 0.5 * sy - 0.5]], atol=1e-9)
        # image edges map onto image edges
        corner = np.linalg.solve(cam.K, [cam.width - 0.5, cam.height - 0.5, 1.0])
        Xc = (cam.R.T @ (corner - cam.t))[None]
        np.testing.assert_allclose(small.project(Xc, distort=False), [[W2 - 0.5, H2 - 0.5]],
                                   atol=1e-9)
    assert np.array_equal(cam.scaled(cam.width, cam.height).K, cam.K)


def test_scaled_matches_cv2_resize():
    """Independent check: a blob drawn at project() and shrunk by cv2.resize lands at scaled()."""
    cam = look_at_camera("c", [0.2, 1.1, 3], [0, 1, 0], 320, 240, 55)
    X = np.array([[-0.7, 0.6, 0.1], [0.0, 1.0, 0.0], [0.9, 1.5, -0.3]])
    sigma = 4.0
    for x in X:
        img = _blob_image(cam.width, cam.height, cam.project(x[None]), sigma)
        for W2, H2 in ((160, 120), (128, 96), (200, 150)):
            small = cv2.resize(img, (W2, H2), interpolation=cv2.INTER_AREA)
            s = W2 / cam.width
            (u, v), = cam.scaled(W2, H2).project(x[None])
            got = _centroid(small, u, v, int(np.ceil(5 * sigma * s)))
            np.testing.assert_allclose(got, [u, v], atol=0.02)
            # forgetting the half-pixel shift would be off by |0.5 (1 - s)| >= 0.1 px
            (nu, nv), = cam.project(x[None]) * s
            assert np.hypot(got[0] - nu, got[1] - nv) > 0.1


def test_undistort_points_and_image():
    cam = Camera("c", "colour", 320, 240,
                 np.array([[260.0, 0, 161.3], [0, 255.0, 118.7], [0, 0, 1]]),
                 np.array([-0.30, 0.08, 0.002, -0.001, 0.0]), np.eye(3), np.zeros(3))
    rng = np.random.default_rng(6)
    X = _points_in_front(cam, rng, 300, spread=0.45)
    pin = cam.undistorted()
    assert not np.any(pin.dist) and np.array_equal(pin.K, cam.K)
    np.testing.assert_allclose(cam.undistort_points(cam.project(X)), pin.project(X), atol=1e-6)

    # blobs drawn where the real (distorted) lens sees them end up where the pinhole sees them
    X = np.array([[-0.5, -0.35, 1.0], [0.45, 0.3, 1.0], [0.0, 0.0, 1.0], [-0.45, 0.3, 1.0]])
    img = _blob_image(cam.width, cam.height, cam.project(X), sigma=2.0)
    und = cam.undistort_image(img)
    assert und.shape == img.shape and und.dtype == img.dtype
    maps = cam._maps["remap"]
    for (u, v), (ud, vd) in zip(pin.project(X), cam.project(X)):
        np.testing.assert_allclose(_centroid(und, u, v, 6), [u, v], atol=0.15)
        assert np.hypot(u - ud, v - vd) > 3 or (u, v) == pytest.approx((161.3, 118.7))
    mask = (img > 0.5).astype(np.uint8) * 255
    assert set(np.unique(cam.undistort_image(mask, cv2.INTER_NEAREST))) <= {0, 255}
    assert cam._maps["remap"] is maps  # computed once
    with pytest.raises(ValueError, match="320x240"):
        cam.undistort_image(np.zeros((10, 10)))


# ---------------------------------------------------------------------------------------------
# files
# ---------------------------------------------------------------------------------------------
def _rig(rng):
    cams = [_random_camera(rng, f"cam{i}") for i in range(3)]
    cams.append(depth_camera_sr4000([0.3, 1.2, 3.0], [0, 1, 0], name="cam3"))
    return cams


def test_calibration_json_round_trip(tmp_path):
    cams = _rig(np.random.default_rng(7))
    path = tmp_path / "calibration.json"
    save_calibration(path, cams)
    back = load_calibration(path)
    assert len(back) == 4 and all(_same(a, b) for a, b in zip(cams, back))
    assert all(_same(a, b) for a, b in zip(cams, load_cameras(path)))
    assert json.loads(path.read_text())["cameras"][3]["kind"] == "depth"
    assert _same(Camera.from_dict(cams[0].to_dict()), cams[0])


@pytest.mark.parametrize("suffix", [".yml", ".yaml", ".json", ".xml"])
def test_opencv_filestorage_round_trip(tmp_path, suffix):
    cams = _rig(np.random.default_rng(8))
    path = tmp_path / f"rig{suffix}"
    save_opencv_yaml(path, cams)
    for back in (load_opencv_yaml(path), load_cameras(path)):
        assert len(back) == 4 and all(_same(a, b) for a, b in zip(cams, back))


def test_opencv_single_camera_with_rvec(tmp_path):
    cam = _random_camera(np.random.default_rng(9), "side")
    path = tmp_path / "single.yml"
    fs = cv2.FileStorage(str(path), cv2.FileStorage_WRITE)
    fs.write("camera_name", "side")
    fs.write("image_width", cam.width)
    fs.write("image_height", cam.height)
    fs.write("camera_matrix", cam.K)
    fs.write("distortion_coefficients", cam.dist[:4].reshape(4, 1))  # 4-term file: k3 = 0
    fs.write("rvec", cv2.Rodrigues(cam.R)[0])
    fs.write("T", cam.t.reshape(3, 1))
    fs.release()
    (back,) = load_opencv_yaml(path)
    assert back.name == "side" and back.kind == "colour" and back.dist[4] == 0
    np.testing.assert_allclose(back.R, cam.R, atol=1e-12)
    np.testing.assert_array_equal(back.dist[:4], cam.dist[:4])
    X = _points_in_front(cam, np.random.default_rng(10), 20)
    expect = dataclasses.replace(cam, dist=np.append(cam.dist[:4], 0)).project(X)
    np.testing.assert_allclose(back.project(X), expect, atol=1e-8)


def test_opencv_ros_style_yaml(tmp_path):
    path = tmp_path / "ros.yaml"
    path.write_text("image_width: 640\nimage_height: 480\ncamera_name: left\n"
                    "camera_matrix:\n  rows: 3\n  cols: 3\n"
                    "  data: [510.5, 0, 322.25, 0, 511.0, 241.5, 0, 0, 1]\n"
                    "distortion_model: plumb_bob\n"
                    "distortion_coefficients:\n  rows: 1\n  cols: 5\n"
                    "  data: [-0.2, 0.05, 0.001, 0, 0]\n")
    (cam,) = load_cameras(path)
    assert (cam.name, cam.width, cam.height) == ("left", 640, 480)
    np.testing.assert_array_equal(cam.K, [[510.5, 0, 322.25], [0, 511.0, 241.5], [0, 0, 1]])
    np.testing.assert_array_equal(cam.dist, [-0.2, 0.05, 0.001, 0, 0])
    np.testing.assert_array_equal(cam.R, np.eye(3))


CALISCOPE_TOML = """\
[cameras.0]
cam_id = 0
rotation_count = 0
ignore = false
size = [640, 480]
matrix = [[500.0, 0.0, 320.0], [0.0, 505.0, 240.0], [0.0, 0.0, 1.0]]
distortions = [0.1, -0.05, 0.001, 0.002, 0.01]
translation = [0.1, -0.2, 1.5]
rotation = {rotation}

[cameras.2]
cam_id = 2
ignore = true
size = [640, 480]
matrix = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]
distortions = [0.0, 0.0, 0.0, 0.0, 0.0]
translation = [0.0, 0.0, 0.0]
rotation = [0.0, 0.0, 0.0]
"""


def test_caliscope_synthetic_matrix_and_rodrigues(tmp_path):
    rvec = np.array([0.3, -1.1, 0.4])
    R = cv2.Rodrigues(rvec)[0]
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text(CALISCOPE_TOML.format(rotation=json.dumps(R.tolist())))
    b.write_text(CALISCOPE_TOML.format(rotation=json.dumps(rvec.tolist())))
    (ca,), (cb,) = load_caliscope_toml(a), load_cameras(b)  # cam 2 is ignored
    assert ca.name == "cam0" and (ca.width, ca.height) == (640, 480)
    np.testing.assert_array_equal(ca.R, R)
    np.testing.assert_allclose(cb.R, R, atol=1e-12)
    np.testing.assert_array_equal(ca.t, [0.1, -0.2, 1.5])
    np.testing.assert_array_equal(ca.dist, [0.1, -0.05, 0.001, 0.002, 0.01])


def _axes_meeting_point(cams):
    """Least-squares point closest to all optical axes."""
    M, rhs = np.zeros((3, 3)), np.zeros(3)
    for c in cams:
        P = np.eye(3) - np.outer(c.R[2], c.R[2])
        M += P
        rhs += P @ c.center
    return np.linalg.solve(M, rhs)


def _rig_is_plausible(cams) -> bool:
    centres = np.array([c.center for c in cams])
    spread = np.linalg.norm(centres[:, None] - centres[None], axis=-1).max()
    p = _axes_meeting_point(cams)
    uv = np.array([c.project(p[None], distort=False)[0] for c in cams])
    inside = np.all((uv >= 0) & (uv <= [cams[0].width, cams[0].height]))
    return bool(spread < 3.0 and all(c.depth_of(p[None])[0] > 0.3 for c in cams) and inside)


def test_caliscope_real_camera_array():
    path = _caliscope_file()
    cams = load_caliscope_toml(path)
    assert [c.name for c in cams] == ["cam0", "cam1", "cam2", "cam3"]
    assert all((c.width, c.height, c.kind) == (1280, 720, "colour") for c in cams)
    assert cams[0].K[0, 0] == pytest.approx(903.550124089999)
    assert cams[0].dist[0] == pytest.approx(-0.3320992998866297)
    # all four cameras look at a common region about a metre in front of them ...
    assert _rig_is_plausible(cams)
    # ... which fails if rotation/translation were camera -> world instead
    swapped = [Camera(c.name, c.kind, c.width, c.height, c.K, c.dist, c.R.T, -c.R.T @ c.t)
               for c in cams]
    assert not _rig_is_plausible(swapped)
    # caliscope's config.toml ([cam_N] tables) holds the same calibration
    config = path.with_name("config.toml")
    if config.is_file():
        assert all(_same(a, b) for a, b in zip(cams, load_cameras(config)))


# ---------------------------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------------------------
def _good_dict():
    return look_at_camera("cam0", [0, 1, 3], [0, 1, 0], 64, 48, 50).to_dict()


@pytest.mark.parametrize("field, value, message", [
    ("R", [[1, 0, 0], [0, 1, 0.01], [0, 0, 1]], r"cameras\[1\]\.R must be a rotation"),
    ("R", [[-1, 0, 0], [0, 1, 0], [0, 0, 1]], r"cameras\[1\]\.R must be a rotation"),
    ("K", None, r"cameras\[1\]\.K is missing"),
    ("K", [[1, 0, 0], [0, 1, 0]], r"cameras\[1\]\.K must be 3x3"),
    ("K", [[-100, 0, 32], [0, 100, 24], [0, 0, 1]], r"cameras\[1\]\.K must have positive focal"),
    ("K", [[100, 1, 32], [0, 100, 24], [0, 0, 1]], r"cameras\[1\]\.K must have zero skew"),
    ("dist", [0.1, 0.0, 0.0, 0.0], r"cameras\[1\]\.dist must be a list of 5"),
    ("t", [0, "x", 1], r"cameras\[1\]\.t must contain only numbers"),
    ("t", [0, float("nan"), 1], r"cameras\[1\]\.t must be finite"),
    ("width", 0, r"cameras\[1\]\.width must be a positive integer"),
    ("height", 2.5, r"cameras\[1\]\.height must be a positive integer"),
    ("kind", "infrared", r"cameras\[1\]\.kind must be one of"),
])
def test_calibration_json_errors_name_file_and_field(tmp_path, field, value, message):
    bad = _good_dict()
    if value is None:
        del bad[field]
    else:
        bad[field] = value
    good = _good_dict()
    good["name"] = "cam1_ok"
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps({"cameras": [good, bad]}))
    with pytest.raises(ValueError, match=r"calibration\.json: " + message):
        load_calibration(path)


def test_file_level_errors(tmp_path):
    path = tmp_path / "calibration.json"
    path.write_text("{not json")
    with pytest.raises(ValueError, match=r"calibration\.json: not valid JSON"):
        load_calibration(path)
    with pytest.raises(ValueError, match=r"calibration\.json: not valid JSON"):
        load_cameras(path)
    path.write_text(json.dumps({"cameras": []}))
    with pytest.raises(ValueError, match="non-empty list"):
        load_calibration(path)
    path.write_text(json.dumps({"cameras": [_good_dict(), _good_dict()]}))
    with pytest.raises(ValueError, match="duplicate camera names"):
        load_calibration(path)

    yml = tmp_path / "intrinsics.yml"
    fs = cv2.FileStorage(str(yml), cv2.FileStorage_WRITE)
    fs.write("image_width", 64)
    fs.write("image_height", 48)
    fs.release()
    with pytest.raises(ValueError, match=r"intrinsics\.yml: camera_matrix is missing"):
        load_opencv_yaml(yml)
    fs = cv2.FileStorage(str(yml), cv2.FileStorage_WRITE)
    fs.startWriteStruct("cam0", cv2.FileNode_MAP)
    fs.write("image_width", 64)
    fs.write("image_height", 48)
    fs.write("camera_matrix", np.array([[100.0, 0, 32], [0, 100, 24], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[0.1, 0.2, 0.0, 0.0, 0.0, 0.3]]))
    fs.endWriteStruct()
    fs.release()
    with pytest.raises(ValueError, match=r"intrinsics\.yml: cam0\.distortion_coefficients"):
        load_opencv_yaml(yml)
    garbage = tmp_path / "garbage.yml"
    garbage.write_text("%YAML:1.0\n---\n: : [unbalanced\n")
    with pytest.raises(ValueError, match=r"garbage\.yml"):
        load_opencv_yaml(garbage)

    toml = tmp_path / "camera_array.toml"
    toml.write_text(CALISCOPE_TOML.format(rotation="[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]"))
    with pytest.raises(ValueError, match=r"camera_array\.toml: cameras\.0\.rotation must be 3x3"):
        load_caliscope_toml(toml)
    toml.write_text("[cameras.0\n")
    with pytest.raises(ValueError, match=r"camera_array\.toml: not valid TOML"):
        load_cameras(toml)
    with pytest.raises(ValueError, match="unknown calibration format"):
        load_cameras(tmp_path / "rig.txt")
    with pytest.raises(FileNotFoundError):
        load_opencv_yaml(tmp_path / "missing.yml")


def test_camera_constructor_names_field():
    with pytest.raises(ValueError, match=r"Camera\('x'\)\.R must be a rotation"):
        Camera("x", "depth", 10, 10, np.eye(3), np.zeros(5), 2 * np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match=r"Camera\('x'\)\.dist must be"):
        Camera("x", "depth", 10, 10, np.eye(3), np.zeros(4), np.eye(3), np.zeros(3))


# ---------------------------------------------------------------------------------------------
# every calibration reader: round trips, detection from the content, errors, units
# (gltrack.data.calibration)
# ---------------------------------------------------------------------------------------------
from gltrack.data.calibration import (  # noqa: E402
    check_metres,
    detect_format,
    load_any_calibration,
    load_pose2sim_toml,
    load_qualisys_qca,
    save_pose2sim_toml,
)


def _zup_rig(n=3, W=1088, H=1920, distort=True):
    """Portrait cameras 3 m around the origin of a Z-up world (Pose2Sim-like), known exactly."""
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.3
        eye = [3 * np.cos(a), 3 * np.sin(a), 1.5 + 0.1 * i]
        c = look_at_camera(f"cam_{i + 1:02d}", eye, [0.1, -0.2, 0.9], W, H, 60.0,
                           up=(0, 0, 1))
        K = c.K.copy()
        K[0, 2] += 3.25 * (i + 1)
        K[1, 1] *= 1.001
        dist = np.array([-0.05 * (i + 1), 0.01, 0.001, -0.0005, 0.0]) if distort else np.zeros(5)
        cams.append(dataclasses.replace(c, K=K, dist=dist))
    return cams


def _write_qca(path, cams, video_resolution=None, model="none"):
    """A Qualisys .qca.txt of ``cams`` with Pose2Sim's conventions (the inverse of the reader)."""
    lines = ["<?xml version='1.0' encoding='ASCII'?>", '<calibration type="regular">',
             "  <cameras>"]
    s = 1.0 if video_resolution is None else 1080 / video_resolution
    for c in cams:
        R_qca = np.diag([1.0, -1.0, -1.0]) @ c.R
        centre_mm = c.center * 1000
        rot = " ".join(f'r{i + 1}{j + 1}="{R_qca[i, j]:.17g}"' for i in range(3) for j in range(3))
        res = "" if video_resolution is None else f' video_resolution="{video_resolution}p"'
        W, H = round(c.width * s), round(c.height * s)
        lines += [f'    <camera active="1" model="{model}" serial="{c.name}"{res}>',
                  f'      <fov_video bottom="{H - 1}" left="0" right="{W - 1}" top="0"/>',
                  f'      <transform {rot} x="{centre_mm[0]:.17g}" y="{centre_mm[1]:.17g}" '
                  f'z="{centre_mm[2]:.17g}"/>',
                  f'      <intrinsic focalLengthU="{c.fx * 64 * s:.17g}" focalLengthV="{c.fy * 64 * s:.17g}" '
                  f'centerPointU="{c.cx * 64 * s:.17g}" centerPointV="{c.cy * 64 * s:.17g}" '
                  f'radialDistortion1="{c.dist[0] * 64:.17g}" radialDistortion2="{c.dist[1] * 64:.17g}" '
                  f'radialDistortion3="0" tangentalDistortion1="{c.dist[2] * 64:.17g}" '
                  f'tangentalDistortion2="{c.dist[3] * 64:.17g}"/>',
                  "    </camera>"]
    lines += ["  </cameras>", "</calibration>", ""]
    Path(path).write_text("\n".join(lines))


def _write_caliscope(path, cams):
    lines = []
    for i, c in enumerate(cams):
        lines += [f"[cameras.{i}]", f"cam_id = {i}", "rotation_count = 0", "ignore = false",
                  f"size = [{c.width}, {c.height}]", f"matrix = {json.dumps(c.K.tolist())}",
                  f"distortions = {json.dumps(c.dist.tolist())}",
                  f"translation = {json.dumps(c.t.tolist())}",
                  f"rotation = {json.dumps(c.R.tolist())}", ""]
    Path(path).write_text("\n".join(lines))


def _max_reprojection(a, b, n=300):
    """Largest pixel difference of two cameras over points in front of ``a``."""
    X = _points_in_front(a, np.random.default_rng(7), n)
    return float(np.abs(a.project(X) - b.project(X)).max())


def _assert_same_rig(got, want, names=None, tol_px=1e-6):
    assert len(got) == len(want)
    for g, w, name in zip(got, want, names or [c.name for c in want]):
        assert g.name == name
        assert (g.width, g.height) == (w.width, w.height)
        np.testing.assert_allclose(g.K, w.K, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(g.dist, w.dist, atol=1e-12)
        np.testing.assert_allclose(g.R, w.R, atol=1e-9)
        np.testing.assert_allclose(g.t, w.t, atol=1e-9)
        assert _max_reprojection(w, g) < tol_px


@pytest.mark.parametrize("fmt", ["gltrack", "opencv-yml", "opencv-json", "opencv-xml",
                                 "caliscope", "pose2sim", "qualisys"])
def test_every_reader_round_trips_and_is_detected_from_content(tmp_path, fmt):
    cams = _zup_rig()
    # a neutral suffix: the format must come from the content, not from the name
    path = tmp_path / "calib.dat"
    names = None
    if fmt == "gltrack":
        save_calibration(path, cams)
    elif fmt.startswith("opencv"):
        real = tmp_path / f"calib.{fmt.split('-')[1]}"  # FileStorage picks its syntax by suffix
        save_opencv_yaml(real, cams)
        real.rename(path)
    elif fmt == "caliscope":
        _write_caliscope(path, cams)
        names = [f"cam{i}" for i in range(len(cams))]
    elif fmt == "pose2sim":
        save_pose2sim_toml(path, cams)
    else:
        _write_qca(path, cams)
    want = {"opencv-yml": "opencv", "opencv-json": "opencv", "opencv-xml": "opencv"}.get(fmt, fmt)
    if fmt.startswith("opencv") and fmt != "opencv-json":
        path = path.rename(tmp_path / f"calib.{fmt.split('-')[1]}")  # cv2 needs the suffix to read
    assert detect_format(path) == want
    _assert_same_rig(load_any_calibration(path), cams, names,
                     tol_px=1e-6 if fmt != "qualisys" else 1e-5)


def test_opencv_json_without_suffix_is_still_read(tmp_path):
    cams = _zup_rig(2)
    save_opencv_yaml(tmp_path / "c.json", cams)
    assert detect_format(tmp_path / "c.json") == "opencv"
    _assert_same_rig(load_any_calibration(tmp_path / "c.json"), cams)


def test_pose2sim_toml_four_distortion_terms_and_metadata(tmp_path):
    path = tmp_path / "Calib.toml"
    path.write_text('[cam_01]\nname = "front"\nsize = [ 1088.0, 1920.0]\n'
                    "matrix = [[1500.0, 0.0, 540.0], [0.0, 1500.0, 960.0], [0.0, 0.0, 1.0]]\n"
                    "distortions = [-0.01, 0.02, 0.001, 0.002]\nrotation = [0.1, 0.2, 0.3]\n"
                    "translation = [0.5, 0.6, 3.0]\nfisheye = false\n\n"
                    "[metadata]\nadjusted = false\nerror = 0.0\n")
    (cam,) = load_pose2sim_toml(path)
    assert cam.name == "front" and (cam.width, cam.height) == (1088, 1920)
    np.testing.assert_array_equal(cam.dist, [-0.01, 0.02, 0.001, 0.002, 0.0])
    np.testing.assert_allclose(cam.R, cv2.Rodrigues(np.array([0.1, 0.2, 0.3]))[0])


def test_qualisys_video_resolution_and_marker_cameras(tmp_path):
    cams = _zup_rig(2, W=1920, H=1088)
    # a 540p recording of cameras calibrated at 1080p: image and K halve
    _write_qca(tmp_path / "a.qca.txt", [c.scaled(960, 544) for c in cams], video_resolution=540)
    got = load_qualisys_qca(tmp_path / "a.qca.txt")
    assert [(c.width, c.height) for c in got] == [(960, 544)] * 2
    for g, c in zip(got, cams):
        np.testing.assert_allclose(g.fx, c.fx / 2, rtol=1e-12)
    # marker-only cameras (no video) are skipped as Pose2Sim skips them
    _write_qca(tmp_path / "b.qca.txt", cams, model="Arqus A12")
    with pytest.raises(ValueError, match="no video camera"):
        load_qualisys_qca(tmp_path / "b.qca.txt")


@pytest.mark.parametrize("fmt, edit, message", [
    ("pose2sim", lambda s: s.replace("matrix = ", "matrx = ", 1), r"\[cam_01\]\.matrix is missing"),
    ("pose2sim", lambda s: s.replace("fisheye = false", "fisheye = true", 1),
     r"\[cam_01\]\.fisheye"),
    ("pose2sim", lambda s: s.replace("size = [1088.0, 1920.0]", "size = [1088.0]", 1),
     r"\[cam_01\]\.size must be \[width, height\]"),
    ("pose2sim", lambda s: s.replace("rotation = [", "rotation = [1.0, ", 1),
     r"\[cam_01\]\.rotation must be a Rodrigues vector"),
    ("qualisys", lambda s: s.replace("focalLengthU=", "focalLengthX=", 1),
     r"camera\[0\] \(serial cam_01\)\.intrinsic\.focalLengthU is missing"),
    ("qualisys", lambda s: s.replace(' x="', ' x="abc', 1),
     r"camera\[0\] \(serial cam_01\)\.transform\.x must be a number"),
    ("qualisys", lambda s: s.replace("<fov_video", "<fov_vid", 1),
     r"camera\[0\] \(serial cam_01\): element <fov_video> is missing"),
    ("qualisys", lambda s: s.replace("</calibration>", "", 1), "not valid XML"),
])
def test_reader_errors_name_file_and_field(tmp_path, fmt, edit, message):
    path = tmp_path / "bad.txt"
    cams = _zup_rig(2)
    (save_pose2sim_toml if fmt == "pose2sim" else _write_qca)(path, cams)
    path.write_text(edit(path.read_text()))
    with pytest.raises(ValueError, match=message) as info:
        load_any_calibration(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("text, message", [
    ("hello = 3\n", "TOML without camera tables"),
    ("<root/>\n", "XML but neither"),
    ("{not json", "not valid JSON"),
    ("\x00\x01\x02 binary", "not a calibration file"),
])
def test_unknown_formats_are_named(tmp_path, text, message):
    path = tmp_path / "x.cal"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        load_any_calibration(path)
    assert str(path) in str(info.value)
    with pytest.raises(FileNotFoundError, match="no such file"):
        load_any_calibration(tmp_path / "absent.toml")


def test_millimetres_are_detected(tmp_path):
    cams = _zup_rig()
    mm = [dataclasses.replace(c, t=c.t * 1000) for c in cams]
    save_pose2sim_toml(tmp_path / "mm.toml", mm)
    with pytest.raises(ValueError, match=r"mm\.toml: translation: .*millimetres"):
        load_any_calibration(tmp_path / "mm.toml")
    assert check_metres(cams, "ok") < 10  # metres pass: a 3 m ring spans ~5 m
    save_calibration(tmp_path / "mm.json", mm[:1])  # one camera: its distance from the origin
    with pytest.raises(ValueError, match=r"mm\.json: t: the camera lies"):
        load_any_calibration(tmp_path / "mm.json")


def test_pose2sim_toml_and_qualisys_agree_on_the_shared_take(shared):
    folder = shared / "video" / "pose2sim_balancing_4cam"
    toml, qca = folder / "Calib_qualisys.toml", folder / "Calib.qca.txt"
    if not (toml.is_file() and qca.is_file()):
        pytest.skip(f"{folder}: calibration files absent")
    assert (detect_format(toml), detect_format(qca)) == ("pose2sim", "qualisys")
    a, b = load_any_calibration(toml), load_any_calibration(qca)
    assert [c.name for c in a] == ["cam_01", "cam_02", "cam_03", "cam_04"]
    assert [c.name for c in b] == ["cam01", "cam02", "cam03", "cam04"]
    # points in the capture volume (Z-up, floor z = 0), in front of every camera
    rng = np.random.default_rng(3)
    X = rng.uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 2.0], (500, 3))
    for ca, cb in zip(a, b):
        assert (ca.width, ca.height) == (cb.width, cb.height) == (1088, 1920)
        assert np.all(ca.depth_of(X) > 0)
        err = np.abs(ca.project(X) - cb.project(X)).max()
        assert err < 1.0, f"{ca.name}: {err:.3g} px"
