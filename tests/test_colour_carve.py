"""Colour-statistics voxel carving (Caillette 2008 sec. 6.1) on synthetic camera images.

The images are built here in numpy by exact per-pixel ray casting (independent of the carving
code): a uniformly coloured sphere over a smooth, colourful, noisy background texture.
"""
import cv2
import numpy as np
import pytest
from scipy.stats import chi2

from gltrack.camera import look_at_camera
from gltrack.observe.background import YuvBackground
from gltrack.observe.colour_carve import carve_colour, chi2_threshold_poly
from gltrack.observe.voxels import carve

CENTRE = np.array([0.1, 1.0, -0.05])
RADIUS = 0.3
HALF = 0.6
BOUNDS = tuple(CENTRE - HALF) + tuple(CENTRE + HALF)
OBJECT_BGR = np.array([40.0, 70.0, 190.0])
NOISE = 3.0  # grey levels, per BGR channel
N_TRAIN = 24
# a floor patch under the sphere where a shadow falls
SHADOW_LO = CENTRE + np.array([-0.55, -0.58, -0.55])
SHADOW_HI = CENTRE + np.array([0.55, -0.50, 0.55])


def _cameras(w=160, h=120):
    cams = []
    for i, (az, el) in enumerate([(0.3, 0.4), (2.0, 0.25), (3.6, 0.5), (5.0, 0.9)]):
        eye = CENTRE + 3.0 * np.array([np.cos(el) * np.sin(az), np.sin(el),
                                       np.cos(el) * np.cos(az)])
        cams.append(look_at_camera(f"cam{i}", eye, CENTRE, w, h, 40))
    return cams


def _rays(cam):
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    r = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, float)], -1)
    d = r @ cam.R  # camera -> world directions (R^T r)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _sphere_mask(cam, centre=CENTRE):
    d = _rays(cam)
    oc = centre - cam.center
    along = d @ oc
    return (oc @ oc - along ** 2 <= RADIUS ** 2) & (along > 0)


def _box_mask(cam, lo, hi):
    """Pixels whose ray crosses the axis-aligned box (slab test)."""
    d = _rays(cam)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - cam.center) / d
        t1 = (hi - cam.center) / d
    tmin = np.nanmax(np.minimum(t0, t1), axis=-1)
    tmax = np.nanmin(np.maximum(t0, t1), axis=-1)
    return (tmax >= np.maximum(tmin, 0))


def _texture(cam, rng):
    """Smooth, saturated colour texture (BGR float, 30..225)."""
    small = rng.uniform(30, 225, (cam.height // 10 + 2, cam.width // 10 + 2, 3))
    return cv2.resize(small, (cam.width, cam.height), interpolation=cv2.INTER_CUBIC).clip(30, 225)


def _noisy(img, rng):
    return np.clip(np.rint(img + rng.normal(0, NOISE, img.shape)), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(7)
    cams = _cameras()
    tex = [_texture(c, rng) for c in cams]
    bgs = [YuvBackground.fit([_noisy(t, rng) for _ in range(N_TRAIN)]) for t in tex]
    return cams, tex, bgs


def _frame(cams, tex, rng, *, centre=CENTRE, sphere=True, shadow=False):
    imgs, masks = [], []
    for c, t in zip(cams, tex):
        img = t.copy()
        if shadow:
            img[_box_mask(c, SHADOW_LO, SHADOW_HI)] *= 0.9
        m = _sphere_mask(c, centre) if sphere else np.zeros((c.height, c.width), bool)
        img[m] = OBJECT_BGR
        imgs.append(_noisy(img, rng))
        masks.append(m)
    return imgs, masks


def _centroid(vox):
    return (vox.centers * vox.volumes[:, None]).sum(0) / vox.volume


# ------------------------------------------------------------------------------- thresholds
@pytest.mark.parametrize("k_max, bound", [(30, 0.03), (278, 0.07)])
def test_threshold_polynomial_matches_chi2(k_max, bound):
    poly = chi2_threshold_poly(0.99, k_max)
    k = np.arange(1, k_max + 1)
    exact = chi2.ppf(0.99, 3 * k)
    rel = np.abs(poly(k) / exact - 1)
    # measured: 0.0266 (k <= 30) and 0.0683 (k <= 278, a 320x240 image)
    assert rel.max() < bound, rel.max()
    assert poly.order == 2
    # an ordinary least-squares quadratic is far worse at small k, where most voxels are
    ls = np.polyval(np.polyfit(k, exact, 2), k)
    assert np.abs(ls / exact - 1).max() > 2 * rel.max()
    # alpha matters
    assert np.all(chi2_threshold_poly(0.9, k_max)(k) < poly(k))


def test_threshold_polynomial_rejects_bad_input():
    with pytest.raises(ValueError, match="alpha"):
        chi2_threshold_poly(1.0, 30)
    with pytest.raises(ValueError, match="k_max"):
        chi2_threshold_poly(0.99, 1)


# ------------------------------------------------------------------------------- background
def test_full_covariance_model_gives_chi2_distances(rng):
    """Strongly correlated sensor noise: d_M must be chi-square(3), agreeing with a direct
    per-pixel np.cov + solve, and a diagonal model must not be."""
    H, W = 40, 50
    base = rng.uniform(60, 190, (H, W, 3))
    # B and R move against each other: U and V correlate at about -0.9
    L = np.array([[6.0, 0, 0], [0, 2.0, 0], [-6.0, 0, 2.0]])

    def frame():
        return np.clip(np.rint(base + rng.normal(size=(H, W, 3)) @ L.T), 0, 255).astype(np.uint8)

    train = [frame() for _ in range(200)]
    bg = YuvBackground.fit(train, noise_var=0.1, shadow_drop=0.0)
    test = frame()
    dm = bg.distance(test)
    assert dm.shape == (H, W) and dm.dtype == np.float32
    # direct twin on a few pixels
    yuv = np.stack([cv2.cvtColor(f, cv2.COLOR_BGR2YUV) for f in train]).astype(np.float64)
    y = cv2.cvtColor(test, cv2.COLOR_BGR2YUV).astype(np.float64)
    for r, c in [(0, 0), (13, 27), (39, 49)]:
        S = np.cov(yuv[:, r, c].T) + 0.1 * np.eye(3)
        d = y[r, c] - yuv[:, r, c].mean(0)
        assert np.isclose(dm[r, c], d @ np.linalg.solve(S, d), rtol=1e-3)
    # distribution over all pixels: mean 3 and the 99 % point of chi2(3)
    dms = np.concatenate([bg.distance(frame()).ravel() for _ in range(10)])
    assert abs(dms.mean() - 3.0) < 0.25, dms.mean()
    assert abs(np.mean(dms > chi2.ppf(0.99, 3)) - 0.01) < 0.004
    diag = YuvBackground(bg.mean, np.linalg.inv(np.linalg.inv(bg.inv_cov) * np.eye(3)))
    dd = np.concatenate([diag.distance(frame()).ravel() for _ in range(10)])
    assert np.mean(dd > chi2.ppf(0.99, 3)) > 0.02
    # the shadow twin: the distance is the smaller of the two Gaussians' (direct twin again)
    sh = YuvBackground.fit(train, noise_var=0.1)
    dark = np.clip(np.rint(base * 0.9), 0, 255).astype(np.uint8)
    yd = cv2.cvtColor(dark, cv2.COLOR_BGR2YUV).astype(np.float64)
    r, c = 20, 20
    S = np.cov(yuv[:, r, c].T) + 0.1 * np.eye(3)
    mu = yuv[:, r, c].mean(0)
    mu_s = np.r_[0.9 * mu[0], 128 + 0.9 * (mu[1:] - 128)]
    both = [(yd[r, c] - m) @ np.linalg.solve(S, yd[r, c] - m) for m in (mu, mu_s)]
    assert both[1] < both[0]
    assert np.isclose(sh.distance(dark)[r, c], min(both), rtol=1e-3)
    assert np.isclose(bg.distance(dark)[r, c], both[0], rtol=1e-3)


def test_shadow_model_absorbs_ten_percent_darkening(scene, rng):
    cams, tex, bgs = scene
    dark = _noisy(tex[0] * 0.9, rng)
    t1 = chi2.ppf(0.99, 3)
    with_shadow = bgs[0].distance(dark)
    no_shadow = YuvBackground(bgs[0].mean, bgs[0].inv_cov, shadow_drop=0.0).distance(dark)
    y_only = YuvBackground(bgs[0].mean, bgs[0].inv_cov, shadow_chroma=False).distance(dark)
    assert np.mean(with_shadow > t1) < 0.03
    assert np.mean(no_shadow > t1) > 0.9
    # the literal Y-only shift misses the chroma drop of this saturated texture on some pixels
    assert np.mean(y_only > t1) > 2 * np.mean(with_shadow > t1)
    # unshadowed pixels still use the unshadowed Gaussian
    assert np.mean(bgs[0].distance(_noisy(tex[0], rng)) > t1) < 0.03


def test_background_fit_validates_frames(scene):
    good = np.zeros((10, 12, 3), np.uint8)
    with pytest.raises(ValueError, match="background frame 1"):
        YuvBackground.fit([good, good.astype(np.float32)])
    with pytest.raises(ValueError, match="background frame 1"):
        YuvBackground.fit([good, np.zeros((10, 13, 3), np.uint8)])
    with pytest.raises(ValueError, match="at least one"):
        YuvBackground.fit([])
    cams, tex, bgs = scene
    imgs = [np.zeros((c.height, c.width, 3), np.uint8) for c in cams]
    imgs[2] = imgs[2][:-1]
    with pytest.raises(ValueError, match="cam2"):
        carve_colour(cams, imgs, bgs, BOUNDS)
    with pytest.raises(ValueError, match="one image and one background"):
        carve_colour(cams, imgs[:3], bgs, BOUNDS)


# ------------------------------------------------------------------------------- carving
@pytest.fixture(scope="module")
def carved(scene):
    cams, tex, bgs = scene
    imgs, masks = _frame(cams, tex, np.random.default_rng(11))
    vox = carve_colour(cams, imgs, bgs, BOUNDS, base=8, max_depth=3)
    return imgs, masks, vox, dict(carve_colour.last_stats)


def test_sphere_volume_centroid_and_mask_carving_agree(scene, carved):
    cams, tex, bgs = scene
    imgs, masks, vox, stats = carved
    true = 4 / 3 * np.pi * RADIUS ** 3
    # four views: the visual hull is somewhat larger than the sphere, never much smaller
    assert 0.95 * true < vox.volume < 1.3 * true, (vox.volume, true)
    assert np.linalg.norm(_centroid(vox) - CENTRE) < 0.02
    assert np.linalg.norm(vox.centers - CENTRE, axis=1).max() < 1.35 * RADIUS
    ref = carve(cams, masks, BOUNDS, base=8, max_depth=3)
    A = {tuple(r) for r in vox.at_level(3)}
    B = {tuple(r) for r in ref.at_level(3)}
    assert len(A & B) / len(A | B) > 0.9, (len(A), len(B), len(A & B))
    assert abs(vox.volume - ref.volume) < 0.05 * ref.volume
    # hierarchical: big interior voxels were kept whole, and samples were drawn
    assert np.any(vox.level < 3)
    assert stats["samples"] > stats["classifications"] > 0
    assert stats["threshold_max_rel_error"] < 0.07
    assert sum(lv["kept"] for lv in stats["levels"]) == len(vox)


def test_voxel_colours_match_the_object(carved):
    imgs, masks, vox, stats = carved
    assert vox.colour.shape == (len(vox), 3) and vox.colour.dtype == np.float32
    err = np.abs(vox.colour - OBJECT_BGR).max(axis=1)
    assert np.median(err) < 2.0, np.median(err)
    assert np.quantile(err, 0.95) < 6.0, np.quantile(err, 0.95)


def test_carving_without_colours_keeps_the_same_voxels(scene, carved):
    cams, tex, bgs = scene
    imgs, masks, vox, stats = carved
    bare = carve_colour(cams, imgs, bgs, BOUNDS, base=8, max_depth=3, colours=False)
    assert bare.colour is None and len(bare) == len(vox) > 0
    assert np.array_equal(bare.ijk, vox.ijk) and np.array_equal(bare.level, vox.level)


def test_empty_scene_gives_no_voxels(scene):
    cams, tex, bgs = scene
    imgs, _ = _frame(cams, tex, np.random.default_rng(12), sphere=False)
    vox = carve_colour(cams, imgs, bgs, BOUNDS, base=8, max_depth=2)
    assert len(vox) == 0
    # nearly every coarse voxel is already background in some camera
    lv0 = carve_colour.last_stats["levels"][0]
    assert lv0["split"] < 0.02 * lv0["voxels"]


def test_moving_the_object_moves_the_voxels(scene, carved):
    cams, tex, bgs = scene
    shift = np.array([0.15, 0.0, -0.1])
    imgs, _ = _frame(cams, tex, np.random.default_rng(13), centre=CENTRE + shift)
    vox = carve_colour(cams, imgs, bgs, BOUNDS, base=8, max_depth=2)
    assert np.linalg.norm(_centroid(vox) - (CENTRE + shift)) < 0.03
    assert np.linalg.norm(_centroid(vox) - _centroid(carved[2])) > 0.15


def test_shadow_creates_no_voxels_but_the_object_does(scene):
    cams, tex, bgs = scene
    imgs, _ = _frame(cams, tex, np.random.default_rng(14), shadow=True)

    def in_patch(v):
        return np.all((v.centers > SHADOW_LO - 0.02) & (v.centers < SHADOW_HI + 0.02), axis=1)

    vox = carve_colour(cams, imgs, bgs, BOUNDS, base=8, max_depth=2)
    assert vox.volumes[in_patch(vox)].sum() < 0.002  # m^3; the patch is 0.097
    assert abs(vox.volume - 4 / 3 * np.pi * RADIUS ** 3) < 0.3 * vox.volume
    # without the shadow Gaussian the same images do carve the shadowed floor patch
    plain = [YuvBackground(b.mean, b.inv_cov, shadow_drop=0.0) for b in bgs]
    vox0 = carve_colour(cams, imgs, plain, BOUNDS, base=8, max_depth=2)
    assert vox0.volumes[in_patch(vox0)].sum() > 0.03


def test_image_border_and_tolerance_behave_like_mask_carving(scene):
    """Camera 0 aimed aside so the sphere is cut by its image border: voxels it cannot see are
    dropped, as mask-based ``carve`` drops them; ``tolerance=1`` lets them back in."""
    cams, tex, bgs = scene
    rng = np.random.default_rng(15)
    c0 = cams[0]
    aside = look_at_camera("cam0", c0.center, CENTRE + 1.5 * c0.R[0], c0.width, c0.height, 40)
    cams = [aside] + cams[1:]
    tex = [_texture(aside, rng)] + tex[1:]
    bgs = [YuvBackground.fit([_noisy(tex[0], rng) for _ in range(N_TRAIN)])] + bgs[1:]
    imgs, masks = _frame(cams, tex, rng)
    # the cut is real: the sphere touches the border and is narrower than seen centred
    width = masks[0].any(axis=0).sum()
    assert masks[0][:, 0].any() and width < 0.6 * _sphere_mask(c0).any(axis=0).sum()
    for tol in (0, 1):
        vox = carve_colour(cams, imgs, bgs, BOUNDS, base=8, max_depth=2, tolerance=tol)
        ref = carve(cams, masks, BOUNDS, base=8, max_depth=2, tolerance=tol)
        A = {tuple(r) for r in vox.at_level(2)}
        B = {tuple(r) for r in ref.at_level(2)}
        assert len(A & B) / len(A | B) > 0.9, (tol, len(A), len(B), len(A & B))
        if tol == 0:
            cut = vox.volume
    assert vox.volume > 1.2 * cut
