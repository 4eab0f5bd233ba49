"""Colour-cluster appearance model: cluster bitmasks, human-colour table, init and refinement."""
import cv2
import numpy as np
import pytest

from gltrack.body.dofs import make_dofs
from gltrack.body.kinematics import Kinematics
from gltrack.body.mesh import PARTS, make_body_mesh
from gltrack.body.skeleton import default_skeleton
from gltrack.camera import look_at_camera
from gltrack.observe import hls
from gltrack.observe.appearance import (AppearanceModel, AppearanceParams, build_clusters,
                                        human_lut_from_bits)
from gltrack.render import reference as ref
from gltrack.render.engine import ScoringEngine


def bins_of(mask):
    return [b for b in range(32) if (int(mask) >> b) & 1]


def centre_value(b):
    """Raw 0..255 value in the middle of bin b."""
    return 8 * b + 4


# ---------------------------------------------------------------------------------------------
# cluster construction on hand-made colour sets


def test_single_colour_cluster_is_its_voxel():
    v = np.array([[centre_value(10), centre_value(16), centre_value(20)]] * 5, np.uint8)
    cl = build_clusters(np.zeros(5, int), v, 2, AppearanceParams(min_halfwidth=0.5))
    assert [bins_of(m) for m in cl.bits[0]] == [[10], [16], [20]]
    wider = build_clusters(np.zeros(5, int), v, 2, AppearanceParams(min_halfwidth=1.0))
    assert [bins_of(m) for m in wider.bits[0]] == [[9, 10, 11], [15, 16, 17], [19, 20, 21]]


def test_hue_wraps_around():
    hues = np.array([centre_value(31), centre_value(0)] * 4)
    v = np.stack([hues, np.full(8, centre_value(16)), np.full(8, centre_value(20))], 1).astype(np.uint8)
    cl = build_clusters(np.zeros(8, int), v, 1, AppearanceParams(k=1.0, min_halfwidth=0.5))
    assert abs(((cl.centre[0, 0] + 16) % 32) - 16) < 1e-9     # the mean is at bin edge 0/32
    assert sorted(bins_of(cl.bits[0, 0])) == [0, 31]


def test_box_is_bounding_box_of_principal_axes(rng):
    """Extents against an independent construction from the same covariance."""
    n = 400
    t = rng.normal(size=n) * 2.0
    l = 16 + t + rng.normal(size=n) * 0.3
    s = 12 + t * 0.5 + rng.normal(size=n) * 0.3
    h = np.full(n, 5.5)
    v = np.clip(np.round(np.stack([h, l, s], 1) * 8), 0, 255).astype(np.uint8)
    k = 2.0
    cl = build_clusters(np.zeros(n, int), v, 1, AppearanceParams(k=k, min_halfwidth=0.25))
    x = v.astype(float) / 8
    C = np.cov(x.T, bias=True)
    lam, E = np.linalg.eigh(C)
    ends = np.concatenate([x.mean(0)[:, None] + sgn * k * np.sqrt(np.clip(lam, 0, None)) * E for sgn in (1, -1)], 1)
    for j in (1, 2):
        lo, hi = ends[j].min(), ends[j].max()
        want = [b for b in range(32) if b < hi and b + 1 > lo]
        assert bins_of(cl.bits[0, j]) == want
        assert hi - x[:, j].mean() < k * np.sqrt(C[j, j]) + 1e-9  # inside the ellipsoid's shadow
    assert bins_of(cl.bits[0, 0]) == [5]


def test_dark_grey_and_unknown_clusters():
    dark = np.array([[centre_value(b), centre_value(1), centre_value(25)] for b in (3, 17, 28)], np.uint8)
    grey = np.array([[centre_value(b), centre_value(16), centre_value(1)] for b in (3, 17, 28)], np.uint8)
    colour = np.array([[centre_value(8), centre_value(20), centre_value(20)]] * 3, np.uint8)
    tri = np.repeat([0, 1, 2], 3)
    cl = build_clusters(tri, np.concatenate([dark, grey, colour]), 5, AppearanceParams(min_halfwidth=0.5))
    allb = int(hls.ALL_BITS)
    assert int(cl.bits[0, 0]) == allb and int(cl.bits[0, 2]) == allb and bins_of(cl.bits[0, 1]) == [1]
    assert int(cl.bits[1, 0]) == allb and bins_of(cl.bits[1, 2]) == [1]
    assert bins_of(cl.bits[2, 0]) == [8]
    # triangles 3 and 4 were never seen: any hue/saturation, a lightness seen on the body
    assert not cl.known[3:].any() and cl.known[:3].all()
    for f in (3, 4):
        assert int(cl.bits[f, 0]) == allb and int(cl.bits[f, 2]) == allb
        assert bins_of(cl.bits[f, 1]) == [1, 16, 20]


def test_human_lut_equals_brute_force(rng):
    n = 300
    tri = rng.integers(0, 40, n)
    centres = rng.integers(0, 256, (40, 3))
    v = np.clip(centres[tri] + rng.normal(0, 5, (n, 3)), 0, 255).astype(np.uint8)
    cl = build_clusters(tri, v, 50, AppearanceParams(min_samples=4))
    lut = human_lut_from_bits(cl.bits, cl.known)
    ob = hls.HLS_BITS_LUT
    tb = cl.bits[cl.known]
    brute = np.zeros(32768, bool)
    for c in tb:
        brute |= np.all((ob & c) != 0, axis=1)
    assert np.array_equal(lut, brute)
    assert 0 < lut.sum() < lut.size
    assert not human_lut_from_bits(cl.bits, np.zeros(50, bool)).any()


# ---------------------------------------------------------------------------------------------
# a rendered synthetic frame painted with per-part colours

SIZE = 128  # = the engine tile, so the GPU and CPU sampling paths see the same pixels
BG_BGR = (60, 62, 60)  # dark grey: no hue, matches no part


def part_colours():
    hls_img = np.array([[[int(i * 256 / len(PARTS)) % 256, 128, 220] for i in range(len(PARTS))]], np.uint8)
    return cv2.cvtColor(hls_img, cv2.COLOR_HLS2BGR_FULL)[0].astype(float)


@pytest.fixture(scope="module")
def scene():
    skel = default_skeleton(1.75)
    dofs = make_dofs(skel, "full")
    kin = Kinematics(skel, dofs)
    mesh = make_body_mesh(skel, lod=0)
    cams = []
    for i, a in enumerate((0.4, 2.4, 4.4)):
        eye = (2.6 * np.sin(a), 1.1, 2.6 * np.cos(a))
        cams.append(look_at_camera(f"cam{i}", eye, (0, 0.9, 0), SIZE, SIZE, 50.0))
    p0 = dofs.zero(skel)
    truth = kin.skinning_matrices(p0[None])
    turned = p0.copy()
    turned[4] += np.pi  # about the vertical: same silhouette family, left and right swapped
    shifted = p0.copy()
    shifted[0] += 0.12
    wrong = kin.skinning_matrices(np.stack([turned, shifted]))
    rng = np.random.default_rng(3)
    face_colour = part_colours()[mesh.part[mesh.faces[:, 0]]]
    images, masks, tris = [], [], []
    for cam in cams:
        _, tri = ref.render_candidates(mesh, truth, cam.K, cam.R, cam.t, SIZE, SIZE)
        img = np.empty((SIZE, SIZE, 3))
        img[:] = BG_BGR
        img[tri[0] >= 0] = face_colour[tri[0][tri[0] >= 0]]
        img = np.clip(img + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8)
        images.append(img)
        masks.append(tri[0] >= 0)
        tris.append(tri[0])
    return dict(mesh=mesh, kin=kin, cams=cams, truth=truth, wrong=wrong, images=images,
                masks=masks, tris=tris, n_bones=len(skel.names))


def _ref_scores(sc, model, S):
    tb = model.tri_bits()
    out = np.zeros(len(S))
    for cam, img in zip(sc["cams"], sc["images"]):
        _, tri = ref.render_candidates(sc["mesh"], S, cam.K, cam.R, cam.t, SIZE, SIZE)
        ob = hls.observed_bits(img)
        out += [ref.appearance_score(t, ob, tb) for t in tri]
    return out


def test_init_scores_true_pose_highest(scene):
    sc = scene
    model = AppearanceModel.from_first_frame(sc["mesh"], sc["truth"][0], sc["cams"], sc["images"], sc["masks"])
    known = model.clusters.known
    assert 0.15 < known.mean() < 1.0  # small faces at 128 px get < min_samples pixels
    s_true, s_turned, s_shifted = _ref_scores(sc, model, np.concatenate([sc["truth"], sc["wrong"]]))
    body_px = sum(m.sum() for m in sc["masks"])
    assert s_true > 0.9 * body_px
    assert s_true > 3 * s_turned and s_true > 1.5 * s_shifted
    # the human table: body colours are human, the background is not
    for img, m in zip(sc["images"], sc["masks"]):
        hm = model.human_mask(img)
        assert hm[m].mean() > 0.95 and not hm[~m].any()


def test_gpu_sampling_and_engine_score(ctx, scene):
    sc = scene
    cpu = AppearanceModel.from_first_frame(sc["mesh"], sc["truth"][0], sc["cams"], sc["images"], sc["masks"])
    with ScoringEngine(ctx, sc["mesh"], sc["n_bones"], sc["cams"], tile=SIZE, reduction="mipmap") as eng:
        gpu = AppearanceModel.from_first_frame(sc["mesh"], sc["truth"][0], sc["cams"], sc["images"],
                                               sc["masks"], engine=eng)
        both = cpu.clusters.known & gpu.clusters.known
        assert both.sum() > 0.9 * max(cpu.clusters.known.sum(), gpu.clusters.known.sum())
        same = np.all(cpu.tri_bits()[both] == gpu.tri_bits()[both], axis=1)
        assert same.mean() > 0.9
        for c, img in enumerate(sc["images"]):
            eng.set_masks(c, sc["masks"][c])
            eng.set_appearance(c, hls.observed_bits(img), gpu.tri_bits())
        out = eng.score(np.concatenate([sc["truth"], sc["wrong"]]), ["appearance"])[:, :, 2].sum(1)
    assert out[0] > 3 * out[1] and out[0] > 1.5 * out[2]


def test_refine_accepts_close_and_rejects_far_colours(scene):
    sc = scene
    far = [np.where(m[..., None], 255 - img, img) for img, m in zip(sc["images"], sc["masks"])]
    adopting = AppearanceModel.from_first_frame(sc["mesh"], sc["truth"][0], sc["cams"], sc["images"],
                                                sc["masks"])
    unknown_before = ~adopting.clusters.known
    n_unknown_colours = unknown_before[adopting._tri].sum()
    added = adopting.refine(sc["truth"][0], sc["cams"], far, sc["masks"])
    # only triangles without a cluster take the inverted colours (as many as they had before)
    assert added == n_unknown_colours > 0
    params = AppearanceParams(adopt_unseen=False)
    model = AppearanceModel.from_first_frame(sc["mesh"], sc["truth"][0], sc["cams"], sc["images"],
                                             sc["masks"], params=params)
    n0, bits0, v0 = model.n_colours, model.tri_bits(), model.version
    assert model.refine(sc["truth"][0], sc["cams"], far, sc["masks"]) == 0
    assert model.n_colours == n0 and model.version == v0
    brighter = [np.where(m[..., None], np.clip(img.astype(int) + 5, 0, 255), img).astype(np.uint8)
                for img, m in zip(sc["images"], sc["masks"])]
    added = model.refine(sc["truth"][0], sc["cams"], brighter, sc["masks"])
    assert added > 0.8 * n0 and model.version == v0 + 1
    assert not np.array_equal(model.tri_bits(), bits0)
    seen = model.clusters.known
    assert (model.clusters.centre[seen, 1] > AppearanceModel.from_first_frame(
        sc["mesh"], sc["truth"][0], sc["cams"], sc["images"], sc["masks"]).clusters.centre[seen, 1]).mean() > 0.9


def test_sample_cap_keeps_newest(rng):
    class _Mesh:
        n_faces = 2
    params = AppearanceParams(max_samples=4, min_samples=1)
    for gen in (None, rng):
        m = AppearanceModel(_Mesh(), params, gen)
        m._add(np.zeros(3, np.int64), np.full((3, 3), 10, np.uint8))
        m._add(np.array([0, 0, 0, 1]), np.full((4, 3), 200, np.uint8))
        assert m.n_colours == 5 and np.bincount(m._tri).tolist() == [4, 1]
        if gen is None:
            assert (m._hls[m._tri == 0] == 200).sum() == 9  # three newest 200s, one old 10
