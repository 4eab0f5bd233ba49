"""The ``upper`` DOF preset: a subject seen from the waist up (seated behind a desk). The legs
keep their rest pose and their surface is left out of the body's mesh, so they are neither
drawn nor scored."""
import numpy as np

from gltrack.body.dofs import HIDDEN_PARTS
from gltrack.body.mesh import PARTS
from gltrack.body.model import BodyModel
from gltrack.data.results import load_body_record, save_body_record
from gltrack.render.engine import ScoringEngine
from gltrack.render.reference import render_candidates

LEGS = [PARTS.index(p) for p in HIDDEN_PARTS["upper"]]


def test_upper_preset_fixes_the_legs_and_leaves_their_surface_out(tmp_path):
    full, upper = BodyModel.build(), BodyModel.build(preset="upper")
    legs = [n for n in full.dofs.names if n.split("_r")[0] in
            ("l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle")]
    assert legs and not set(legs) & set(upper.dofs.names)
    assert set(upper.dofs.names) == set(full.dofs.names) - set(legs)
    # no face of the shown surface touches a leg vertex; the rest of the surface is all there
    assert not np.isin(upper.mesh.part[upper.mesh.faces], LEGS).any()
    kept = ~np.isin(full.mesh.part[full.mesh.faces], LEGS).any(axis=1)
    assert upper.mesh.n_faces == kept.sum() < full.mesh.n_faces
    np.testing.assert_array_equal(np.sort(upper.mesh.vertices[upper.mesh.faces].reshape(-1, 9), axis=0),
                                  np.sort(full.mesh.vertices[full.mesh.faces[kept]].reshape(-1, 9), axis=0))
    # markers still follow the (fixed) legs, and the joints are the full body's at rest legs
    assert upper.markers.names == full.markers.names
    x = upper.dofs.zero(upper.skeleton)
    np.testing.assert_allclose(upper.joints(x[None]), full.joints(full.dofs.zero(full.skeleton)[None]))
    # preset changes go both ways; the record rebuilds the same shown surface
    assert upper.with_preset("full").mesh.n_faces == full.mesh.n_faces
    assert full.with_preset("upper").mesh.n_faces == upper.mesh.n_faces
    save_body_record(tmp_path, upper, "file")
    again, rec = load_body_record(tmp_path)
    assert rec["preset"] == "upper" and again.mesh.n_faces == upper.mesh.n_faces


def test_hidden_legs_are_out_of_the_silhouette_cost(ctx):
    """Erasing the legs from the observed mask (a desk hides them) costs the full body its
    legs' pixels; the upper body has no legs to pay for, and its torso still counts."""
    from gltrack.bench.rigs import ring_cameras

    full, upper = BodyModel.build(), BodyModel.build(preset="upper")
    cam = ring_cameras((0.0, 0.9, 0.0), n=1, radius=3.0)[0].scaled(64, 64)
    x_full = full.dofs.zero(full.skeleton)
    x_full[1] = 0.98
    x_up = upper.dofs.zero(upper.skeleton)
    x_up[1] = 0.98
    z, _ = render_candidates(full.mesh, full.skinning(x_full[None]), cam.K, cam.R, cam.t, 64, 64)
    seen = z[0] > 0
    rows = np.nonzero(seen.any(axis=1))[0]
    desk = np.zeros_like(seen)
    desk[(rows.min() + rows.max()) // 2:] = True  # the lower half of the person is hidden
    hidden = seen & ~desk

    def xor(body, x, mask):
        eng = ScoringEngine(ctx, body.mesh, body.skeleton.n_joints, [cam], tile=64)
        try:
            eng.set_masks(0, mask, np.zeros_like(mask))
            return float(eng.score(body.skinning(x[None]), ["silhouette"])[0, 0, 1])
        finally:
            eng.release()

    # the full body pays for legs the mask no longer shows; the upper body has none to pay for
    assert xor(full, x_full, hidden) > xor(full, x_full, seen) + 20
    assert xor(upper, x_up, hidden) < xor(full, x_full, hidden) - 20
    # and the upper body is still fitted: its torso moved aside costs
    torso_off = x_up.copy()
    torso_off[0] += 0.3
    assert xor(upper, torso_off, hidden) > xor(upper, x_up, hidden) + 20


def test_upper_preset_keeps_the_seated_pelvis_upright():
    """The seated preset limits the pelvis' tilt (pitch and roll) to 0.5 rad and leaves its
    turn free; the full body's pelvis is free in every angle. A pose tilted beyond the limit
    is clipped to it."""
    up = BodyModel.build(None, "upper").dofs
    full = BodyModel.build(None, "full").dofs
    for name in ("pelvis_rx", "pelvis_rz"):
        i = up.index(name)
        assert (up.lower[i], up.upper[i]) == (-0.5, 0.5)
        assert np.isinf(full.lower[full.index(name)]) and np.isinf(full.upper[full.index(name)])
    assert np.isinf(up.upper[up.index("pelvis_ry")])
    x = up.zero(BodyModel.build(None, "upper").skeleton)
    x[up.index("pelvis_rx")], x[up.index("pelvis_ry")] = -1.1, 2.5
    v = up.validate(x)[0]
    assert v[up.index("pelvis_rx")] == -0.5 and v[up.index("pelvis_ry")] == 2.5
    # every other limit is the full preset's
    for i, n in enumerate(up.names):
        if n not in ("pelvis_rx", "pelvis_rz"):
            j = full.index(n)
            assert (up.lower[i], up.upper[i]) == (full.lower[j], full.upper[j]), n
