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


def test_hold_seat_narrows_this_bodys_root_limits_only():
    """The seat box narrows the pelvis translation limits of one body in place (a state space
    built before sees it, as the trackers' samplers do); another body keeps its limits; a bad
    box is refused with its name."""
    import pytest

    from gltrack.sample import StateSpace
    from gltrack.track.bodies import SEAT_REACH, hold_seat, seat_of

    body, other = BodyModel.build(preset="upper"), BodyModel.build(preset="upper")
    space = StateSpace.from_dofs(body.dofs)
    x0 = body.dofs.zero(body.skeleton)
    x0[:3] = (0.2, 0.5, -0.3)
    seat = seat_of(x0)
    assert seat["reach"] == SEAT_REACH
    np.testing.assert_allclose(seat["low"], x0[:3] - SEAT_REACH)
    hold_seat(body, seat)
    far = np.repeat(x0[None], 2, axis=0)
    far[0, :3] += 1.0
    far[1, :3] -= 1.0
    for clamped in (space.clamp(far), body.dofs.validate(far)):
        np.testing.assert_allclose(clamped[0, :3], x0[:3] + SEAT_REACH)
        np.testing.assert_allclose(clamped[1, :3], x0[:3] - SEAT_REACH)
        np.testing.assert_allclose(clamped[:, 3:], far[:, 3:])  # rotations untouched
    assert np.all(other.dofs.upper[:3] > x0[:3] + 1.0)
    # a wider box never widens the limits
    hold_seat(body, seat_of(x0, 5.0))
    np.testing.assert_allclose(body.dofs.upper[:3], x0[:3] + SEAT_REACH)
    for bad in ({"low": [0, 0]}, {"low": [0, 0, 0], "high": [1, 1, -1]}, [1, 2, 3]):
        with pytest.raises(ValueError, match="body.json: field 'seat'"):
            hold_seat(other, bad, where="body.json: field 'seat'")


def test_a_seated_run_holds_the_pelvis_where_it_started_and_on_resume(tmp_path):
    """``track`` with the upper preset records the seat its start found in ``body.json`` and
    keeps every frame's pelvis in it, also after a resume, while the rendered subject slides
    0.3 m sideways (so the hold is what keeps it: the other joints still follow the arms)."""
    import json

    from gltrack.bench.multiview import RING, render_dataset
    from gltrack.bench.rigs import ring_cameras
    from gltrack.track.bodies import SEAT_REACH
    from gltrack.track.runner import track

    body = BodyModel.build(preset="upper")
    d = body.dofs
    n = 5
    P = np.repeat(d.zero(body.skeleton)[None], n, axis=0)
    P[:, 1] = 0.98
    P[:, 0] = np.linspace(0.0, 0.3, n)  # slides along x
    P[:, d.index("l_shoulder_rz")] = np.linspace(-1.2, -0.3, n)
    P = d.validate(P)
    ds = tmp_path / "ds"
    cams = ring_cameras((0.0, 0.9, 0.0), **dict(RING, radius=3.0))
    render_dataset(ds, body, P, cams, 30.0, np.random.default_rng(1))
    out = tmp_path / "res"
    opts = {"particles": 40, "tile": 64, "appearance": False}
    track(ds, "hps", out, options=opts, init="groundtruth", body="dataset", progress=False)
    seat = json.loads((out / "body.json").read_text())["seat"]
    np.testing.assert_allclose(seat["low"], P[0, :3] - SEAT_REACH)
    params = np.array([json.loads(line)["params"] for line in open(out / "frames.jsonl")])
    assert len(params) == n
    assert np.all(np.abs(params[:, :3] - P[0, :3]) <= SEAT_REACH + 1e-9), params[:, :3]
    assert params[-1, 0] > P[0, 0] + 0.05  # it leans on the box's edge towards the subject
    # resume after two frames: the seat comes back from body.json
    lines = open(out / "frames.jsonl").read().splitlines(keepends=True)
    (out / "frames.jsonl").write_text("".join(lines[:2]))
    for f in out.glob("checkpoint*"):
        f.unlink()
    track(ds, "hps", out, options=opts, init="groundtruth", body="dataset", progress=False,
          resume=True)
    params = np.array([json.loads(line)["params"] for line in open(out / "frames.jsonl")])
    assert len(params) == n
    assert np.all(np.abs(params[:, :3] - P[0, :3]) <= SEAT_REACH + 1e-9), params[:, :3]
