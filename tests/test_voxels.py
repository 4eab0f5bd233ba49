"""Hierarchical shape-from-silhouette voxels against an analytic sphere and brute force."""
import dataclasses

import numpy as np
import pytest

from gltrack.camera import look_at_camera
from gltrack.observe.voxels import carve, carve_brute_force, voxel_colours

CENTRE = np.array([0.1, 1.0, -0.05])
RADIUS = 0.35
BOUNDS = (-0.5, 0.4, -0.65, 0.7, 1.6, 0.55)


def _cameras():
    cams = []
    for i, (az, el) in enumerate([(0.3, 0.4), (2.0, 0.2), (3.6, 0.5), (5.0, 1.2)]):
        eye = CENTRE + 3.0 * np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
        cams.append(look_at_camera(f"cam{i}", eye, CENTRE, 120, 100, 40))
    return cams


def _sphere_mask(cam):
    """Exact per-pixel ray/sphere test (independent of the carving code)."""
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, float)], -1)
    d = rays @ cam.R  # camera -> world directions (R^T r)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    oc = CENTRE - cam.center
    along = d @ oc
    dist2 = oc @ oc - along ** 2
    return (dist2 <= RADIUS ** 2) & (along > 0)


@pytest.fixture(scope="module")
def scene():
    cams = _cameras()
    return cams, [_sphere_mask(c) for c in cams]


def _hull_volume_mc(cams, masks, rng, n=200_000):
    """Monte-Carlo volume of the visual hull: a point is in it if it projects onto
    foreground in every camera (pixel under its projection)."""
    lo, hi = np.array(BOUNDS[:3]), np.array(BOUNDS[3:])
    X = lo + rng.random((n, 3)) * (hi - lo)
    inside = np.ones(n, bool)
    for c, m in zip(cams, masks):
        px = np.floor(c.project(X) + 0.5).astype(int)
        ok = (px[:, 0] >= 0) & (px[:, 0] < c.width) & (px[:, 1] >= 0) & (px[:, 1] < c.height)
        inside &= ok
        inside[ok] &= m[px[ok, 1], px[ok, 0]]
    return inside.mean() * np.prod(hi - lo)


def test_sphere_volume(scene, rng):
    cams, masks = scene
    vox = carve(cams, masks, BOUNDS, base=10, max_depth=3)
    true = 4 / 3 * np.pi * RADIUS ** 3
    # four views: the visual hull is a little larger than the sphere, never much smaller
    assert 0.97 * true < vox.volume < 1.3 * true, (vox.volume, true)
    # and it matches an independent Monte-Carlo estimate of the same hull within 5 %
    mc = _hull_volume_mc(cams, masks, rng)
    assert abs(vox.volume - mc) < 0.05 * mc, (vox.volume, mc)
    # every voxel centre lies near the sphere
    r = np.linalg.norm(vox.centers - CENTRE, axis=1)
    assert r.max() < 1.35 * RADIUS
    c = (vox.centers * vox.volumes[:, None]).sum(0) / vox.volume
    assert np.linalg.norm(c - CENTRE) < 0.02


def test_coarse_to_fine_equals_brute_force(scene):
    cams, masks = scene
    volumes = []
    for tol in (0, 1):
        h = carve(cams, masks, BOUNDS, base=5, max_depth=3, tolerance=tol)
        tests = carve.last_stats["classifications"]
        b = carve_brute_force(cams, masks, BOUNDS, base=5, max_depth=3, tolerance=tol)
        A = {tuple(r) for r in h.at_level(3)}
        B = {tuple(r) for r in b.ijk}
        assert A == B and len(A) > 100
        assert np.isclose(h.volume, b.volume)
        assert len(h) < len(b)  # big inner voxels kept whole
        assert tests < 0.5 * (5 * 8) ** 3 * len(cams)
        volumes.append(h.volume)
    assert volumes[1] > volumes[0]  # ignoring one camera's "background" keeps more


def test_block_boxes_are_each_voxels_own_boxes(rng):
    """block_boxes (each lattice corner projected once, the extremes taken per axis) against
    pixel_boxes of every voxel's own eight corners, with lens distortion and voxels behind
    the camera; the coarse grid as one block and the octants of split voxels."""
    from gltrack.observe.voxels import _first_block, _grid, _octants, block_boxes, pixel_boxes

    cam = look_at_camera("c", np.array([0.3, 1.2, 2.0]), CENTRE, 120, 100, 50)
    cam = dataclasses.replace(cam, dist=np.array([-0.2, 0.05, 0.001, -0.002, 0.0]))
    # a volume the camera stands inside: some voxels lie (partly) behind it
    origin, size0, ijk = _grid((-0.6, 0.3, -0.7, 0.8, 1.7, 2.6), 6)
    blocks, extent = _first_block(ijk)
    for level in range(3):
        size = size0 / 2 ** level
        got = block_boxes(cam, origin, size, blocks, extent, True)
        ref = pixel_boxes(cam, origin + ijk * size, np.full(len(ijk), size), True)
        np.testing.assert_array_equal(got[0], ref[0])
        assert 0 < got[0].sum() < len(ijk)
        for a, b in zip(got[1:], ref[1:]):
            f = got[0]
            assert np.abs(a[f] - b[f]).max() <= 1  # a corner on a pixel edge may round apart
            assert np.mean(a[f] == b[f]) > 0.999
        split = rng.choice(len(ijk), size=min(40, len(ijk)), replace=False)
        ijk, blocks, extent = _octants(ijk[split])
    still = block_boxes(cam, origin, size, blocks, extent, True)
    moved = block_boxes(cam, origin + 0.05, size, blocks, extent, True)
    assert np.any(moved[1] != still[1])


def test_points_split_and_colours(scene):
    cams, masks = scene
    vox = carve(cams, masks, BOUNDS, base=8, max_depth=2)
    pts, vol = vox.points(max_size=0.05)
    assert np.isclose(vol.sum(), vox.volume) and len(pts) > len(vox)
    assert np.all(vol ** (1 / 3) <= 0.05 + 1e-9)
    imgs = [np.where(m[..., None], np.array([10, 200, 30], np.uint8), 0).astype(np.uint8)
            for m in masks]
    col = voxel_colours(vox, cams, imgs)
    assert col.shape == (len(vox), 3)
    assert np.allclose(np.median(col, axis=0), [10, 200, 30], atol=1)
    with_col = carve(cams, masks, BOUNDS, base=8, max_depth=2, images=imgs)
    assert np.array_equal(with_col.colour, col)


def test_empty_masks_and_bad_input(scene):
    cams, masks = scene
    empty = [np.zeros_like(m) for m in masks]
    assert len(carve(cams, empty, BOUNDS, base=4, max_depth=2)) == 0
    with pytest.raises(ValueError, match="bounds"):
        carve(cams, masks, (0, 0, 0, -1, 1, 1))
    with pytest.raises(ValueError, match="mask"):
        carve(cams, [m[:10] for m in masks], BOUNDS)
    with pytest.raises(ValueError, match="tolerance"):
        carve(cams, masks, BOUNDS, tolerance=4)
