"""Triangulation of labelled views (:func:`gltrack.camera.triangulate`) and the hand-labelled
reference of the shared Pose2Sim take (``scripts/pose2sim_reference.py``)."""
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


def _script():
    spec = importlib.util.spec_from_file_location("pose2sim_reference",
                                                  REPO / "scripts" / "pose2sim_reference.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_hand_labels_of_the_pose2sim_take_agree_across_views(shared, tmp_path):
    """The labelled joints triangulate consistently (every view within 40 px of the point the
    others agree on), give plausible bones, and their left and right are the same limbs in
    every view: exchanging them in any one view makes the views disagree several times more."""
    import json

    from gltrack.data.calibration import load_any_calibration

    mod = _script()
    labels = json.loads(mod.LABELS.read_text())
    calib = shared / "video" / "pose2sim_balancing_4cam" / labels["calibration"]
    cams = load_any_calibration(calib)
    frames, pts, res = mod.reference_points(labels, cams)
    assert frames == [10, 30, 50, 70, 90]
    assert np.nanmax(res) < 40 and np.nanmedian(res) < 15
    J = labels["joints"]
    seg = lambda a, b: np.linalg.norm(pts[:, J.index(a)] - pts[:, J.index(b)], axis=1)  # noqa: E731
    for side in "lr":
        assert np.all((seg(f"{side}_hip", f"{side}_knee") > 0.3)
                      & (seg(f"{side}_hip", f"{side}_knee") < 0.55))
        assert np.all((seg(f"{side}_knee", f"{side}_ankle") > 0.3)
                      & (seg(f"{side}_knee", f"{side}_ankle") < 0.55))
    ankles = pts[:, [J.index("l_ankle"), J.index("r_ankle")], 2]   # Z up, floor near 0
    assert np.all(ankles.min(axis=1) < 0.25) and np.all(ankles > 0.0)
    swap = [J.index(("r_" + j[2:]) if j.startswith("l_") else ("l_" + j[2:]))
            if j[:2] in ("l_", "r_") else J.index(j) for j in J]
    for cam in ("cam_01", "cam_02", "cam_03", "cam_04"):
        mixed = json.loads(json.dumps(labels))
        for f in mixed["frames"].values():
            v = f[cam]
            f[cam] = {J[i]: v[J[s]] for i, s in enumerate(swap)}
        assert np.nansum(mod.reference_points(mixed, cams)[2]) > 3 * np.nansum(res), cam
    # and the script writes a TRC that eval's reader takes
    assert mod.main(["--shared", str(shared), "--out", str(tmp_path / "ref.trc")]) == 0
    from gltrack.export.trc import read_trc

    trc = read_trc(tmp_path / "ref.trc")
    assert trc["names"][1] == "LShoulder" and trc["frame"].tolist() == [11, 31, 51, 71, 91]
    np.testing.assert_allclose(trc["time"], np.array(frames) / 60.0, atol=1e-5)
