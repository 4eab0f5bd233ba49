"""Foreground without empty background frames (gltrack.observe.foreground).

A synthetic scene the test makes itself: a static random-texture background per camera, a
"person" (three stacked spheres, rendered exactly by ray-sphere tests) seen by 4 analytic
cameras, and a distractor disc that moves through camera 0's image only (someone walking past
behind the subject, seen by one camera).
"""
from __future__ import annotations

import threading
import tomllib

import cv2
import numpy as np
import pytest

from gltrack.camera import Camera, look_at_camera
from gltrack.observe.foreground import (CUES, ForegroundParams, SequenceForeground, dilate_mask,
                                        erode_mask, estimate_foreground, fill_boxes,
                                        masked_median, outside_reaching, shared_volume,
                                        support_column)

W, H = 160, 120
RADII = (0.22, 0.2, 0.12)
HEIGHTS = (0.5, 0.95, 1.35)
SHIRT = np.array([40, 60, 200], np.float64)  # BGR: the subject's red shirt


def _cameras():
    cams = []
    for i, a in enumerate(np.radians([0, 80, 170, 260])):
        eye = (3.0 * np.sin(a), 1.6, 3.0 * np.cos(a))
        cams.append(look_at_camera(f"cam{i}", eye, (0.0, 0.9, 0.0), W, H, 50.0))
    return cams


def _rays(cam):
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    pix = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3).astype(float)
    d = pix @ np.linalg.inv(cam.K).T @ cam.R  # world directions (rows)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _person_mask(cam, rays, x):
    """(H, W) bool: pixels whose ray meets one of the spheres of a person at (x, -x) metres
    on the floor (a diagonal path, seen moving sideways by every camera)."""
    o = cam.center
    hit = np.zeros(len(rays), bool)
    for r, y in zip(RADII, HEIGHTS):
        c = np.array([x, y, -x]) - o
        along = rays @ c
        d2 = c @ c - along ** 2
        hit |= (along > 0) & (d2 <= r * r)
    return hit.reshape(H, W)


def _scene(rng, xs, distractor=True):
    """frames (C lists of T images), true masks (C, T, H, W), distractor masks (T, H, W)."""
    cams = _cameras()
    T = len(xs)
    frames, masks = [], []
    colour = SHIRT
    for cam in cams:
        # static texture: random blobs of colour at a few scales, like a cluttered room
        bg = sum(cv2.resize(rng.uniform(40, 220, (h, w, 3)), (W, H), interpolation=cv2.INTER_CUBIC)
                 for h, w in ((4, 5), (12, 16), (30, 40))) / 3.0
        rays = _rays(cam)
        fr, ms = [], []
        for x in xs:
            m = _person_mask(cam, rays, x)
            img = bg.copy()
            img[m] = colour
            fr.append(img)
            ms.append(m)
        frames.append(fr)
        masks.append(np.stack(ms))
    dis = np.zeros((T, H, W), bool)
    if distractor:
        yy, xx = np.mgrid[0:H, 0:W]
        for t in range(T):
            cy = 15 + (H - 30) * t / max(T - 1, 1)  # down the right edge, off the subject
            dis[t] = (xx - 140) ** 2 / 12 ** 2 + (yy - cy) ** 2 / 20 ** 2 <= 1.0
            dis[t] &= ~masks[0][t]
            frames[0][t][dis[t]] = (200, 180, 40)
    out = [[np.clip(f + rng.normal(0, 2.0, f.shape), 0, 255).astype(np.uint8) for f in fr]
           for fr in frames]
    return cams, out, np.stack(masks), dis


def _iou(a, b):
    return float(np.sum(a & b) / max(np.sum(a | b), 1))


def _mean_iou(masks, truth):
    return np.array([np.mean([_iou(m[t], g[t]) for t in range(len(g))])
                     for m, g in zip(masks, truth)])


@pytest.fixture(scope="module")
def moving():
    rng = np.random.default_rng(7)
    return _scene(rng, np.linspace(-0.45, 0.45, 12))


def test_masks_reach_iou_and_distractor_goes_with_the_hull(moving):
    cams, frames, truth, dis = moving
    full = estimate_foreground(frames, cams, rng=np.random.default_rng(1))
    iou = _mean_iou(full.masks, truth)
    assert np.all(iou >= 0.8), iou
    # the distractor, seen by camera 0 alone, is not in the final masks ...
    assert full.masks[0][dis].mean() < 0.02
    # ... but the temporal background alone keeps it (the multi-view cue is what removes it)
    median_only = estimate_foreground(frames, cams, cues=("shadows",), passes=1)
    assert median_only.masks[0][dis].mean() > 0.5
    assert full.foreground_fraction().shape == (4,)
    big = full.mask_at(0, 3, (2 * W, 2 * H))
    assert big.shape == (2 * H, 2 * W) and abs(big.mean() - full.masks[0][3].mean()) < 0.01


def test_cameras_side_by_side_give_the_masks_of_one_thread(moving):
    """The cameras' steps run on threads at the same time, and the masks are those of one
    thread: GrabCut's random start is seeded per camera, not drawn from one shared stream."""
    cams, frames, truth, dis = moving
    one = SequenceForeground(frames, cams, rng=np.random.default_rng(1), threads=1).run()
    four = SequenceForeground(frames, cams, rng=np.random.default_rng(1), threads=4)
    meet = threading.Barrier(2, timeout=30)  # breaks unless two cameras run at once
    assert sorted(four.per_camera(lambda c: (meet.wait() if c < 2 else 0, c)[1])) == [0, 1, 2, 3]
    masks = four.run().masks
    assert all(np.array_equal(a, b) for a, b in zip(one.masks, masks))
    assert np.all(_mean_iou(masks, truth) >= 0.8)
    with pytest.raises(ValueError, match="threads"):
        SequenceForeground(frames, cams, threads=0)


def test_person_masks_fix_the_background_of_a_subject_that_barely_moves():
    rng = np.random.default_rng(3)
    # 0.2 m in 12 frames: the torso covers its pixels in most frames, so a median keeps it
    cams, frames, truth, _ = _scene(rng, np.linspace(-0.3, -0.1, 12), distractor=False)
    # frame 0 as the background away from the person (blurred as the estimator blurs)
    clean = [cv2.GaussianBlur(f[0], (0, 0), ForegroundParams().blur) for f in frames]
    # exact masks need no safety margin (the default 5 px is for a tracker's silhouettes)
    params = ForegroundParams(exclude_margin=1)
    plain = estimate_foreground(frames, cams, cues=(), passes=1, params=params)
    given = estimate_foreground(frames, cams, cues=(), passes=1, person_masks=truth,
                                params=params)
    # the background behind the person: the median without masks is the person's colour
    err_plain, err_given = [], []
    for c in range(4):
        # behind the person in some frames, seen in frame 0, observed with the masks given
        seen = truth[c].any(axis=0) & ~truth[c][0] & given.known[c]
        assert seen.sum() > 50
        ref = clean[c][seen].astype(float)
        err_plain.append(np.abs(plain.backgrounds[c][seen] - ref).mean())
        err_given.append(np.abs(given.backgrounds[c][seen] - ref).mean())
    assert np.mean(err_given) < 0.25 * np.mean(err_plain), (err_given, err_plain)
    assert _mean_iou(given.masks, truth).mean() > _mean_iou(plain.masks, truth).mean() + 0.2


def test_ghost_test_drops_the_background_where_the_subject_stood():
    """The subject stands still for 10 frames, then walks off in 0.2 m steps (6 frames): the
    temporal median holds it where it stood, so that spot (its "ghost") is foreground in the
    walking frames. The ghost test drops it (the true background there recurs in a third of
    the frames) and keeps the walking subject (each pixel covered in a frame or two)."""
    rng = np.random.default_rng(11)
    xs = np.r_[np.full(10, -0.45), np.arange(-0.25, 0.76, 0.2)]
    cams, frames, truth, _ = _scene(rng, xs, distractor=False)
    walk = slice(10, len(xs))
    ghost = [truth[c][0][None] & ~truth[c][walk] for c in range(4)]

    def measure(cues, passes):
        r = estimate_foreground(frames, cams, cues=cues, passes=passes)
        kept = np.mean([r.masks[c][walk][ghost[c]].mean() for c in range(4)])
        return kept, _mean_iou([m[walk] for m in r.masks], [t[walk] for t in truth]).mean()

    kept, iou = measure((), 1)
    kept_g, iou_g = measure(("ghosts",), 1)
    assert kept > 0.9 and kept_g < 0.15, (kept, kept_g)
    assert iou_g > iou + 0.2, (iou, iou_g)
    full = [c for c in CUES if c != "ghosts"]
    kept, iou = measure(full, 2)
    kept_g, iou_g = measure(full + ["ghosts"], 2)
    assert kept > 0.5 and kept_g < 0.1, (kept, kept_g)
    assert iou_g > 0.8 and iou_g > iou + 0.2, (iou, iou_g)


def _leg_mask(cam, rays, radius=0.06, top=0.34):
    """(H, W) bool: pixels whose ray meets a vertical cylinder standing on the floor at the
    origin (y in [0, top], metres): a leg that never moves."""
    o = cam.center
    dx, dz = rays[:, 0], rays[:, 2]
    a = dx * dx + dz * dz
    b = 2 * (o[0] * dx + o[2] * dz)
    c = o[0] ** 2 + o[2] ** 2 - radius ** 2
    disc = b * b - 4 * a * c
    ok = disc >= 0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    s1, s2 = (-b - sq) / (2 * a), (-b + sq) / (2 * a)
    y1, y2 = o[1] + s1 * rays[:, 1], o[1] + s2 * rays[:, 1]
    lo, hi = np.minimum(y1, y2), np.maximum(y1, y2)
    return (ok & (s2 > 0) & (hi >= 0) & (lo <= top)).reshape(H, W)


def _balancing(top):
    """The spheres sway 0.3 m above a leg (``_leg_mask`` of height ``top``) in the subject's
    colour that stands still on the floor for the whole take: cameras, frames, the true masks
    of the spheres and of the leg (C, H, W)."""
    rng = np.random.default_rng(5)
    cams, frames, truth, _ = _scene(rng, np.linspace(-0.2, 0.2, 12), distractor=False)
    legs = []
    for c, cam in enumerate(cams):
        leg = _leg_mask(cam, _rays(cam), top=top) & ~truth[c][0]
        for t in range(len(frames[c])):
            here = leg & ~truth[c][t]
            noise = rng.normal(0, 2, (here.sum(), 3))
            frames[c][t][here] = np.clip(SHIRT + noise, 0, 255).astype(np.uint8)
        legs.append(leg)
    return cams, frames, truth, legs


def _nothing_of_the_floor_around(masks, legs, full):
    for c in range(len(legs)):
        near = dilate_mask(legs[c], 6) & ~dilate_mask(full[c].any(axis=0), 2)
        assert masks[c][:, near].mean() < 0.05


def test_support_cue_finds_a_leg_that_never_moves():
    """A subject balancing on one leg: the temporal background holds the still leg, and every
    other cue misses it. With the floor known, the support cue finds it in the column under
    the hull by its colour, the subject's, and keeps what 3 views agree on."""
    cams, frames, truth, legs = _balancing(top=0.34)
    full = [t | leg[None] for t, leg in zip(truth, legs)]
    without = estimate_foreground(frames, cams, rng=np.random.default_rng(1))
    floor = ((0.0, 1.0, 0.0), 0.0)
    with_ = estimate_foreground(frames, cams, rng=np.random.default_rng(1), floor=floor)
    # switching the cue off by name gives the old masks
    off = estimate_foreground(frames, cams, rng=np.random.default_rng(1), floor=floor,
                              cues=[c for c in CUES if c != "support"])

    def recall(r):
        return np.mean([r.masks[c][:, legs[c]].mean() for c in range(4)])

    # GrabCut's band grows the masks a little way down the leg from the body (0.61 measured)
    assert recall(off) == recall(without) < 0.7, (recall(without), recall(off))
    assert recall(with_) > 0.9 and recall(with_) > recall(without) + 0.25, recall(with_)
    assert "support" in with_.stages and "support" not in without.stages
    assert with_.stages["support"][0][:, legs[0]].mean() > 0.5
    iou0, iou1 = _mean_iou(without.masks, full).mean(), _mean_iou(with_.masks, full).mean()
    assert iou1 > iou0, (iou0, iou1)
    # nothing of the floor around the leg comes with it
    _nothing_of_the_floor_around(with_.masks, legs, full)


def test_support_cue_keeps_a_shank_cut_off_from_the_body():
    """A leg 0.18 m tall under spheres whose lowest reaches down to 0.28 m: the still shank is
    apart from the body in the images (on the Pose2Sim take: still shorts between the bare
    shank and the moving body, which neither the temporal background nor the support colour
    test takes). The masks keep only 2-D components that touch the hull's reprojection, and
    the shank does not; its support pixels are multi-view consistent in the column's lower
    half, so it stays (recall 0.38-0.67 per camera before it was kept)."""
    cams, frames, truth, legs = _balancing(top=0.18)
    full = [t | leg[None] for t, leg in zip(truth, legs)]
    r = estimate_foreground(frames, cams, rng=np.random.default_rng(1),
                            floor=((0.0, 1.0, 0.0), 0.0))
    recall = [r.masks[c][:, legs[c]].mean() for c in range(4)]
    assert min(recall) > 0.85, recall
    _nothing_of_the_floor_around(r.masks, legs, full)


def test_support_column_from_the_floor_to_the_centroid():
    lo = np.array([[0.0, 0.5, 0.0], [0.1, 0.6, 0.0]])
    size = np.array([0.1, 0.1])
    col = support_column(lo, size, ((0, 1, 0), 0.0), reach=0.4, step=0.1)
    assert col is not None
    clo, csize = col
    top = clo[:, 1] + csize
    # from the floor to the centroid's height, around the centroid's foot
    assert abs(clo[:, 1].min()) < 1e-9 and abs(top.max() - 0.6) < 1e-9
    centre = np.array([0.1, 0.6, 0.05])
    assert np.allclose((clo + 0.5 * csize[:, None]).mean(axis=0)[[0, 2]], centre[[0, 2]])
    assert np.isclose(clo[:, 0].min(), 0.1 - 0.4) and np.isclose((clo[:, 0] + csize).max(), 0.5)
    # a hull whose centroid is under the floor (a wrong floor), or an empty one: no column
    assert support_column(lo - [0, 0.7, 0], size, ((0, 1, 0), 0.0), reach=0.4, step=0.1) is None
    assert support_column(np.zeros((0, 3)), np.zeros(0), ((0, 1, 0), 0.0), reach=0.4,
                          step=0.1) is None
    # any up direction: the same hull in a Z-up world
    zlo = lo[:, [0, 2, 1]] * [1, -1, 1] - [0, 0.1, 0]
    zcol = support_column(zlo, size, ((0, 0, 1), 0.0), reach=0.4, step=0.1)
    assert zcol is not None and abs(zcol[0][:, 2].min()) < 1e-9
    with pytest.raises(ValueError, match="floor"):
        estimate_foreground([[np.zeros((H, W, 3), np.uint8)]] * 4, _cameras(),
                            floor=((0, 0, 0), 0.0))


def test_prior_bounds_the_spill_fills_holes_and_loses_a_one_view_blob(moving):
    """The "prior" cue on masks the test spoils: every view's mask spills 6 px past the body
    and has a hole in the torso; camera 0's prior also takes a blob no other view sees (a
    second person). The prior's consistent pixels plus the masks' edge next to them come back;
    a frame whose prior is missing in two views keeps its masks, and so does a view whose prior
    is only a blob in a corner, off the body."""
    cams, frames, truth, dis = moving
    est = SequenceForeground(frames, cams, rng=np.random.default_rng(1))
    spoilt, prior = [], []
    for c in range(4):
        m = np.stack([dilate_mask(g, 6) for g in truth[c]])
        ys, xs = np.nonzero(truth[c][5])
        m[5, int(ys.mean()) - 3:int(ys.mean()) + 3, int(xs.mean()) - 3:int(xs.mean()) + 3] = False
        spoilt.append(m)
        q = truth[c].copy()
        if c == 0:
            q |= dis
        prior.append(q)
    prior[1][7] = False
    prior[2][7] = False
    prior[3][9] = False
    prior[3][9][:15, :15] = True
    used = est.consistent_prior(prior)
    out = est.with_prior(spoilt, used)
    r = ForegroundParams().prior_margin
    for c in range(4):
        for t in (0, 5, 11):
            # the hole is filled; of the spill, only the margin next to the prior stays
            assert np.all(out[c][t] >= truth[c][t]) and np.all(used[c][t] == truth[c][t])
            assert np.all(out[c][t] <= dilate_mask(truth[c][t], r + 1))
            assert not np.all(spoilt[c][t] <= dilate_mask(truth[c][t], r + 1))
            assert _iou(out[c][t], truth[c][t]) > _iou(spoilt[c][t], truth[c][t]) + 0.1
        assert np.array_equal(out[c][7], spoilt[c][7]) and not used[c][7].any()
    assert out[0][dis].mean() < 0.02 and used[0][dis].mean() < 0.02
    assert np.array_equal(out[3][9], spoilt[3][9]) and not used[3][9].any()
    assert used[0][9].any() and not np.array_equal(out[0][9], spoilt[0][9])
    # a prior that changes changes the masks: the prior's pixels are the masks' core
    shifted = [np.roll(q, 4, axis=2) for q in prior]
    moved = est.with_prior(spoilt, est.consistent_prior(shifted))
    assert not np.array_equal(moved[3][0], out[3][0])


def test_person_prior_in_the_whole_chain():
    """A subject that barely moves (the cues miss its torso) with a probability prior (uint8,
    half the image size): the masks come close to the truth, within the margin of the prior;
    the prior is recorded as a stage, and is off when the cue is left out."""
    rng = np.random.default_rng(3)
    cams, frames, truth, dis = _scene(rng, np.linspace(-0.3, -0.1, 12))
    half = [np.stack([cv2.resize(g.astype(np.uint8) * 255, (W // 2, H // 2),
                                 interpolation=cv2.INTER_AREA) for g in gs]) for gs in truth]
    plain = estimate_foreground(frames, cams, rng=np.random.default_rng(1))
    with_prior = estimate_foreground(frames, cams, rng=np.random.default_rng(1),
                                     person_prior=half)
    assert "prior" in with_prior.stages and "prior" not in plain.stages
    a, b = _mean_iou(plain.masks, truth), _mean_iou(with_prior.masks, truth)
    assert np.all(b > a + 0.1), (a, b)
    r = ForegroundParams().prior_margin
    for m, g in zip(with_prior.masks, truth):
        for t in range(len(g)):
            # the truth's upsampled half-size prior is within a pixel of the truth
            assert np.all(m[t] <= dilate_mask(g[t], r + 1))
            assert np.mean(g[t] & ~m[t]) < 0.002
    assert with_prior.masks[0][dis].mean() < 0.02
    off = estimate_foreground(frames, cams, rng=np.random.default_rng(1), person_prior=half,
                              cues=[c for c in CUES if c != "prior"])
    assert all(np.array_equal(x, y) for x, y in zip(off.masks, plain.masks))
    with pytest.raises(ValueError, match=r"person_prior\[1\] has 2 frames"):
        estimate_foreground(frames, cams, person_prior=[half[0], half[1][:2], None, None])


def test_scene_trim_drops_a_coarse_prior_s_spill():
    """A coarse prior (the truth dilated 5 px, as the landmark model's 256-pixel logits fill a
    body's concavities) with ``scene_trim``: its pixels that show the scene seen in the other
    frames go where they reach the mask's outside, where the subject itself passed in a
    quarter of the frames the prior claimed them (``scene_contrast``): the spill's inner part,
    more than half of it in every view; without the trim it all stays. A spill that the
    subject never covers looks like a still part of it (a ghost: it always matches its
    background) and stays. Off (the default), nothing is trimmed."""
    rng = np.random.default_rng(5)
    cams, frames, truth, _ = _scene(rng, np.linspace(-0.9, 0.9, 12), distractor=False)
    coarse = [np.stack([dilate_mask(g, 5) for g in gs]).astype(np.uint8) * 255 for gs in truth]
    r = ForegroundParams().prior_margin
    runs = {trim: estimate_foreground(frames, cams, rng=np.random.default_rng(1),
                                      person_prior=coarse,
                                      params=ForegroundParams(scene_trim=trim))
            for trim in (False, True)}
    default = estimate_foreground(frames, cams, rng=np.random.default_rng(1),
                                  person_prior=coarse)
    assert all(np.array_equal(a, b) for a, b in zip(default.masks, runs[False].masks))
    assert "scene" not in default.stages  # the stack is kept only for the trim
    # per camera: the masks' pixels beyond the prior margin, over the truth's
    spill = {trim: np.array([np.mean([np.mean(m & ~dilate_mask(g, r + 1)) / np.mean(g)
                                      for m, g in zip(ms, gs)])
                             for ms, gs in zip(res.masks, truth)])
             for trim, res in runs.items()}
    iou = {trim: _mean_iou(res.masks, truth) for trim, res in runs.items()}
    assert np.all(spill[False] > 0.3), spill
    assert np.all(spill[True] < 0.5 * spill[False]), spill
    assert np.all(iou[True] > iou[False] + 0.05), iou
    # the stage says where the frames show the scene: the spill's ring, not the body
    ring = [dilate_mask(g, 5) & ~dilate_mask(g, r + 1) for g in truth[1]]
    scene = runs[True].stages["scene"][1]
    assert np.mean([scene[t][ring[t]].mean() for t in range(12)]) > 0.9
    assert np.mean([scene[t][truth[1][t]].mean() for t in range(12)]) < 0.05


def test_scene_trim_keeps_what_is_enclosed_or_never_looked_different(moving):
    """``with_prior`` with a ``scene`` stack, on a still mask (a square body and a 3-pixel
    ring of its prior's spill, 12 frames): where the ring looked different from its background
    in a third of the frames (something passed there), it goes in the frames it shows the
    scene; a scene-coloured region the mask encloses stays; a ring that showed its background
    in every frame the prior claimed it is taken for a still part of the subject (its own
    ghost) and stays; and with ``scene_trim`` off, or a contrast above a third, nothing goes."""
    cams, frames, _, _ = moving
    T = 12
    body = np.zeros((40, 40), bool)
    body[10:30, 10:30] = True
    mask = dilate_mask(body, 3)
    ring, enclosed = mask & ~body, np.zeros_like(body)
    enclosed[16:24, 16:24] = True
    masks = [np.repeat(mask[None], T, axis=0)]
    still = [np.repeat((ring | enclosed)[None], T, axis=0)]
    passed = [still[0].copy()]
    passed[0][:4] = enclosed  # frames 0-3: something passed over the ring, it looked different

    def trimmed(scene, **params):
        est = SequenceForeground(frames, cams, params=ForegroundParams(**params),
                                 rng=np.random.default_rng(1))
        return est.with_prior(masks, masks, scene)[0]

    out = trimmed(passed, scene_trim=True)
    assert np.array_equal(out[4:], np.repeat((mask & ~ring)[None], T - 4, axis=0))
    assert np.array_equal(out[:4], masks[0][:4])
    assert out[:, enclosed].all()
    assert np.array_equal(trimmed(still, scene_trim=True), masks[0])
    assert np.array_equal(trimmed(passed), masks[0])  # off by default
    assert np.array_equal(trimmed(passed, scene_trim=True, scene_contrast=0.5), masks[0])


def test_outside_reaching_keeps_components_that_touch_the_outside():
    mask = np.zeros((20, 20), bool)
    mask[2:18, 2:18] = True
    mask[8:10, 8:10] = False  # a hole
    region = np.zeros_like(mask)
    region[2:5, 2:5] = True     # at the mask's edge: goes
    region[12:15, 12:15] = True  # enclosed: stays
    region[7:11, 7:11] = True    # around the hole (within the mask): goes
    region &= mask
    out = outside_reaching(region, mask)
    assert out[2:5, 2:5].all() and not out[12:15, 12:15].any()
    assert out[7:11, 7:11][mask[7:11, 7:11]].all()
    assert not outside_reaching(np.zeros_like(mask), mask).any()


def test_helpers_and_errors():
    cams = _cameras()
    b = shared_volume(cams)
    assert b.shape == (6,) and np.all(b[:3] < 0.0) and np.all(b[3:] > 0.5)
    m = fill_boxes((5, 6), np.array([[1, 1], [4, 3]]), np.array([[3, 2], [9, 9]]))
    assert m.sum() == 2 + 2 * 2 and m[1, 1] and m[4, 5] and not m[0, 0]
    s = np.zeros((5, 2, 2, 1), np.uint8)
    s[:, 0, 0, 0] = [10, 200, 12, 11, 200]
    ex = np.zeros((5, 2, 2), bool)
    ex[[1, 4], 0, 0] = True
    med, spread, known = masked_median(s, ex)
    assert med[0, 0, 0] == 11 and known.all()
    img = np.zeros((H, W, 3), np.uint8)
    with pytest.raises(ValueError, match="frames_by_camera has 1 cameras"):
        estimate_foreground([[img]], cams)
    with pytest.raises(ValueError, match="uniform scaling"):
        estimate_foreground([[np.zeros((H, W + 40, 3), np.uint8)]] * 4, cams)
    with pytest.raises(ValueError, match="same, non-zero number of frames"):
        estimate_foreground([[img, img]] + [[img]] * 3, cams)
    with pytest.raises(ValueError, match="cues"):
        estimate_foreground([[img, img]] * 4, cams, cues=("magic",))
    with pytest.raises(ValueError, match="ForegroundParams.passes"):
        ForegroundParams(passes=0)
    with pytest.raises(ValueError, match="ForegroundParams.ghost_recurrence"):
        ForegroundParams(ghost_recurrence=0.0)
    with pytest.raises(ValueError, match="ForegroundParams.ghost_gap"):
        ForegroundParams(ghost_gap=-0.1)
    with pytest.raises(ValueError, match="ForegroundParams.prior_margin"):
        ForegroundParams(prior_margin=-1)
    with pytest.raises(ValueError, match="ForegroundParams.scene_contrast"):
        ForegroundParams(scene_contrast=2.0)


def _pose2sim_cameras(folder, sizes):
    """Test-only reading of Calib_qualisys.toml (the package's reader is ingest's business)."""
    d = tomllib.loads((folder / "Calib_qualisys.toml").read_text())
    cams = []
    for (name, c), (w, h) in zip(sorted((k, v) for k, v in d.items() if k.startswith("cam")),
                                 sizes):
        R, _ = cv2.Rodrigues(np.array(c["rotation"], float))
        cams.append(Camera(name, "colour", w, h, np.array(c["matrix"]),
                           np.array(list(c["distortions"]) + [0.0]), R,
                           np.array(c["translation"])))
    return cams


def test_pose2sim_three_frames_end_to_end(shared):
    folder = shared / "video" / "pose2sim_balancing_4cam"
    frames = []
    for i in range(1, 5):
        cap = cv2.VideoCapture(str(folder / f"cam0{i}.mp4"))
        fr = []
        for k in (0, 50, 99):  # spread over the take: 3 consecutive frames hardly differ
            cap.set(cv2.CAP_PROP_POS_FRAMES, k)
            ok, img = cap.read()
            assert ok, f"cam0{i}.mp4: could not decode frame {k}"
            fr.append(img)
        cap.release()
        frames.append(fr)
    # encoders pad to 16: cam01/02 are 1080 wide where the calibration says 1088; K is kept
    cams = _pose2sim_cameras(folder, [(f[0].shape[1], f[0].shape[0]) for f in frames])
    res = estimate_foreground(frames, cams, params=ForegroundParams(work_size=320))
    frac = res.foreground_fraction()
    assert res.masks[0].shape == (3, 320, 180)
    # the person covers ~5-10 % of each portrait frame; 3 frames give a poor median, so only
    # plausibility is checked: something, and far from everything
    assert np.all(frac > 0.002) and np.all(frac < 0.35), frac
