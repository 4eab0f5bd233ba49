"""Observation model: background subtraction, HLS quantisation, environment layers (GPU vs CPU)."""
import cv2
import numpy as np
import pytest

from gltrack.camera import look_at_camera
from gltrack.observe import hls
from gltrack.observe.background import BackgroundModel, clean_mask
from gltrack.observe.environment import EnvironmentLayers, environment_masks_cpu

# ---------------------------------------------------------------------------------------------
# synthetic scene: a red blob moving over a textured background, casting a shadow

H, W = 120, 160
BLOB_BGR = (40, 60, 210)


def _background(rng):
    tex = cv2.GaussianBlur(rng.integers(0, 256, (H, W, 3)).astype(np.float32), (0, 0), 3)
    tex = (tex - tex.mean()) * 3 + 128
    yy, xx = np.mgrid[:H, :W]
    tex += 30 * ((xx // 16 + yy // 16) % 2)[..., None]
    return np.clip(tex, 20, 230)


def _noisy(img, rng):
    return np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)


def _frame(bg, cx, rng):
    """Frame with the blob centred at column cx; returns (image, blob mask, shadow mask)."""
    img = bg.copy()
    yy, xx = np.mgrid[:H, :W]
    shadow = ((xx - cx - 25) / 30.0) ** 2 + ((yy - 95) / 10.0) ** 2 < 1
    # a real shadow is lit by bluish ambient light only: dimmer and slightly bluer
    img[shadow] = img[shadow] * 0.55 + (3, 0, 0)
    blob = (xx - cx) ** 2 + (yy - 60) ** 2 < 20 ** 2
    img[blob] = BLOB_BGR
    return _noisy(img, rng), blob, shadow & ~blob


def _iou(a, b):
    return (a & b).sum() / (a | b).sum()


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(7)
    bg = _background(rng)
    train = [_noisy(bg, rng) for _ in range(10)]
    frames = [_frame(bg, cx, rng) for cx in (40, 80, 120)]
    return train, frames


@pytest.mark.parametrize("method", ["mog2", "gaussian_yuv"])
def test_background_finds_blob_and_ignores_shadow(scene, method):
    train, frames = scene
    model = BackgroundModel().fit(train, method)
    for img, blob, shadow in frames:
        fg = model.foreground(img)
        assert fg.dtype == bool and fg.shape == (H, W)
        assert _iou(fg, blob) > 0.8
        assert fg[shadow].mean() < 0.05, "shadow marked as foreground"


def test_shadow_test_is_what_removes_the_shadow(scene):
    train, frames = scene
    img, blob, shadow = frames[1]
    with_test = BackgroundModel(shadows=True).fit(train, "gaussian_yuv").foreground(img)
    without = BackgroundModel(shadows=False).fit(train, "gaussian_yuv").foreground(img)
    assert without[shadow].mean() > 0.9
    assert with_test[shadow].mean() < 0.05
    # a colour change of the same luminance drop is not a shadow
    tinted = img.copy()
    tinted[shadow] = (tinted[shadow] * np.array([0.3, 0.9, 0.5])).astype(np.uint8)
    assert BackgroundModel().fit(train, "gaussian_yuv").foreground(tinted)[shadow].mean() > 0.5


def test_mog2_does_not_learn_while_tracking(scene):
    train, frames = scene
    model = BackgroundModel().fit(train, "mog2")
    img, blob, _ = frames[0]
    for _ in range(30):
        fg = model.foreground(img)
    assert _iou(fg, blob) > 0.8


def test_background_validates_input(scene):
    train, _ = scene
    with pytest.raises(ValueError, match="method"):
        BackgroundModel().fit(train, "median")
    model = BackgroundModel().fit(train, "gaussian_yuv")
    with pytest.raises(ValueError, match="160x120"):
        model.foreground(np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(RuntimeError):
        BackgroundModel().foreground(train[0])


def test_background_subset_uses_rng(scene, rng):
    train, frames = scene
    model = BackgroundModel(max_train_frames=4).fit(train, "gaussian_yuv", rng=rng)
    img, blob, _ = frames[2]
    assert _iou(model.foreground(img), blob) > 0.8


def test_clean_mask_removes_speckle_and_fills_holes():
    m = np.zeros((50, 50), bool)
    m[10:30, 10:30] = True
    m[20, 20] = False          # pin hole
    m[40, 40] = True           # speckle
    out = clean_mask(m, 3, 20)
    assert out[20, 20] and not out[40, 40] and out[15:25, 15:25].all()


# ---------------------------------------------------------------------------------------------
# HLS quantisation


def _direct_bits(hls_pixel):
    """Independent per-pixel computation with the documented thresholds."""
    h, l, s = (int(v) >> 3 for v in hls_pixel)
    full = 0xFFFFFFFF
    meaningful_sat = 3 <= l < 29
    meaningful_hue = meaningful_sat and s >= 3
    return (1 << h if meaningful_hue else full, 1 << l, 1 << s if meaningful_sat else full)


def test_observed_bits_match_direct_computation(rng):
    img = rng.integers(0, 256, (24, 20, 3), dtype=np.uint8)
    img[0, :4] = [(0, 0, 0), (255, 255, 255), (128, 128, 128), (0, 0, 255)]  # black, white, grey, red
    img[1, :3] = [(10, 10, 12), (250, 245, 255), (100, 104, 100)]
    bits = hls.observed_bits(img)
    assert bits.shape == (24, 20, 3) and bits.dtype == np.uint32
    # OpenCV's vectorised and scalar paths round differently (pure red: L 128 vs 127), so the
    # direct computation converts the whole image too, never pixel by pixel.
    ref = cv2.cvtColor(img, cv2.COLOR_BGR2HLS_FULL)
    for r in range(img.shape[0]):
        for c in range(img.shape[1]):
            assert tuple(int(b) for b in bits[r, c]) == _direct_bits(ref[r, c]), (r, c, img[r, c])
    assert bits[0, 0, 0] == hls.ALL_BITS and bits[0, 0, 2] == hls.ALL_BITS  # black
    assert bits[0, 2, 0] == hls.ALL_BITS and bits[0, 2, 2] == 1             # grey: hue only
    assert bits[0, 3, 0] == 1                                                # red: hue bin 0


def test_lut_layout_and_thresholds():
    lut = hls.HLS_BITS_LUT
    assert lut.shape == (32768, 3) and lut.dtype == np.uint32
    v = (21 << 10) | (16 << 5) | 20
    assert tuple(lut[v]) == (1 << 21, 1 << 16, 1 << 20)
    assert lut[(21 << 10) | (2 << 5) | 20][0] == hls.ALL_BITS      # dark
    assert lut[(21 << 10) | (29 << 5) | 20][2] == hls.ALL_BITS     # bright
    assert lut[(21 << 10) | (16 << 5) | 2][0] == hls.ALL_BITS      # grey
    assert lut[(21 << 10) | (16 << 5) | 2][2] == 1 << 2
    looser = hls.make_bits_lut(s_grey=1)
    assert looser[(21 << 10) | (16 << 5) | 2][0] == 1 << 21
    with pytest.raises(ValueError):
        hls.make_bits_lut(l_dark=40)


def test_voxel_index_packs_bins(rng):
    img = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    b = cv2.cvtColor(img, cv2.COLOR_BGR2HLS_FULL).astype(int) >> 3
    assert np.array_equal(hls.voxel_index(img), b[..., 0] * 1024 + b[..., 1] * 32 + b[..., 2])
    with pytest.raises(ValueError):
        hls.voxel_index(img.astype(np.float32))


# ---------------------------------------------------------------------------------------------
# environment layers


def _cams():
    return [look_at_camera("a", (0, 1, 3), (0, 1, 0), 37, 23, 50.0),
            look_at_camera("b", (3, 1, 0), (0, 1, 0), 64, 48, 50.0)]


def _random_inputs(rng, cam):
    h, w = cam.height, cam.width
    return (rng.random((h, w)) < 0.5, rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
            rng.random((h, w)) < 0.4, rng.random(32768) < 0.5)


def test_environment_gpu_equals_cpu(ctx, rng):
    cams = _cams()
    with EnvironmentLayers(ctx, cams) as env:
        for trial in range(3):
            for c, cam in enumerate(cams):
                fg, img, poly, lut = _random_inputs(rng, cam)
                g_fg, g_bl = env.apply(c, fg, img, poly, lut)
                c_fg, c_bl = environment_masks_cpu(fg, img, poly, lut)
                assert g_fg.shape == (cam.height, cam.width) and g_fg.dtype == bool
                assert np.array_equal(g_fg, c_fg) and np.array_equal(g_bl, c_bl)
                assert 0 < g_fg.sum() < g_fg.size and 0 < g_bl.sum() < g_bl.size
                code = env.codes(c, fg, img, poly, lut)
                assert np.array_equal((code & 4) != 0, lut[hls.voxel_index(img)])


def test_environment_truth_table(ctx):
    """All 8 combinations of (I_F, I_H, occluder) against the paper's eqs. 5-7 worked by hand."""
    cam = look_at_camera("t", (0, 1, 3), (0, 1, 0), 8, 1, 50.0)
    img = np.zeros((1, 8, 3), np.uint8)
    img[0, :] = (0, 0, 200)                 # red
    img[0, 1::2] = (200, 0, 0)              # blue
    lut = np.zeros(32768, bool)
    lut[hls.voxel_index(img[:, :1])[0, 0]] = True   # only red is human
    i_h = np.array([1, 0] * 4, bool)
    i_f = np.array([1, 1, 0, 0] * 2, bool)
    occ = np.array([0] * 4 + [1] * 4, bool)
    # (F,H,occ): (1,1,0)->fg   (1,0,0)->block  (0,1,0)->-  (0,0,0)->-
    #            (1,1,1)->fg   (1,0,1)->block  (0,1,1)->block  (0,0,1)->block
    want_fg = np.array([1, 0, 0, 0, 1, 0, 0, 0], bool)
    want_bl = np.array([0, 1, 0, 0, 0, 1, 1, 1], bool)
    with EnvironmentLayers(ctx, [cam]) as env:
        g = env.apply(0, i_f[None], img, occ[None], lut)
    c = environment_masks_cpu(i_f[None], img, occ[None], lut)
    assert np.array_equal(lut[hls.voxel_index(img)][0], i_h)
    for fg, bl in (g, c):
        assert np.array_equal(fg[0], want_fg) and np.array_equal(bl[0], want_bl)


def test_environment_outputs_follow_inputs(ctx, rng):
    cam = _cams()[1]
    fg, img, poly, lut = _random_inputs(rng, cam)
    with EnvironmentLayers(ctx, [cam]) as env:
        f0, b0 = env.apply(0, fg, img, poly, lut)
        f1, b1 = env.apply(0, fg, img, poly, ~lut)          # LUT re-uploaded on change
        assert not np.array_equal(f0, f1) and not np.array_equal(b0, b1)
        f2, b2 = env.apply(0, fg, img, ~poly, lut)
        assert np.array_equal(f0, f2) and not np.array_equal(b0, b2)
        f3, _ = env.apply(0, ~fg, img, poly, lut)
        assert not np.array_equal(f0, f3)
        f4, b4 = env.apply(0, fg, img, None, np.ones(32768, bool))   # all human, no occluders
        assert np.array_equal(f4, fg) and not b4.any()
        with pytest.raises(ValueError, match="camera"):
            env.apply(0, fg[:-1], img[:-1], None, lut)
        with pytest.raises(ValueError, match="lut"):
            env.apply(0, fg, img, None, lut[:100])
