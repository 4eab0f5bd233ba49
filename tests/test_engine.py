"""The GPU scoring engine against its independent CPU twin (gltrack.render.reference).

Tolerance: engine and reference are two rasterisers; they can disagree only on pixels whose centre
lies (within float32 rounding) on a triangle edge or where two surfaces are within float32 depth
resolution. On the default body at 64x64 that is a handful of pixels out of several hundred, so
each candidate's sum must agree within 1 % of the reference's value (with a floor of one pixel's
worth for near-zero sums).
"""
import os

import numpy as np
import pytest

from gltrack.body.dofs import make_dofs
from gltrack.body.kinematics import Kinematics
from gltrack.body.mesh import make_body_mesh
from gltrack.body.skeleton import default_skeleton
from gltrack.camera import look_at_camera
from gltrack.gl.programs import ShaderError
from gltrack.render import reference as ref
from gltrack.render.engine import (CustomCost, DepthCostParams, ScoringEngine, grid_for,
                                   silhouette_iou, silhouette_overlap)

TILE = 64
#: The engine's two ways to skin and two ways to keep a candidate in its tile (ScoringEngine's
#: ``skinning`` and ``tile_clip``): every pair must give the reference's images and scores.
# (skinning, tile clip, triangle ids): software GL's paths first, then a GPU's
PATHS = [("vertex", "distance", "provoking"), ("vertex", "fragment", "provoking"),
         ("compute", "distance", "provoking"), ("compute", "fragment", "primitive"),
         ("vertex", "distance", "primitive"), ("compute", "fragment", "provoking")]


def path_kwargs(ctx, path):
    skinning, tile_clip, triangle_ids = path
    if skinning == "compute" and ctx.version_code < 430:
        pytest.skip("compute skinning needs OpenGL 4.3")
    return {"skinning": skinning, "tile_clip": tile_clip, "triangle_ids": triangle_ids}


@pytest.fixture(scope="module")
def body():
    skel = default_skeleton(1.75)
    dofs = make_dofs(skel, "full")
    return skel, dofs, Kinematics(skel, dofs), make_body_mesh(skel)


def cams(n=1, size=TILE, kind="depth"):
    out = []
    for i in range(n):
        a = 2 * np.pi * i / max(n, 1) + 0.3
        eye = (2.4 * np.sin(a), 1.0, 2.4 * np.cos(a))
        out.append(look_at_camera(f"cam{i}", eye, (0, 0.9, 0), size, size, 50.0, kind=kind))
    return out


def random_poses(body, rng, n, sigma=0.35):
    skel, dofs, kin, _ = body
    P = dofs.zero(skel) + rng.normal(size=(n, dofs.size)) * sigma
    P[:, :3] = dofs.zero(skel)[:3] + rng.normal(size=(n, 3)) * 0.05
    P[:, 3:6] *= 0.3
    return dofs.validate(P)


def ref_render(mesh, S, cam):
    return ref.render_candidates(mesh, S, cam.K, cam.R, cam.t, cam.width, cam.height)


def assert_close(engine, reference, what):
    tol = 0.01 * np.maximum(np.abs(reference), 100.0)
    bad = np.abs(engine - reference) > tol
    assert not bad.any(), f"{what}: engine {engine[bad]} vs reference {reference[bad]}"


def test_grid_is_power_of_two():
    for n, g in [(1, (1, 1)), (2, (2, 1)), (3, (2, 2)), (5, (4, 2)), (1024, (32, 32))]:
        assert grid_for(n, 64) == g
    with pytest.raises(ValueError):
        grid_for(5000, 64)


@pytest.mark.parametrize("path", PATHS, ids="-".join)
def test_rendered_tiles_match_reference(ctx, body, rng, path):
    skel, dofs, kin, mesh = body
    cam = cams()[0]
    S = kin.skinning_matrices(random_poses(body, rng, 6))
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, **path_kwargs(ctx, path)) as eng:
        z, tri = eng.render_tiles(S)
    rz, rtri = ref_render(mesh, S, cam)
    both = (z > 0) & (rz > 0)
    differ = (z > 0) != (rz > 0)
    assert both.sum(axis=(1, 2)).min() > 200, "the body must be visible"
    assert differ.sum() <= 0.01 * both.sum()
    assert np.abs(z[both] - rz[both]).max() < 1e-3
    assert (tri[both] == rtri[both]).mean() > 0.98
    assert set(np.unique(tri[z == 0])) == {-1}


@pytest.mark.parametrize("smooth,path", [(False, PATHS[0]), (True, PATHS[0]), (True, PATHS[3])],
                         ids=["pixel", "smooth", "smooth-compute-fragment"])
def test_depth_scores_match_reference(ctx, body, rng, smooth, path):
    skel, dofs, kin, mesh = body
    cam = cams()[0]
    truth = random_poses(body, rng, 1)
    obs, _ = ref_render(mesh, kin.skinning_matrices(truth), cam)
    obs = obs[0] + rng.normal(size=obs[0].shape) * 0.01 * (obs[0] > 0)
    obs[rng.random(obs.shape) < 0.03] = 0.0  # dropouts
    S = kin.skinning_matrices(random_poses(body, rng, 12))
    params = DepthCostParams(smooth=smooth)
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, depth_params=params,
                       **path_kwargs(ctx, path)) as eng:
        eng.set_depth(0, obs)
        got = {}
        for red in ("mipmap", "compute"):
            eng.reduction, eng._auto_pending = red, False
            got[red] = eng.score(S, ["depth"])[:, 0]
    rz, _ = ref_render(mesh, S, cam)
    want = np.array([ref.depth_cost(rz[i], obs, scale=params.scale, c_model_only=params.c_model_only,
                                    c_obs_only=params.c_obs_only, smooth=smooth, penalty=params.penalty)
                     for i in range(len(S))])
    assert_close(got["mipmap"][:, 0], want, "depth/mipmap")
    assert_close(got["compute"][:, 0], want, "depth/compute")
    assert np.allclose(got["mipmap"], got["compute"], rtol=1e-4, atol=1e-3)
    assert np.all(got["mipmap"][:, 1:] == 0), "channels not asked for stay zero"
    assert np.ptp(want) > 10, "different poses must score differently"


@pytest.mark.parametrize("path", [PATHS[0], PATHS[2], PATHS[3], PATHS[4]], ids="-".join)
def test_silhouette_and_appearance_multi_camera(ctx, body, rng, path):
    skel, dofs, kin, mesh = body
    cs = cams(4, size=TILE, kind="colour")
    truth = random_poses(body, rng, 1)
    S = kin.skinning_matrices(random_poses(body, rng, 8))
    tri_bits = rng.integers(1, 2**32, size=(mesh.n_faces, 3), dtype=np.uint64).astype(np.uint32)
    with ScoringEngine(ctx, mesh, skel.n_joints, cs, tile=TILE, **path_kwargs(ctx, path)) as eng:
        obs = []
        for c, cam in enumerate(cs):
            tz, _ = ref_render(mesh, kin.skinning_matrices(truth), cam)
            fg = tz[0] > 0
            block = np.zeros_like(fg)
            block[: TILE // 3, : TILE // 2] = True  # an occluder's polygon
            bits = (1 << rng.integers(0, 32, size=(TILE, TILE, 3))).astype(np.uint32)
            eng.set_masks(c, fg, block)
            eng.set_appearance(c, bits, tri_bits)
            obs.append((fg, block, bits))
        out = eng.score(S, ["silhouette", "appearance"])
    assert out.shape == (8, 4, 4)
    for c, cam in enumerate(cs):
        rz, rtri = ref_render(mesh, S, cam)
        fg, block, bits = obs[c]
        sil = np.array([ref.silhouette_cost(rz[i] > 0, fg, block) for i in range(len(S))])
        app = np.array([ref.appearance_score(rtri[i], bits, tri_bits, block) for i in range(len(S))])
        assert_close(out[:, c, 1], sil, f"silhouette cam{c}")
        assert_close(out[:, c, 2], app, f"appearance cam{c}")
        assert np.ptp(sil) > 5 and app.max() > 10


def test_reduce_groups_give_the_same_sums(ctx, body, rng):
    """Both work groups of the compute reduction (``reduce_group``) give the CPU twin's counts
    exactly (silhouette and appearance on four cameras, with an occluder) and its depth costs to
    float rounding; other poses give other sums."""
    if ctx.version_code < 430:
        pytest.skip("the compute reduction needs OpenGL 4.3")
    skel, dofs, kin, mesh = body
    cs = cams(4, size=TILE, kind="colour")
    truth = kin.skinning_matrices(random_poses(body, rng, 1))
    S = kin.skinning_matrices(random_poses(body, rng, 10))
    tri_bits = rng.integers(1, 2**32, size=(mesh.n_faces, 3), dtype=np.uint64).astype(np.uint32)
    got, want = {}, {}
    with ScoringEngine(ctx, mesh, skel.n_joints, cs, tile=TILE, reduction="compute") as eng:
        for c, cam in enumerate(cs):
            fg = ref_render(mesh, truth, cam)[0][0] > 0
            block = np.zeros_like(fg)
            block[-TILE // 4:, TILE // 2:] = True
            bits = (1 << rng.integers(0, 32, size=(TILE, TILE, 3))).astype(np.uint32)
            eng.set_masks(c, fg, block)
            eng.set_appearance(c, bits, tri_bits)
            rz, rtri = ref_render(mesh, S, cam)
            want[c] = (np.array([ref.silhouette_cost(z > 0, fg, block) for z in rz]),
                       np.array([ref.appearance_score(t, bits, tri_bits, block) for t in rtri]))
        for group in ("wide", "narrow"):
            eng.reduce_group = group
            got[group] = eng.score(S, ["silhouette", "appearance"])
    np.testing.assert_array_equal(got["wide"], got["narrow"])  # counts: exact in any order
    for c in range(len(cs)):
        assert_close(got["narrow"][:, c, 1], want[c][0], f"silhouette cam{c}")
        assert_close(got["narrow"][:, c, 2], want[c][1], f"appearance cam{c}")
        assert np.ptp(want[c][0]) > 5 and np.ptp(want[c][1]) > 5
    cam = cams()[0]
    obs = ref_render(mesh, truth, cam)[0][0]
    params = DepthCostParams(smooth=True)
    depth = {}
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, depth_params=params,
                       reduction="compute") as eng:
        eng.set_depth(0, obs)
        for group in ("wide", "narrow"):
            eng.reduce_group = group
            depth[group] = eng.score(S, ["depth"])[:, 0, 0]
    rz, _ = ref_render(mesh, S, cam)
    want_z = np.array([ref.depth_cost(z, obs, scale=params.scale, c_model_only=params.c_model_only,
                                      c_obs_only=params.c_obs_only, smooth=True,
                                      penalty=params.penalty) for z in rz])
    np.testing.assert_allclose(depth["narrow"], depth["wide"], rtol=1e-5)  # the order of the sum
    assert_close(depth["narrow"], want_z, "depth/narrow")
    assert np.ptp(want_z) > 10


def test_model_channel_gives_silhouette_iou(ctx, body, rng):
    """Channel "model" (|M minus B|) with the XOR count gives the IoU the CPU twin counts
    directly, on both reductions; a different pose gives a different IoU."""
    skel, dofs, kin, mesh = body
    cs = cams(2, size=TILE, kind="colour")
    truth = random_poses(body, rng, 1)
    S = kin.skinning_matrices(np.concatenate([truth, random_poses(body, rng, 5)]))
    with ScoringEngine(ctx, mesh, skel.n_joints, cs, tile=TILE) as eng:
        obs = []
        for c, cam in enumerate(cs):
            tz, _ = ref_render(mesh, kin.skinning_matrices(truth), cam)
            fg = tz[0] > 0
            block = np.zeros_like(fg)
            block[-TILE // 4:, : TILE // 2] = True
            eng.set_masks(c, fg, block)
            obs.append((fg, block))
        got = {}
        for red in ("mipmap", "compute"):
            eng.reduction, eng._auto_pending = red, False
            got[red] = eng.score(S, ["silhouette", "model"])
        with pytest.raises(ValueError, match="share a slot"):
            eng.score(S, ["depth", "model"])
    assert np.allclose(got["mipmap"], got["compute"], rtol=1e-4, atol=1e-3)
    for c, cam in enumerate(cs):
        rz, _ = ref_render(mesh, S, cam)
        fg, block = obs[c]
        area = np.array([ref.model_area(rz[i], block) for i in range(len(S))])
        assert_close(got["compute"][:, c, 0], area, f"model cam{c}")
        f_px = np.count_nonzero(fg & ~block)
        iou = silhouette_iou(got["compute"][:, c, 0], f_px, got["compute"][:, c, 1])
        want = np.array([ref.silhouette_iou(rz[i], fg, block) for i in range(len(S))])
        assert np.abs(iou - want).max() < 0.02, (iou, want)
        assert iou[0] > 0.97 and iou[1:].min() < iou[0] - 0.05, iou
        # the one-sided shares: model on foreground and foreground covered
        got3 = np.stack(silhouette_overlap(got["compute"][:, c, 0], f_px,
                                           got["compute"][:, c, 1]))
        want3 = np.array([ref.silhouette_overlap(rz[i], fg, block) for i in range(len(S))]).T
        np.testing.assert_allclose(got3[0], iou)
        assert np.abs(got3 - want3).max() < 0.02, (got3, want3)
        assert got3[1:, 0].min() > 0.97 and got3[1:, 1:].min() < 0.92, got3


def test_silhouette_overlap_from_counts_and_from_masks():
    """IoU, model on foreground and foreground covered from the engine's counts (M, F, XOR)
    match the direct count of the CPU twin; an empty model or foreground gives NaN."""
    m = np.zeros((4, 5), bool)
    f = np.zeros((4, 5), bool)
    m[0, :4] = True        # 4 model pixels
    f[0, 1:5] = True       # 6 foreground pixels, 3 of them under the model
    f[1, :2] = True
    block = np.zeros_like(m)
    block[0, 1] = True     # one shared pixel ignored: M 3, F 5, both 2
    for bl, (M, F, both) in ((None, (4, 6, 3)), (block, (3, 5, 2))):
        want = (both / (M + F - both), both / M, both / F)
        np.testing.assert_allclose(ref.silhouette_overlap(m, f, bl), want)
        np.testing.assert_allclose(silhouette_overlap(M, F, M + F - 2 * both), want)
    assert ref.silhouette_iou(m, f) == pytest.approx(3 / 7)
    empty = np.zeros_like(m)
    iou, on_fg, covered = ref.silhouette_overlap(empty, f)
    assert iou == 0.0 and np.isnan(on_fg) and covered == 0.0
    iou, on_fg, covered = silhouette_overlap(np.array([0.0, 4.0]), 0.0, np.array([0.0, 4.0]))
    assert np.isnan(iou[0]) and iou[1] == 0.0 and np.isnan(covered).all()
    assert np.isnan(on_fg[0]) and on_fg[1] == 0.0


def test_observation_resampled_to_tile(ctx, body, rng):
    skel, dofs, kin, mesh = body
    cam = look_at_camera("tof", (0.3, 1.0, 3.0), (0, 0.9, 0), 176, 144, 40.0, kind="depth")
    truth = random_poses(body, rng, 1)
    obs, _ = ref_render(mesh, kin.skinning_matrices(truth), cam)
    S = kin.skinning_matrices(random_poses(body, rng, 4))
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE) as eng:
        eng.set_depth(0, obs[0])
        got = eng.score(S)[:, 0, 0]
    import cv2

    small = cv2.resize(obs[0].astype(np.float32), (TILE, TILE), interpolation=cv2.INTER_NEAREST_EXACT)
    st = cam.scaled(TILE, TILE)
    rz, _ = ref_render(mesh, S, st)
    want = np.array([ref.depth_cost(rz[i], small) for i in range(len(S))])
    assert_close(got, want, "resampled depth")


@pytest.mark.parametrize("path", PATHS, ids="-".join)
def test_tiles_are_clipped(ctx, body, path):
    """A candidate sticking out of its tile must not bleed into the neighbour tiles."""
    skel, dofs, kin, mesh = body
    cam = cams()[0]
    p = np.repeat(dofs.zero(skel)[None], 4, axis=0)
    p[0, 0] += 0.9   # half out of its tile to the right
    p[1, 1] += 0.9   # out of the top/bottom edge
    p[2, 2] += 30.0  # far behind the camera: nothing visible
    p[3, 0] -= 0.9
    S = kin.skinning_matrices(p)
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, **path_kwargs(ctx, path)) as eng:
        z, _ = eng.render_tiles(S)
    rz, _ = ref_render(mesh, S, cam)
    assert (z[2] > 0).sum() == 0
    for i in (0, 1, 3):
        assert 0 < (z[i] > 0).sum()
        assert abs(int((z[i] > 0).sum()) - int((rz[i] > 0).sum())) <= 0.02 * (rz[i] > 0).sum() + 2


def test_chunking_matches_single_batch(ctx, body, rng):
    skel, dofs, kin, mesh = body
    cam = cams()[0]
    obs, _ = ref_render(mesh, kin.skinning_matrices(random_poses(body, rng, 1)), cam)
    S = kin.skinning_matrices(random_poses(body, rng, 37))
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, max_texture=256) as small, \
            ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE) as big:
        assert small.max_batch == 16
        for e in (small, big):
            e.set_depth(0, obs[0])
        a, b = small.score(S), big.score(S)
    assert np.allclose(a, b, rtol=1e-5, atol=1e-3)
    assert small.evaluations == 37



def test_compute_reduction_reads_all_cameras_back_once(ctx, body, rng):
    """The compute reduction leaves each camera's sums in a slice of its own and reads them back
    once per call (the mipmap one once per camera): three cameras, 17 candidates (a partly
    filled 8x4 grid, whose unused tiles must not spill into the next camera's slice), each
    camera's depth cost against the CPU twin, and the cameras' observations differ so a slice
    read for the wrong camera would show."""
    skel, dofs, kin, mesh = body
    if ctx.version_code < 430:
        pytest.skip("the compute reduction needs OpenGL 4.3")
    cs = cams(3)
    truth = kin.skinning_matrices(random_poses(body, rng, 1))
    S = kin.skinning_matrices(random_poses(body, rng, 17))
    params = DepthCostParams()
    obs = [ref_render(mesh, truth, cam)[0][0] for cam in cs]
    # workers=0: the readbacks counted are this process's (a call this size would go to them)
    with ScoringEngine(ctx, mesh, skel.n_joints, cs, tile=TILE, depth_params=params,
                       workers=0) as eng:
        for c in range(len(cs)):
            eng.set_depth(c, obs[c])
        got, reads = {}, {}
        for red in ("mipmap", "compute"):
            eng.reduction, eng._auto_pending = red, False
            before = eng.readbacks
            got[red] = eng.score(S, ["depth"])[:, :, 0]
            reads[red] = eng.readbacks - before
    assert reads == {"mipmap": 3, "compute": 1}
    for c, cam in enumerate(cs):
        rz, _ = ref_render(mesh, S, cam)
        want = np.array([ref.depth_cost(rz[i], obs[c], scale=params.scale,
                                        c_model_only=params.c_model_only,
                                        c_obs_only=params.c_obs_only, smooth=params.smooth,
                                        penalty=params.penalty) for i in range(len(S))])
        assert_close(got["compute"][:, c], want, f"compute cam{c}")
        assert_close(got["mipmap"][:, c], want, f"mipmap cam{c}")
    assert np.abs(got["compute"][:, 0] - got["compute"][:, 1]).max() > 10

def test_partly_filled_grid_ignores_stale_tiles(ctx, body, rng):
    """17 candidates take an 8x4 grid of which only 3 rows are cleared, scored and reduced: a
    full batch of other poses on the same target before must not leak into their scores (both
    reductions, against the CPU twin)."""
    skel, dofs, kin, mesh = body
    cam = cams()[0]
    obs, _ = ref_render(mesh, kin.skinning_matrices(random_poses(body, rng, 1)), cam)
    full = kin.skinning_matrices(random_poses(body, rng, 32))
    S = kin.skinning_matrices(random_poses(body, rng, 17))
    assert grid_for(32, 64) == grid_for(17, 64) == (8, 4)
    params = DepthCostParams()
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, depth_params=params) as eng:
        eng.set_depth(0, obs[0])
        assert eng._used_height(17, 8) == 3 * TILE and eng._used_height(32, 8) == 4 * TILE
        got = {}
        for red in ("mipmap", "compute"):
            eng.reduction, eng._auto_pending = red, False
            eng.score(full, ["depth"])
            got[red] = eng.score(S, ["depth"])[:, 0, 0]
    rz, _ = ref_render(mesh, S, cam)
    want = np.array([ref.depth_cost(rz[i], obs[0], scale=params.scale,
                                    c_model_only=params.c_model_only, c_obs_only=params.c_obs_only,
                                    smooth=params.smooth, penalty=params.penalty)
                     for i in range(len(S))])
    assert_close(got["mipmap"], want, "partly filled grid/mipmap")
    assert_close(got["compute"], want, "partly filled grid/compute")
    assert np.ptp(want) > 10


def test_custom_cost_shader(ctx, body, rng, tmp_path):
    skel, dofs, kin, mesh = body
    cam = cams()[0]
    src = tmp_path / "absdiff.glsl"
    src.write_text(
        "float custom_cost(ivec2 pixel, ivec2 local) {\n"
        "    float zo = texelFetch(obs_z, local, 0).r;\n"
        "    float zm = texelFetch(model_z, pixel, 0).r;\n"
        "    return (zo > 0.0 && zm > 0.0) ? min(abs(zo - zm), 0.5) : 0.0;\n"
        "}\n")
    obs, _ = ref_render(mesh, kin.skinning_matrices(random_poses(body, rng, 1)), cam)
    S = kin.skinning_matrices(random_poses(body, rng, 5))
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, custom=CustomCost(str(src))) as eng:
        eng.set_depth(0, obs[0])
        got = eng.score(S, ["custom"])[:, 0, 3]
    rz, _ = ref_render(mesh, S, cam)
    both = (rz > 0) & (obs > 0)
    want = np.where(both, np.minimum(np.abs(obs - rz), 0.5), 0).sum(axis=(1, 2))
    assert np.allclose(got, want, rtol=0.02, atol=0.05)
    assert np.ptp(want) > 0.1


def test_bad_input_gives_clear_errors(ctx, body, tmp_path):
    skel, dofs, kin, mesh = body
    cam = cams()[0]
    S = kin.skinning_matrices(dofs.zero(skel))
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE) as eng:
        with pytest.raises(ValueError, match="no observation"):
            eng.score(S)
        eng.set_depth(0, np.zeros((TILE, TILE)))
        assert eng.score(S[:0]).shape == (0, 1, 4)
        with pytest.raises(ValueError, match="shape"):
            eng.score(S[:, :3])
        bad = S.copy()
        bad[0, 0, 0, 0] = np.nan
        with pytest.raises(ValueError, match="NaN"):
            eng.score(bad)
        with pytest.raises(ValueError, match="size 10x12"):
            eng.set_depth(0, np.zeros((12, 10)))
        with pytest.raises(ValueError, match="unknown"):
            eng.score(S, ["colour"])
        with pytest.raises(ValueError, match="camera index"):
            eng.set_depth(3, np.zeros((TILE, TILE)))
    with pytest.raises(ValueError, match="power of two"):
        ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=48)
    with pytest.raises(ShaderError, match="not found"):
        ScoringEngine(ctx, mesh, skel.n_joints, [cam], custom=CustomCost(str(tmp_path / "nope.glsl"))).score(
            S, ["custom"])
    broken = tmp_path / "broken.glsl"
    broken.write_text("float custom_cost(ivec2 pixel, ivec2 local) {\n    return undefined_name;\n}\n")
    eng = ScoringEngine(ctx, mesh, skel.n_joints, [cam], custom=CustomCost(str(broken)))
    eng.set_depth(0, np.zeros((TILE, TILE)))
    with pytest.raises(ShaderError, match="undefined_name"):
        eng.score(S, ["custom"])
    eng.release()
    eng.release()  # idempotent
    with pytest.raises(RuntimeError, match="released"):
        eng.score(S)


def _rss_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def test_memory_flat_over_10000_batches(ctx, body):
    skel, dofs, kin, mesh = body
    cam = cams(size=16)[0]
    S = kin.skinning_matrices(dofs.zero(skel))
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=16, reduction="compute") as eng:
        eng.set_depth(0, np.zeros((16, 16)))
        for i in range(10_000):
            eng.score(S)
            if i == 1000:
                base = _rss_mb()
        grown = _rss_mb() - base
    for _ in range(50):  # engines come and go without leaking GL objects
        ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=16).release()
    assert grown < 20, f"memory grew by {grown:.1f} MB over 9000 batches"


def test_set_camera_replaces_view_and_needs_new_observation(ctx, body, rng):
    skel, dofs, kin, mesh = body
    a, b = cams(2)
    S = kin.skinning_matrices(random_poses(body, rng, 3))
    with ScoringEngine(ctx, mesh, skel.n_joints, [a], tile=TILE) as eng:
        eng.set_depth(0, np.zeros((TILE, TILE)))
        za, _ = eng.render_tiles(S)
        eng.set_camera(0, b)
        with pytest.raises(ValueError, match="no observation"):
            eng.score(S)
        zb, _ = eng.render_tiles(S)
    rz, _ = ref_render(mesh, S, b)
    assert not np.array_equal(za > 0, zb > 0)
    assert np.abs((zb > 0).sum() - (rz > 0).sum()) <= 0.02 * (rz > 0).sum() + 2


def test_info_reports_backend_and_reduction():
    import json
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "gltrack", "info", "--json"], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    info = json.loads(res.stdout)
    assert info["backend"] in ("egl", "osmesa") and info["version_code"] >= 330
    assert info["reduction"] in ("mipmap", "compute")
    assert info["skinning"] in ("vertex", "compute") and info["tile_clip"] in ("distance", "fragment")
    assert info["skinning_4_cameras"] in ("vertex", "compute")
    assert info["triangle_ids"] in ("primitive", "provoking")
    assert info["reduce_group"] in ("wide", "narrow")
    assert info["engine_workers"] >= 0
    assert info["fk"] in ("cpu", "gpu")
    assert info["max_texture_size"] >= 2048


def test_backend_choice_is_validated(monkeypatch):
    from gltrack.gl.context import GLContextError, create_context

    monkeypatch.setenv("GLTRACK_GL_BACKEND", "x11")
    with pytest.raises(GLContextError, match="unknown GL backend"):
        create_context()
    monkeypatch.setenv("GLTRACK_GL_BACKEND", "egl")
    monkeypatch.setenv("GLTRACK_EGL_DEVICE", "zero")
    with pytest.raises(GLContextError, match="GLTRACK_EGL_DEVICE"):
        create_context()


def test_skinning_paths_give_the_same_images(ctx, body, rng):
    """Compute-pass skinning is the vertex shader's arithmetic on another stage: the same tiles."""
    if ctx.version_code < 430:
        pytest.skip("compute skinning needs OpenGL 4.3")
    skel, dofs, kin, mesh = body
    cam = cams()[0]
    S = kin.skinning_matrices(random_poses(body, rng, 5))
    tiles = {}
    for sk in ("vertex", "compute"):
        with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, skinning=sk) as eng:
            tiles[sk] = eng.render_tiles(S)
    assert np.allclose(tiles["vertex"][0], tiles["compute"][0], atol=1e-5)
    assert np.mean(tiles["vertex"][1] == tiles["compute"][1]) > 0.999
    # and the output follows the input: another pose, other tiles
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, skinning="compute") as eng:
        other = eng.render_tiles(kin.skinning_matrices(random_poses(body, rng, 5)))
    assert not np.allclose(other[0], tiles["compute"][0])


def test_triangle_id_paths_give_the_same_ids(ctx, body, rng):
    """gl_PrimitiveID and the provoking-vertex layout: the same depths and triangle ids, up to
    the z-order of a few pixels where two triangles meet (the layout rotates a triangle's
    corners, which changes the last bits of its interpolated depth), on both skinning paths."""
    skel, dofs, kin, mesh = body
    cam = cams()[0]
    S = kin.skinning_matrices(random_poses(body, rng, 6))
    tiles = {}
    for path in PATHS:
        with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, **path_kwargs(ctx, path)) as eng:
            tiles[path] = eng.render_tiles(S)
    z0, tri0 = tiles[PATHS[4]]  # vertex skinning, clip distances, gl_PrimitiveID: the old path
    assert (z0 > 0).sum() > 1000
    for path, (z, tri) in tiles.items():
        assert np.array_equal(z > 0, z0 > 0), path
        assert np.abs(z - z0).max() < 1e-3, path
        assert np.mean(tri[z0 > 0] == tri0[z0 > 0]) > 0.999, path
    # and the ids follow the pose
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, triangle_ids="provoking") as eng:
        _, other = eng.render_tiles(kin.skinning_matrices(random_poses(body, rng, 6)))
    assert np.mean(other == tiles[PATHS[0]][1]) < 0.95


def test_engine_path_choice():
    from gltrack.render.engine import (choose_reduce_group, choose_skinning, choose_tile_clip,
                                       choose_triangle_ids)

    llvmpipe, h100 = "llvmpipe (LLVM 15.0.6, 256 bits)", "NVIDIA H100 80GB HBM3/PCIe/SSE2"
    assert choose_skinning(llvmpipe, 450) == "vertex"
    assert choose_skinning(llvmpipe, 450, 2) == "vertex"
    assert choose_skinning(llvmpipe, 450, 4) == "compute"  # one skinning pass for all cameras
    assert choose_skinning(llvmpipe, 330, 4) == "vertex"
    assert choose_skinning(h100, 460) == "compute"
    assert choose_skinning(h100, 330) == "vertex"  # no compute shaders before GL 4.3
    assert choose_triangle_ids(llvmpipe) == "provoking"
    assert choose_triangle_ids(h100) == "primitive"
    assert choose_tile_clip(llvmpipe) == "distance"
    assert choose_tile_clip(h100) == "fragment"
    assert choose_reduce_group(llvmpipe) == "narrow"
    assert choose_reduce_group(h100) == "wide"


@pytest.mark.parametrize("env,attr,bad,good", [
    ("GLTRACK_SKINNING", "skinning", "gpu", "vertex"),
    ("GLTRACK_TILE_CLIP", "tile_clip", "scissor", "fragment"),
    ("GLTRACK_TRIANGLE_IDS", "triangle_ids", "geometry", "primitive"),
    ("GLTRACK_REDUCE_GROUP", "reduce_group", "huge", "wide")])
def test_engine_path_env_is_validated(ctx, body, monkeypatch, env, attr, bad, good):
    skel, dofs, kin, mesh = body
    monkeypatch.setenv(env, bad)
    with pytest.raises(ValueError, match=env):
        ScoringEngine(ctx, mesh, skel.n_joints, cams(), tile=TILE)
    monkeypatch.setenv(env, good)
    with ScoringEngine(ctx, mesh, skel.n_joints, cams(), tile=TILE) as eng:
        assert getattr(eng, attr) == good


@pytest.mark.parametrize("preset", ["full", "25", "upper"])
def test_gpu_forward_kinematics_matches_cpu_twin(ctx, body, rng, preset):
    """shaders/fk.comp against Kinematics.skinning_matrices, with Euler orders that differ
    between joints, and the scores of score_poses against score on the CPU's matrices."""
    if ctx.version_code < 430:
        pytest.skip("GPU forward kinematics needs OpenGL 4.3")
    from gltrack.body.skeleton import Skeleton

    skel0, _, _, mesh = body
    orders = tuple(rng.choice(["ZXY", "YXZ", "ZYX", "XYZ", "XZY", "YZX"]) for _ in skel0.orders)
    skel = Skeleton(skel0.names, skel0.parents, skel0.offsets, skel0.ends, orders)
    dofs = make_dofs(skel, preset)
    kin = Kinematics(skel, dofs)
    P = dofs.zero(skel) + rng.normal(size=(20, dofs.size)) * 0.5
    P[:, :3] = dofs.zero(skel)[:3] + rng.normal(size=(20, 3)) * 0.05
    P[0, 5] = 10.0  # outside the limits: clamped on both sides
    cam = cams()[0]
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, fk="gpu") as eng:
        eng.set_kinematics(kin)
        got = eng.gpu_skinning(P)
        want = kin.skinning_matrices(P, dtype=np.float64)
        assert np.abs(got - want).max() < 2e-5
        obs, _ = ref_render(mesh, want[:1], cam)
        eng.set_depth(0, obs[0])
        a = eng.score_poses(P, ["depth"])[:, 0, 0]
        b = eng.score(want, ["depth"])[:, 0, 0]
        assert_close(a, b, "GPU FK scores")
        assert np.ptp(a) > 10, "different poses must score differently"
        moved = P.copy()
        moved[:, 0] += 0.2
        assert np.abs(eng.gpu_skinning(moved) - got).max() > 0.1


def test_score_poses_on_the_cpu_is_score_of_the_cpu_matrices(ctx, body, rng):
    skel, dofs, kin, mesh = body
    cam = cams()[0]
    P = random_poses(body, rng, 9)
    with ScoringEngine(ctx, mesh, skel.n_joints, [cam], tile=TILE, fk="cpu") as eng:
        with pytest.raises(RuntimeError, match="set_kinematics"):
            eng.score_poses(P)
        eng.set_kinematics(kin)
        obs, _ = ref_render(mesh, kin.skinning_matrices(P[:1]), cam)
        eng.set_depth(0, obs[0])
        assert np.array_equal(eng.score_poses(P), eng.score(kin.skinning_matrices(P)))


def test_fk_env_is_validated(ctx, body, monkeypatch):
    skel, dofs, kin, mesh = body
    monkeypatch.setenv("GLTRACK_FK", "cuda")
    with pytest.raises(ValueError, match="GLTRACK_FK"):
        ScoringEngine(ctx, mesh, skel.n_joints, cams(), tile=TILE)


# ------------------------------------------------------------------ worker processes
def test_worker_count_choice(monkeypatch):
    from gltrack.render.engine import resolve_workers
    from gltrack.render.workers import MAX_WORKERS, choose_workers, core_budget

    assert choose_workers(True, 2) == 2 and choose_workers(True, 64) == MAX_WORKERS
    assert choose_workers(True, 1) == 0 and choose_workers(False, 16) == 0  # a GPU draws alone
    llvmpipe, h100 = "llvmpipe (LLVM 15.0.6, 256 bits)", "NVIDIA H100 80GB HBM3/PCIe/SSE2"
    monkeypatch.delenv("GLTRACK_ENGINE_WORKERS", raising=False)
    assert resolve_workers("auto", h100) == 0
    # LP_NUM_THREADS is the process's share of the cores (gltrack batch sets it per job)
    monkeypatch.setenv("LP_NUM_THREADS", "1")
    assert core_budget() == 1 and resolve_workers("auto", llvmpipe) == 0
    monkeypatch.setenv("LP_NUM_THREADS", "100000")
    assert core_budget() == len(os.sched_getaffinity(0))
    monkeypatch.delenv("LP_NUM_THREADS")
    assert resolve_workers("auto", llvmpipe, "fastest") == 0  # it times its choice here
    assert resolve_workers(3, h100) == 3 and resolve_workers("0", llvmpipe) == 0
    with pytest.raises(ValueError, match="workers must be"):
        resolve_workers(-1, llvmpipe)
    monkeypatch.setenv("GLTRACK_ENGINE_WORKERS", "many")
    with pytest.raises(ValueError, match="GLTRACK_ENGINE_WORKERS"):
        resolve_workers("auto", llvmpipe)
    monkeypatch.setenv("GLTRACK_ENGINE_WORKERS", "2")
    assert resolve_workers("auto", h100) == 2 and resolve_workers(0, llvmpipe) == 0
    assert resolve_workers("auto", llvmpipe, "fastest") == 0


def test_which_calls_go_to_the_workers():
    """A call goes to the workers when each share gets a candidate and enough candidates x
    cameras: from 4 candidates with 4 cameras and 2 workers, from 16 with one camera (the
    depth climb's calls of ~55); never without workers."""
    from gltrack.render.engine import use_workers

    assert [use_workers(n, 4, 2) for n in (1, 3, 4, 91)] == [False, False, True, True]
    assert not use_workers(15, 1, 2) and use_workers(16, 1, 2) and use_workers(55, 1, 2)
    assert not use_workers(1, 16, 2), "two shares need two candidates"
    assert use_workers(2, 16, 2)
    assert not use_workers(10_000, 4, 0)
    assert not use_workers(7, 4, 4) and use_workers(8, 4, 4) and use_workers(2, 4, 1)


def _colour_engine(ctx, body, rng, cs, workers):
    skel, dofs, kin, mesh = body
    eng = ScoringEngine(ctx, mesh, skel.n_joints, cs, tile=TILE, workers=workers)
    truth = kin.skinning_matrices(random_poses(body, rng, 1))
    tri_bits = rng.integers(1, 2**32, size=(mesh.n_faces, 3), dtype=np.uint64).astype(np.uint32)
    for c, cam in enumerate(cs):
        fg = ref_render(mesh, truth, cam)[0][0] > 0
        block = np.zeros_like(fg)
        block[: TILE // 4, : TILE // 2] = True
        eng.set_masks(c, fg, block)
        eng.set_appearance(c, (1 << rng.integers(0, 32, size=(TILE, TILE, 3))).astype(np.uint32),
                           tri_bits)
    return eng


def test_workers_score_as_this_process_does(ctx, body, rng):
    """Two worker processes score a 4-camera batch (silhouette, appearance) as the engine does
    alone, and follow new masks, a new camera and pose parameters; small calls stay here.

    Not bit for bit: a candidate's pixels depend on its tile's place in the grid (float rounding
    of the tile transform moves an edge pixel), and a share has a smaller grid. Reordering one
    batch does the same."""
    from gltrack.render import workers as W

    W.close_shared_pool()  # a pool of two, whatever earlier tests started
    skel, dofs, kin, mesh = body
    cs = cams(4, size=TILE, kind="colour")
    P = random_poses(body, rng, 138)  # two shares of 69 candidates x 4 cameras
    S = kin.skinning_matrices(P)
    chans = ["silhouette", "appearance"]
    # both engines get the same random observations
    one = _colour_engine(ctx, body, np.random.default_rng(7), cs, workers=0)
    two = _colour_engine(ctx, body, np.random.default_rng(7), cs, workers=2)
    with one, two:
        small = two.score(S[:3], chans)
        assert W.current_pool() is None, "3 x 4 < 2 x WORKER_MIN_WORK: it stays in this process"
        np.testing.assert_array_equal(small, one.score(S[:3], chans))
        steps = []
        steps.append((one.score(S, chans), two.score(S, chans)))
        pool = W.current_pool()
        assert pool is not None and len(pool) == 2 and two._on_workers == pool.generation
        fg = ref_render(mesh, kin.skinning_matrices(P[:1]), cs[0])[0][0] > 0
        for e in (one, two):
            e.set_masks(0, fg)  # the first candidate's own silhouette, no occluder
        steps.append((one.score(S, chans), two.score(S, chans)))
        moved = look_at_camera("moved", (0.5, 2.0, 2.6), (0, 0.8, 0), TILE, TILE, 45.0, kind="colour")
        for e in (one, two):
            e.set_camera(1, moved)
            e.set_masks(1, fg)
        steps.append((one.score(S, ["silhouette"]), two.score(S, ["silhouette"])))
        for e in (one, two):
            e.set_kinematics(kin)
        # (camera 1 has no colour bits since it moved: silhouettes only from here)
        steps.append((one.score_poses(P, ["silhouette"]), two.score_poses(P, ["silhouette"])))
        assert two.evaluations == one.evaluations == 3 + 4 * len(S)
    for k, (a, b) in enumerate(steps):
        for c in range(4):
            for slot in (1, 2):
                assert_close(b[:, c, slot], a[:, c, slot], f"step {k} camera {c} slot {slot}")
    # the new mask reached the workers: candidate 0 now fits camera 0 to a few edge pixels
    assert steps[1][1][0, 0, 1] < 0.1 * steps[0][1][0, 0, 1]
    assert not np.allclose(steps[2][1][:, 1, 1], steps[1][1][:, 1, 1]), "and the new camera"
    # the workers' scores are those of the CPU twin too
    rz, _ = ref_render(mesh, S, cs[0])
    assert_close(steps[1][1][:, 0, 1], np.array([ref.silhouette_cost(z > 0, fg, None) for z in rz]),
                 "workers vs reference")


def test_dead_worker_falls_back_to_this_process(ctx, body, rng, caplog):
    """A worker that dies costs a warning, not the run: the engine scores the call itself and
    keeps doing so, the pool is stopped, and the next engine that wants workers gets a new one."""
    import logging

    from gltrack.render import workers as W

    W.close_shared_pool()
    skel, dofs, kin, mesh = body
    cs = cams(2, size=TILE, kind="colour")
    S = kin.skinning_matrices(random_poses(body, rng, 160))
    one = _colour_engine(ctx, body, np.random.default_rng(3), cs, workers=0)
    two = _colour_engine(ctx, body, np.random.default_rng(3), cs, workers=2)
    with one:
        want = one.score(S, ["silhouette"])
    two.score(S, ["silhouette"])
    old = W.current_pool()
    procs = list(old._procs)
    procs[0].kill()
    procs[0].wait()
    with caplog.at_level(logging.WARNING, logger="gltrack.render.engine"):
        got = two.score(S, ["silhouette"])
    assert "engine workers failed" in caplog.text
    assert two.workers == 0 and W.current_pool() is None
    assert all(p.poll() is not None for p in procs), "the surviving worker was stopped"
    np.testing.assert_array_equal(got, want)  # scored here, as the one-process engine does
    two.release()
    with _colour_engine(ctx, body, np.random.default_rng(3), cs, workers=2) as three:
        again = three.score(S, ["silhouette"])
        assert W.current_pool().generation > old.generation and three._on_workers
    for c in range(len(cs)):
        assert_close(again[:, c, 1], want[:, c, 1], f"a new pool, camera {c}")


def test_one_pool_serves_every_engine(ctx, body, rng):
    """Engines share the process's pool (its size is the core budget, not engines x cores);
    releasing one drops its copies and leaves the pool to the others; closing the pool stops
    the processes."""
    from gltrack.render import workers as W

    W.close_shared_pool()
    skel, dofs, kin, mesh = body
    S = kin.skinning_matrices(random_poses(body, rng, 128))
    a = _colour_engine(ctx, body, rng, cams(1, size=TILE, kind="colour"), workers=2)
    b = _colour_engine(ctx, body, rng, cams(1, size=TILE, kind="colour"), workers=2)
    a.score(S, ["silhouette"])
    pool = W.current_pool()
    want_b = b.score(S, ["silhouette"])
    assert W.current_pool() is pool and a._on_workers == b._on_workers == pool.generation
    procs = list(pool._procs)
    a.release()
    assert W.current_pool() is pool and all(p.poll() is None for p in procs)
    np.testing.assert_array_equal(b.score(S, ["silhouette"]), want_b)  # b's copy is still there
    b.release()
    W.close_shared_pool()
    assert all(p.poll() is not None for p in procs)
