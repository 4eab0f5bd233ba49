"""CPU oracle (gltrack.render.reference) and pyrender baseline (gltrack.bench.baseline)."""
from __future__ import annotations

import time

import numpy as np
import pytest
import trimesh

from gltrack.body.dofs import make_dofs
from gltrack.body.kinematics import Kinematics
from gltrack.body.mesh import BodyMesh, make_body_mesh
from gltrack.body.skeleton import default_skeleton
from gltrack.render import reference as ref
from gltrack.bench.baseline import gl_camera_pose, run_baseline_in_subprocess

# ---------------------------------------------------------------------------------------------
# fixtures


@pytest.fixture(scope="module")
def body():
    sk = default_skeleton(1.75)
    dofs = make_dofs(sk, "full")
    return sk, dofs, Kinematics(sk, dofs), make_body_mesh(sk)


def _random_poses(sk, dofs, rng, n, spread=6.0):
    p = dofs.zero(sk)[None].repeat(n, 0)
    p[:, 6:] += rng.normal(size=(n, dofs.size - 6)) * dofs.sigma30[6:] * spread
    p[:, 3:6] += rng.normal(size=(n, 3)) * 0.2
    return dofs.validate(p)


def _camera(width=96, height=96):
    """A camera 3 m in front of the subject, slightly above and to the side, looking at it."""
    C = np.array([0.6, 1.2, 3.0])
    target = np.array([0.0, 1.0, 0.0])
    z = target - C
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, -1.0, 0.0])  # image x right, y down
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    t = -R @ C
    f = 1.5 * height  # body about 0.8 of the image height
    # principal point off-centre on purpose, so a half-pixel convention error cannot cancel
    K = np.array([[f, 0, width / 2 - 0.5 + 1.3], [0, f, height / 2 - 0.5 - 0.7], [0, 0, 1]])
    return K, R, t, width, height


def _K(f=10.0, cx=0.0, cy=0.0):
    return np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])


def _lift(uv, z, K):
    """Camera-frame points that project to pixel coords ``uv`` at depths ``z``."""
    uv = np.asarray(uv, float)
    z = np.broadcast_to(np.asarray(z, float), (len(uv),))
    x = (uv[:, 0] - K[0, 2]) / K[0, 0] * z
    y = (uv[:, 1] - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], 1)


# ---------------------------------------------------------------------------------------------
# rasteriser


@pytest.mark.parametrize("winding", [[0, 1, 2], [0, 2, 1]])
def test_single_triangle_coverage_and_depth(winding):
    K = _K()
    verts = _lift([(0.5, 0.5), (6.5, 0.5), (0.5, 6.5)], 2.0, K)
    depth, tri = ref.rasterize(verts, np.array([winding]), K, 8, 8)
    rows, cols = np.mgrid[0:8, 0:8]
    expect = (cols >= 1) & (rows >= 1) & (cols + rows <= 7)  # centres inside, edges inclusive
    assert expect.sum() == 21
    np.testing.assert_array_equal(depth > 0, expect)
    np.testing.assert_allclose(depth[expect], 2.0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(tri, np.where(expect, 0, -1))
    assert depth.dtype == np.float64 and tri.dtype == np.int32


def test_quad_pixel_centre_convention():
    K = _K(f=20.0, cx=3.0, cy=2.0)
    uv = [(1.6, 2.6), (5.4, 2.6), (5.4, 4.4), (1.6, 4.4)]  # covers cols 2..5, rows 3..4
    verts = _lift(uv, 1.5, K)
    depth, tri = ref.rasterize(verts, np.array([[0, 1, 2], [0, 2, 3]]), K, 8, 6)
    expect = np.zeros((6, 8), bool)
    expect[3:5, 2:6] = True
    np.testing.assert_array_equal(depth > 0, expect)
    assert set(np.unique(tri[expect])) == {0, 1}
    # moving the quad by 0.5 px must change coverage: centres are at integers
    depth2, _ = ref.rasterize(_lift(np.array(uv) + 0.5, 1.5, K), np.array([[0, 1, 2], [0, 2, 3]]),
                              K, 8, 6)
    assert (depth2 > 0).sum() != expect.sum() or np.any((depth2 > 0) != expect)


def test_perspective_correct_depth_on_slanted_plane():
    K = np.array([[50.0, 0, 31.5], [0, 45.0, 23.5], [0, 0, 1]])
    W, H = 64, 48
    z0, a, b = 2.0, 0.6, -0.3  # plane z = z0 + a x + b y (camera frame)
    xs = np.array([-1.5, 1.5, 1.5, -1.5])
    ys = np.array([-1.0, -1.0, 1.0, 1.0])
    verts = np.stack([xs, ys, z0 + a * xs + b * ys], 1)
    depth, tri = ref.rasterize(verts, np.array([[0, 1, 2], [0, 2, 3]]), K, W, H)
    r, c = np.nonzero(depth > 0)
    assert len(r) > 0.5 * W * H
    dx = (c - K[0, 2]) / K[0, 0]
    dy = (r - K[1, 2]) / K[1, 1]
    z_true = z0 / (1.0 - a * dx - b * dy)  # ray s*(dx, dy, 1) meets the plane
    np.testing.assert_allclose(depth[r, c], z_true, rtol=1e-12)
    # screen-space linear interpolation of z would be wrong by far more than that
    assert np.abs(depth[r, c] - z_true).max() < 1e-9
    assert np.ptp(depth[r, c]) > 0.5


def test_closer_triangle_wins_and_intersection():
    K = _K(f=10.0, cx=4.0, cy=4.0)
    big = [(-2, -2), (20, -2), (-2, 20)]
    near_tri = _lift(big, 2.0, K)
    far_tri = _lift(big, 3.0, K)
    for faces, closer in (([[0, 1, 2], [3, 4, 5]], 0), ([[3, 4, 5], [0, 1, 2]], 1)):
        depth, tri = ref.rasterize(np.concatenate([near_tri, far_tri]), np.array(faces), K, 8, 8)
        assert np.all(tri == closer)
        np.testing.assert_allclose(depth, 2.0)
    # two crossing planes: the result is their per-pixel minimum
    xs = np.array([-2.0, 2.0, 2.0, -2.0])
    ys = np.array([-2.0, -2.0, 2.0, 2.0])
    p1 = np.stack([xs, ys, 2.0 + 0.5 * xs], 1)
    p2 = np.stack([xs, ys, 2.0 - 0.5 * xs], 1)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    depth, tri = ref.rasterize(np.concatenate([p1, p2]), faces, K, 8, 8)
    dx = (np.arange(8) - 4.0) / 10.0
    z1 = 2.0 / (1 - 0.5 * dx)
    z2 = 2.0 / (1 + 0.5 * dx)
    np.testing.assert_allclose(depth, np.broadcast_to(np.minimum(z1, z2), (8, 8)), rtol=1e-12)
    assert np.all(tri[:, :4] <= 1) and np.all(tri[:, 5:] >= 2)  # z1 is nearer left of centre


def test_shared_edges_through_pixel_centres_leave_no_holes():
    """A randomly split grid whose edges pass exactly through pixel centres covers every one."""
    K = np.array([[37.3, 0, 3.1], [0, 41.7, 2.9], [0, 0, 1]])
    n = 9
    g = 2.0 * np.stack(np.meshgrid(np.arange(n), np.arange(n)), -1).reshape(-1, 2)
    for seed in range(10):
        rng = np.random.default_rng(seed)
        v = _lift(g, 1.0 + rng.random(len(g)), K)
        faces = []
        for r in range(n - 1):
            for c in range(n - 1):
                a, b, cc, d = r * n + c, r * n + c + 1, (r + 1) * n + c + 1, (r + 1) * n + c
                faces += [[a, b, cc], [a, cc, d]] if rng.random() < 0.5 else [[a, b, d], [b, cc, d]]
        perm = rng.permutation(len(v))  # vertex ids unrelated to position
        depth, tri = ref.rasterize(v[perm], np.argsort(perm)[np.array(faces)], K, 17, 17)
        assert np.all(depth[1:16, 1:16] > 0)
        assert np.all(depth[1:16, 1:16] >= 1.0) and np.all(depth <= 2.0)


def test_near_plane_drops_whole_triangle():
    K = _K(f=10.0, cx=4.0, cy=4.0)
    verts = _lift([(0, 0), (8, 0), (0, 8)], 1.0, K)
    depth, _ = ref.rasterize(verts, np.array([[0, 1, 2]]), K, 8, 8)
    assert (depth > 0).sum() > 20
    verts[2, 2] = 0.04  # one vertex in front of the near plane
    depth, tri = ref.rasterize(verts, np.array([[0, 1, 2]]), K, 8, 8)
    assert np.all(depth == 0) and np.all(tri == -1)
    depth, _ = ref.rasterize(verts, np.array([[0, 1, 2]]), K, 8, 8, near=0.01)
    assert (depth > 0).sum() > 0


def test_rasterize_rejects_bad_input():
    K = _K()
    with pytest.raises(ValueError, match="faces"):
        ref.rasterize(np.zeros((3, 3)), np.zeros((1, 4), int), K, 8, 8)
    with pytest.raises(ValueError, match="faces index"):
        ref.rasterize(np.ones((3, 3)), np.array([[0, 1, 3]]), K, 8, 8)
    # faces touching non-finite vertices are dropped, the rest still render
    v = _lift([(0.5, 0.5), (6.5, 0.5), (0.5, 6.5)], 2.0, K)
    v = np.concatenate([v, [[np.nan, 0, 2], [np.inf, 0, 2]]])
    _, tri = ref.rasterize(v, np.array([[0, 3, 2], [0, 1, 2], [4, 1, 2]]), K, 8, 8)
    assert set(np.unique(tri)) == {-1, 1} and (tri == 1).sum() == 21
    with pytest.raises(ValueError, match="skew"):
        ref.rasterize(np.zeros((3, 3)), np.zeros((1, 3), int), K + np.eye(3)[[0]].T @ [[0, 1, 0]],
                      8, 8)


def test_rasterizer_speed_2000_triangles():
    rng = np.random.default_rng(3)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.9)  # 1280 faces
    sphere2 = trimesh.creation.icosphere(subdivisions=2, radius=0.5)  # 320 faces
    v = np.concatenate([sphere.vertices + [0, 0, 3.0], sphere2.vertices + [0.4, 0.2, 2.0],
                        rng.normal(size=(1200, 3)) * 0.3 + [0, 0, 2.5]])
    f = np.concatenate([sphere.faces, sphere2.faces + len(sphere.vertices),
                        rng.integers(len(sphere.vertices) + len(sphere2.vertices), len(v),
                                     size=(400, 3))])
    assert len(f) == 2000
    K = _K(f=100.0, cx=63.5, cy=63.5)
    ref.rasterize(v, f, K, 128, 128)
    t0 = time.perf_counter()
    depth, tri = ref.rasterize(v, f, K, 128, 128)
    elapsed = time.perf_counter() - t0
    assert (depth > 0).sum() > 3000
    assert elapsed < 1.0, f"rasterising 2000 triangles took {elapsed:.3f} s"


# ---------------------------------------------------------------------------------------------
# skinning and rendering of candidates


def test_matrix_blend_skinning_matches_point_blend(body):
    sk, dofs, kin, _ = body
    rng = np.random.default_rng(0)
    V = 200
    joints = rng.integers(0, sk.n_joints, size=(V, 4)).astype(np.int32)
    w = rng.random((V, 4)).astype(np.float32)
    w[:, 3] = 0.0  # an unused slot
    w /= w.sum(1, keepdims=True)
    mesh = BodyMesh(rng.normal(size=(V, 3)), np.array([[0, 1, 2]]), joints, w, np.zeros(V))
    S = kin.skinning_matrices(_random_poses(sk, dofs, rng, 4), dtype=np.float64)
    np.testing.assert_allclose(ref.skin_vertices(mesh, S), mesh.skin(S), atol=1e-12)
    assert not np.allclose(ref.skin_vertices(mesh, S[:1]), ref.skin_vertices(mesh, S[1:2]))


def test_render_candidates_and_scores_follow_pose(body):
    sk, dofs, kin, mesh = body
    rng = np.random.default_rng(1)
    K, R, t, W, H = _camera(64, 64)
    S = kin.skinning_matrices(_random_poses(sk, dofs, rng, 3))
    depth, tri = ref.render_candidates(mesh, S, K, R, t, W, H)
    assert depth.shape == (3, H, W) and tri.shape == (3, H, W)
    assert np.all((depth > 0) == (tri >= 0))
    assert np.all(depth[depth > 0] > 2.0) and np.all(depth < 5.0)
    assert (depth[0] > 0).sum() > 200
    assert np.any(depth[0] != depth[1])
    obs = depth[0]
    sd = ref.score_depth(mesh, S, K, R, t, W, H, obs)
    assert sd[0] == 0.0 and np.all(sd[1:] > 5.0)
    fg = obs > 0
    ss = ref.score_silhouette(mesh, S, K, R, t, W, H, fg)
    assert ss[0] == 0.0 and np.all(ss[1:] > 5.0)
    np.testing.assert_array_equal(ss, [((d > 0) ^ fg).sum() for d in depth])
    # the whole image blocked: nothing counts
    assert np.all(ref.score_silhouette(mesh, S, K, R, t, W, H, fg, np.ones_like(fg)) == 0)
    ones = np.full((H, W, 3), 0xFFFFFFFF, np.uint32)
    tb = np.ones((mesh.n_faces, 3), np.uint32)
    sa = ref.score_appearance(mesh, S, K, R, t, W, H, ones, tb)
    np.testing.assert_array_equal(sa, (depth > 0).sum(axis=(1, 2)))


# ---------------------------------------------------------------------------------------------
# costs


def test_depth_cost_four_cases_by_hand():
    model = np.array([[2.0, 2.0, 0.0, 0.0, 2.0]])
    obs = np.array([[2.05, 0.0, 3.0, 0.0, 2.5]])
    # d = 0.05 of scale 0.15: t = 1/3, t^2 (3 - 2t) = 7/27; d = 0.5 saturates at 1
    expect = 7 / 27 + 0.7 + 0.4 + 0.0 + 1.0
    got = ref.depth_cost(model, obs, scale=0.15, c_model_only=0.7, c_obs_only=0.4)
    assert got == pytest.approx(expect, abs=1e-12)
    assert ref.depth_cost(model, model) == 0.0
    assert ref.depth_cost(model, obs, scale=0.3, c_model_only=0.7, c_obs_only=0.4) < got


def test_smoothed_depth_cost_by_hand():
    model = np.array([[0.0, 2.0, 0.0]])
    obs = np.array([[2.0, 0.0, 0.0]])
    # k=0: own pixel obs-only (1) vs neighbour 1 exact (0 + 0.02) -> 0.02
    # k=1: own pixel model-only (1) vs neighbour 0 or 2 'neither' (0 + 0.02) -> 0.02
    # k=2: own pixel neither -> 0
    assert ref.depth_cost(model, obs, smooth=True, penalty=0.02) == pytest.approx(0.04)
    assert ref.depth_cost(model, obs) == pytest.approx(2.0)
    # a one-pixel shift of the whole image costs at most `penalty` per pixel
    rng = np.random.default_rng(5)
    z = np.where(rng.random((10, 12)) < 0.6, 2.0 + rng.random((10, 12)), 0.0)
    shifted = np.zeros_like(z)
    shifted[:, 1:] = z[:, :-1]
    # model(k + 1) == obs(k), so every pixel but the last column costs at most the penalty
    H, W = z.shape
    smooth = ref.depth_cost(shifted, z, smooth=True, penalty=0.01)
    assert smooth <= 0.01 * H * (W - 1) + 1.0 * H
    assert ref.depth_cost(shifted, z) > 3 * (0.01 * H * (W - 1) + 1.0 * H)


def _smooth_cost_loops(model, obs, scale, cm, co, penalty):
    """Literal per-pixel reading of Ganapathi's L_smooth, for comparison."""
    H, W = model.shape
    total = 0.0
    for r in range(H):
        for c in range(W):
            best = np.inf
            for rr in range(max(r - 1, 0), min(r + 2, H)):
                for cc in range(max(c - 1, 0), min(c + 2, W)):
                    zo, zm = obs[r, c], model[rr, cc]
                    if zo > 0 and zm > 0:
                        x = min(max(abs(zo - zm) / scale, 0.0), 1.0)
                        cost = x * x * (3 - 2 * x)
                    elif zm > 0:
                        cost = cm
                    elif zo > 0:
                        cost = co
                    else:
                        cost = 0.0
                    best = min(best, cost + (penalty if (rr, cc) != (r, c) else 0.0))
            total += best
    return total


def test_smoothed_depth_cost_matches_loops():
    rng = np.random.default_rng(7)
    model = np.where(rng.random((9, 11)) < 0.5, 2.0 + 0.3 * rng.random((9, 11)), 0.0)
    obs = np.where(rng.random((9, 11)) < 0.5, 2.0 + 0.3 * rng.random((9, 11)), 0.0)
    for kw in (dict(scale=0.15, c_model_only=1.0, c_obs_only=1.0, penalty=0.02),
               dict(scale=0.05, c_model_only=0.3, c_obs_only=0.8, penalty=0.1)):
        got = ref.depth_cost(model, obs, smooth=True, **kw)
        want = _smooth_cost_loops(model, obs, kw["scale"], kw["c_model_only"], kw["c_obs_only"],
                                  kw["penalty"])
        assert got == pytest.approx(want, abs=1e-9)
    assert ref.depth_cost(model, obs, smooth=True) < ref.depth_cost(model, obs)


def test_silhouette_cost_with_blocking():
    m = np.array([[1, 1, 0], [0, 1, 0]], bool)
    f = np.array([[1, 0, 1], [0, 0, 0]], bool)
    assert ref.silhouette_cost(m, f) == 3.0  # (0,1), (0,2), (1,1)
    b = np.array([[0, 1, 0], [0, 0, 0]], bool)
    assert ref.silhouette_cost(m, f, b) == 2.0
    assert ref.silhouette_cost(np.where(m, 2.5, 0.0), f, b) == 2.0  # depth works as a mask
    with pytest.raises(ValueError):
        ref.silhouette_cost(m, f[:, :2])


def test_appearance_bit_logic():
    tri = np.array([[0, 1, -1], [1, 0, 2]], np.int32)
    tri_bits = np.array([[0b0011, 0b1, 0b1],
                         [0b0100, 0b1, 0b10],
                         [0b1000, 0b1, 0b1]], np.uint32)
    obs = np.zeros((2, 3, 3), np.uint32)
    obs[0, 0] = [0b0001, 0b1, 0b1]  # tri 0: all three channels share a bit -> counts
    obs[0, 1] = [0b0100, 0b1, 0b01]  # tri 1: saturation 0b01 & 0b10 == 0 -> no
    obs[0, 2] = [0xFFFFFFFF] * 3     # empty pixel -> no
    obs[1, 0] = [0b0100, 0b11, 0b10]  # tri 1: counts
    obs[1, 1] = [0b0100, 0b1, 0b1]   # tri 0: hue 0b0100 & 0b0011 == 0 -> no
    obs[1, 2] = [0x80000008, 0x80000001, 0x1]  # tri 2: counts (high bit ignored, low bits match)
    assert ref.appearance_score(tri, obs, tri_bits) == 3.0
    block = np.zeros((2, 3), bool)
    block[1, 2] = True
    assert ref.appearance_score(tri, obs, tri_bits, block) == 2.0
    with pytest.raises(ValueError, match="tri_bits"):
        ref.appearance_score(tri, obs, tri_bits[:2])


# ---------------------------------------------------------------------------------------------
# pyrender baseline (in a spawn child: pyrender's PyOpenGL/EGL must not meet moderngl in-process)


def test_gl_camera_pose_maps_opencv_axes():
    K, R, t, W, H = _camera()
    pose = gl_camera_pose(R, t)
    X = np.array([0.3, 1.1, -0.2])
    x_cv = R @ X + t
    x_gl = np.linalg.inv(pose) @ np.append(X, 1.0)
    np.testing.assert_allclose(x_gl[:3], x_cv * [1, -1, -1], atol=1e-12)


def _spread_3x3(img):
    """Max minus min over each pixel's 3x3 neighbourhood (edge pixels padded by replication)."""
    H, W = img.shape
    pad = np.pad(img, 1, mode="edge")
    stack = np.stack([pad[dy:dy + H, dx:dx + W] for dy in range(3) for dx in range(3)])
    return stack.max(0) - stack.min(0)


def test_reference_matches_pyrender_depth(body):
    sk, dofs, kin, mesh = body
    rng = np.random.default_rng(11)
    K, R, t, W, H = _camera(96, 96)
    S = kin.skinning_matrices(_random_poses(sk, dofs, rng, 2))
    try:
        gl = run_baseline_in_subprocess("render_depth", mesh, K, R, t, W, H, S, timeout=120)[:, 0]
    except Exception as exc:  # no EGL on this machine
        pytest.skip(f"pyrender/EGL unavailable: {exc}")
    cpu, _ = ref.render_candidates(mesh, S, K, R, t, W, H)
    for g, c in zip(gl, cpu):
        both = (g > 0) & (c > 0)
        disagree = (g > 0) != (c > 0)
        assert both.sum() > 300
        assert disagree.sum() < 0.02 * (c > 0).sum()
        # disagreements only on the silhouette edge: each has a background pixel next to it
        edge = np.zeros_like(disagree)
        m = c > 0
        pad = np.pad(m, 1, constant_values=False)
        for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
            edge |= pad[dy:dy + H, dx:dx + W] != m
        assert np.all(edge[disagree])
        # depth equal away from depth discontinuities
        interior = both & (_spread_3x3(c) < 0.05) & (_spread_3x3(np.where(both, 0.0, 9.0)) == 0)
        assert interior.sum() > 0.25 * both.sum()
        np.testing.assert_allclose(g[interior], c[interior], atol=1e-4)
    # the baseline's scores agree with the reference's on its own renders
    obs = cpu[0]
    gl_scores = run_baseline_in_subprocess("score_silhouette", mesh, K, R, t, W, H, S, obs > 0,
                                           timeout=120)
    assert gl_scores[0] <= 0.02 * (obs > 0).sum()
    assert gl_scores[1] == pytest.approx(ref.silhouette_cost(cpu[1] > 0, obs > 0),
                                         abs=0.02 * (obs > 0).sum())


def test_baseline_throughput_in_subprocess(body):
    sk, dofs, kin, mesh = body
    rng = np.random.default_rng(2)
    K, R, t, W, H = _camera(64, 64)
    S = kin.skinning_matrices(_random_poses(sk, dofs, rng, 4))
    obs, _ = ref.render_candidates(mesh, S[:1], K, R, t, W, H)
    try:
        rate = run_baseline_in_subprocess("candidates_per_s", mesh, K, R, t, W, H, obs[0], S,
                                          mode="depth", n_cameras=2, repeats=2, timeout=120)
    except Exception as exc:
        pytest.skip(f"pyrender/EGL unavailable: {exc}")
    assert 0.1 < rate < 1e5
