"""Triangulation of labelled views (:func:`gltrack.camera.triangulate`) and the hand-labelled
references of the shared takes (``scripts/labelled_reference.py``)."""
import dataclasses
import importlib.util

import numpy as np
import pytest

from gltrack.camera import look_at_camera, triangulate

from conftest import REPO


def rig():
    """Four distorted cameras around a person-sized volume."""
    cams = []
    for k, (x, z) in enumerate([(3, 0), (0, 3), (-3, 0.5), (0.5, -3)]):
        c = look_at_camera(f"c{k}", (x, 1.6, z), (0, 1.0, 0), 640, 480, 50)
        cams.append(dataclasses.replace(c, dist=np.array([-0.12, 0.05, 0.001, -0.002, 0.0])))
    return cams


def test_triangulation_recovers_points_through_the_lens():
    cams = rig()
    rng = np.random.default_rng(0)
    X = rng.uniform([-0.5, 0.0, -0.5], [0.5, 1.9, 0.5], size=(20, 3))
    uv = np.stack([c.project(X) for c in cams])
    P, r = triangulate(cams, uv)
    np.testing.assert_allclose(P, X, atol=1e-7)
    assert np.nanmax(r) < 1e-5
    # a point two cameras do not see is found from the other two; one view is not enough
    uv[:2, 3] = np.nan
    uv[1:, 4] = np.nan
    P, r = triangulate(cams, uv)
    np.testing.assert_allclose(P[3], X[3], atol=1e-7)
    assert np.isnan(P[4]).all() and np.isnan(r[:, 4]).all() and np.isnan(r[:2, 3]).all()
    # ignoring the lens (distort=False on distorted pixels) moves the points: the lens matters
    P0, _ = triangulate(cams, np.stack([c.project(X) for c in cams]), distort=False)
    assert np.abs(P0 - X).max() > 0.003
    # pixel noise gives millimetres, and residuals of the noise's size
    noisy = np.stack([c.project(X) for c in cams]) + rng.normal(scale=1.0, size=(4, 20, 2))
    P, r = triangulate(cams, noisy)
    assert np.abs(P - X).max() < 0.02 and 0.1 < np.nanmedian(r) < 3.0
    with pytest.raises(ValueError, match="uv must be"):
        triangulate(cams, uv[:3])


def test_points_are_triangulated_independently_of_each_other():
    """All points are solved in one batch: each noisy point, seen by its own subset of the
    views, comes out as it does alone with only the cameras that see it."""
    cams = rig()
    rng = np.random.default_rng(1)
    X = rng.uniform([-0.5, 0.0, -0.5], [0.5, 1.9, 0.5], size=(12, 3))
    uv = np.stack([c.project(X) for c in cams]) + rng.normal(scale=2.0, size=(4, 12, 2))
    uv[rng.random((4, 12)) < 0.3] = np.nan
    P, r = triangulate(cams, uv)
    for n in range(len(X)):
        views = np.flatnonzero(np.isfinite(uv[:, n, 0]))
        if len(views) < 2:
            assert np.isnan(P[n]).all()
            continue
        p1, r1 = triangulate([cams[c] for c in views], uv[views, n:n + 1])
        np.testing.assert_allclose(P[n], p1[0], atol=1e-9)
        np.testing.assert_allclose(r[views, n], r1[:, 0], atol=1e-6)
    assert (np.isfinite(P).all(axis=1)).sum() >= 6  # most points seen twice or more


def _script():
    spec = importlib.util.spec_from_file_location("labelled_reference",
                                                  REPO / "scripts" / "labelled_reference.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


#: each keypoints file, its cameras and the bones (joint pair, metres) every frame must give
KEYPOINTS = {
    "pose2sim_balancing_keypoints.json": (
        ("cam_01", "cam_02", "cam_03", "cam_04"),
        {("l_hip", "l_knee"): (0.3, 0.55), ("r_hip", "r_knee"): (0.3, 0.55),
         ("l_knee", "l_ankle"): (0.3, 0.55), ("r_knee", "r_ankle"): (0.3, 0.55)}),
    "caliscope_4cam_keypoints.json": (
        ("cam0", "cam1", "cam2", "cam3"),
        {("l_shoulder", "l_elbow"): (0.22, 0.38), ("r_shoulder", "r_elbow"): (0.22, 0.38),
         ("l_elbow", "l_wrist"): (0.18, 0.34), ("r_elbow", "r_wrist"): (0.18, 0.34),
         ("l_shoulder", "r_shoulder"): (0.25, 0.45)}),
}


@pytest.mark.parametrize("name", sorted(KEYPOINTS))
def test_hand_labels_of_a_shared_take_agree_across_views(shared, tmp_path, name):
    """The labelled joints triangulate consistently (every view within 40 px of the point the
    others agree on), give plausible bones, and their left and right are the same limbs in
    every view: exchanging them in any one view makes the views disagree several times more."""
    import json

    from gltrack.data.calibration import load_any_calibration

    mod = _script()
    path = REPO / "scripts" / "data" / name
    labels = mod.load_labels(path)
    calib = shared / labels["take"].removeprefix("../shared/") / labels["calibration"]
    cams = load_any_calibration(calib)
    frames, pts, res = mod.reference_points(labels, cams)
    assert len(frames) == 5 and np.isfinite(pts).all()
    assert np.nanmax(res) < 40 and np.nanmedian(res) < 15
    J = labels["joints"]
    views, bones = KEYPOINTS[name]
    for (a, b), (lo, hi) in bones.items():
        d = np.linalg.norm(pts[:, J.index(a)] - pts[:, J.index(b)], axis=1)
        assert np.all((d > lo) & (d < hi)), (a, b, d)
    if "l_ankle" in J:
        ankles = pts[:, [J.index("l_ankle"), J.index("r_ankle")], 2]   # Z up, floor near 0
        assert np.all(ankles.min(axis=1) < 0.25) and np.all(ankles > 0.0)
    swap = [J.index(("r_" + j[2:]) if j.startswith("l_") else ("l_" + j[2:]))
            if j[:2] in ("l_", "r_") else J.index(j) for j in J]
    for cam in views:
        mixed = json.loads(json.dumps(labels))
        for f in mixed["frames"].values():
            v = f[cam]
            f[cam] = {J[i]: v[J[s]] for i, s in enumerate(swap)}
        assert np.nansum(mod.reference_points(mixed, cams)[2]) > 3 * np.nansum(res), cam
    # and the script writes a TRC that eval's reader takes, in either axes
    from gltrack.export.trc import opensim_axes, read_trc

    for axes in ("opensim", "calibration"):
        out = tmp_path / f"{axes}.trc"
        assert mod.main(["--keypoints", str(path), "--shared", str(shared), "--axes", axes,
                         "--out", str(out)]) == 0
        trc = read_trc(out)
        assert trc["names"] == [mod.P2S_NAMES[j] for j in J]
        assert trc["frame"].tolist() == [f + 1 for f in frames]
        np.testing.assert_allclose(trc["time"], np.array(frames) / labels["fps"], atol=1e-5)
        M = opensim_axes(labels["up"]) if axes == "opensim" else np.eye(3)
        np.testing.assert_allclose(trc["points"][:, 0] / 1000.0, pts[:, 0] @ M.T, atol=1e-4)


def test_labelled_reference_rejects_an_incomplete_keypoints_file(tmp_path, capsys):
    """A keypoints file without a field the TRC needs is refused with the file and the field."""
    mod = _script()
    bad = tmp_path / "kp.json"
    bad.write_text('{"take": "x", "calibration": "c.toml", "up": "z", "joints": ["nose"], '
                   '"frames": {}}')
    assert mod.main(["--keypoints", str(bad), "--out", str(tmp_path / "r.trc")]) == 1
    err = capsys.readouterr().err
    assert str(bad) in err and "'fps'" in err
    bad.write_text('{"take": "x", "calibration": "c.toml", "fps": 6, "up": "z", '
                   '"joints": ["chin"], "frames": {}}')
    assert mod.main(["--keypoints", str(bad), "--out", str(tmp_path / "r.trc")]) == 1
    assert "'chin'" in capsys.readouterr().err
    assert not (tmp_path / "r.trc").exists()
