"""Joint-name maps, skeletons from BVH, retargeting (rotations and IK) and load_motion."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gltrack.body.dofs import make_dofs
from gltrack.body.kinematics import Kinematics
from gltrack.body.skeleton import JOINT_NAMES, PARENTS, default_skeleton
from gltrack.motion.bvh import Bvh, read_bvh, resample, write_bvh
from gltrack.motion.names import detect_convention, joint_map
from gltrack.motion.retarget import load_motion, retarget, retarget_error, skeleton_from_bvh

CLIPS = ("cmu_02_01_walk.bvh", "cmu_131_01_start_walk_stop_max.bvh",
         "cmu_131_03_start_hop_stop_max.bvh", "cmu_131_03_start_hop_stop_max_metres.bvh",
         "cmu_60_10_salsa_daz_metres.bvh")
IDENTITY = {n: n for n in JOINT_NAMES}

MB = ["Hips", "LHipJoint", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase", "RHipJoint",
      "RightUpLeg", "RightLeg", "RightFoot", "RightToeBase", "LowerBack", "Spine", "Spine1", "Neck",
      "Neck1", "Head", "LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand", "RightShoulder",
      "RightArm", "RightForeArm", "RightHand"]
MAX = ["Hips", "LHipJoint", "LeftHip", "LeftKnee", "LeftAnkle", "LeftToe", "RHipJoint", "RightHip",
       "RightKnee", "RightAnkle", "RightToe", "lowerback", "Chest", "Chest2", "lowerneck", "Neck",
       "Head", "LeftCollar", "LeftShoulder", "LeftElbow", "LeftWrist", "RightCollar",
       "RightShoulder", "RightElbow", "RightWrist"]
DAZ = ["hip", "abdomen", "chest", "neck", "head", "lCollar", "lShldr", "lForeArm", "lHand",
       "rCollar", "rShldr", "rForeArm", "rHand", "lButtock", "lThigh", "lShin", "lFoot",
       "rButtock", "rThigh", "rShin", "rFoot"]


# ---------------------------------------------------------------------- names
def test_conventions_detected_and_shoulder_trap():
    assert detect_convention(MB) == "motionbuilder"
    assert detect_convention(MAX) == "3dsmax"
    assert detect_convention(DAZ) == "daz"
    mb, mx, dz = joint_map(MB), joint_map(MAX), joint_map(DAZ)
    # "LeftShoulder" is the clavicle in MotionBuilder naming but the upper arm in 3ds Max naming
    assert mb["l_clavicle"] == "LeftShoulder" and mb["l_shoulder"] == "LeftArm"
    assert mx["l_clavicle"] == "LeftCollar" and mx["l_shoulder"] == "LeftShoulder"
    assert mx["r_elbow"] == "RightElbow" and mb["r_elbow"] == "RightForeArm"
    assert dz["l_hip"] == "lThigh" and dz["r_ankle"] == "rFoot" and dz["pelvis"] == "hip"
    assert set(mb) == set(JOINT_NAMES) and len(set(mb.values())) == len(JOINT_NAMES)
    # namespace prefixes and case are ignored
    pref = joint_map(["mixamorig:" + n.upper() for n in MB])
    assert pref["l_knee"] == "mixamorig:LEFTLEG"


def test_mapping_override_and_errors():
    m = joint_map(MB, mapping={"head": "Neck1"})
    assert m["head"] == "Neck1" and m["neck"] == "Neck"
    with pytest.raises(ValueError, match=r"cannot map canonical joints \['l_elbow'\]"):
        joint_map([n for n in MB if n != "LeftForeArm"])
    with pytest.raises(ValueError, match="unknown joint-name convention"):
        joint_map(["a", "b", "c"])
    with pytest.raises(ValueError, match="not in the file"):
        joint_map(MB, mapping={"head": "Skull"})
    with pytest.raises(ValueError, match="unknown canonical joints"):
        joint_map(MB, mapping={"skull": "Head"})
    assert joint_map(list(JOINT_NAMES), mapping=IDENTITY) == IDENTITY


# ---------------------------------------------------------------------- synthetic BVH from gltrack
def _bvh_from_params(skel, dofs, params, orders, fps=30.0):
    """A BVH with the gltrack joints, whose motion is ``params`` written in other Euler orders."""
    L = Kinematics(skel, dofs).local_rotations(dofs.validate(params, clamp=False))
    channels, cols = [], [params[:, :3]]
    for j, order in enumerate(orders):
        ch = [f"{a}rotation" for a in order]
        channels.append((["Xposition", "Yposition", "Zposition"] if j == 0 else []) + ch)
        cols.append(Rotation.from_matrix(L[:, j]).as_euler(order, degrees=True))
    ends = {n: skel.ends[j] for j, n in enumerate(JOINT_NAMES) if np.any(skel.ends[j])}
    return Bvh(list(JOINT_NAMES), np.array(PARENTS), skel.offsets, channels, ends, 1.0 / fps,
               np.concatenate(cols, axis=1))


def _random_params(dofs, skel, rng, T):
    lo = np.where(np.isfinite(dofs.lower), dofs.lower, -1.0)
    hi = np.where(np.isfinite(dofs.upper), dofs.upper, 1.0)
    p = rng.uniform(0.5 * lo, 0.5 * hi, size=(T, dofs.size))
    p[:, :3] = skel.offsets[0] + rng.normal(0, 0.3, size=(T, 3))
    return p


@pytest.mark.parametrize("orders", ["XYZ", "ZYX", "YZX"])
def test_rotations_recover_known_params_from_any_channel_order(rng, orders):
    skel = default_skeleton(1.7)
    dofs = make_dofs(skel, "full")
    truth = _random_params(dofs, skel, rng, 40)
    bvh = _bvh_from_params(skel, dofs, truth, [orders] * len(JOINT_NAMES))
    params, report = retarget(bvh, skel, dofs, mapping=IDENTITY, return_report=True)
    assert report["clamped"] == 0
    np.testing.assert_allclose(params, truth, atol=1e-7)
    # gltrack FK of the result reproduces the BVH's own FK (two implementations)
    err = retarget_error(bvh, skel, dofs, params, mapping=IDENTITY)
    assert err["max_mm"] < 1e-4
    # a different pose is measurably wrong
    worse = retarget_error(bvh, skel, dofs, np.roll(params, 1, axis=0), mapping=IDENTITY)
    assert worse["mean_mm"] > 10


def test_clamping_is_counted_and_angles_unwrapped(rng):
    skel = default_skeleton(1.7)
    dofs = make_dofs(skel, "full")
    T = 60
    truth = np.tile(dofs.zero(skel), (T, 1))
    yaw = np.linspace(0, 3 * np.pi, T)  # 1.5 turns: Euler output wraps, params must not
    truth[:, dofs.index("pelvis_ry")] = yaw
    knee = dofs.index("l_knee_rx")
    truth[:, knee] = np.linspace(0.0, 3.0, T)  # flexed past 90 deg, and past the 2.6 limit
    bvh = _bvh_from_params(skel, dofs, truth, ["ZXY"] * len(JOINT_NAMES))
    params, report = retarget(bvh, skel, dofs, mapping=IDENTITY, return_report=True)
    np.testing.assert_allclose(params[:, dofs.index("pelvis_ry")], yaw, atol=1e-9)
    over = int((truth[:, knee] > dofs.upper[knee]).sum())
    assert over > 0 and report["clamped"] == over
    assert report["clamped_per_dof"] == {"l_knee_rx": over}
    np.testing.assert_allclose(params[:, knee], np.minimum(truth[:, knee], dofs.upper[knee]),
                               atol=1e-9)


# ---------------------------------------------------------------------- real clips
@pytest.fixture(scope="module")
def clips(shared):
    return {n: read_bvh(shared / "mocap" / n) for n in CLIPS}


def test_real_clip_conventions(clips):
    conv = {n: detect_convention(b.names) for n, b in clips.items()}
    assert conv == {CLIPS[0]: "motionbuilder", CLIPS[1]: "3dsmax", CLIPS[2]: "3dsmax",
                    CLIPS[3]: "3dsmax", CLIPS[4]: "daz"}


def test_skeleton_from_bvh_geometry(clips):
    b = clips["cmu_131_03_start_hop_stop_max_metres.bvh"]  # arms hang down in its rest pose
    m = joint_map(b.names)
    rest_b = b.rest_positions()[[b.index(m[c]) for c in JOINT_NAMES]]
    exact = skeleton_from_bvh(b, rest="bvh")
    pos = exact.rest_positions()
    np.testing.assert_allclose(pos - pos[0], rest_b - rest_b[0], atol=1e-12)
    tp = skeleton_from_bvh(b)
    # same bone lengths, limbs re-aimed to the T-pose
    np.testing.assert_allclose(np.linalg.norm(tp.offsets[1:], axis=1),
                               np.linalg.norm(exact.offsets[1:], axis=1), atol=1e-12)
    for name, d in (("l_elbow", [1, 0, 0]), ("r_wrist", [-1, 0, 0]), ("l_knee", [0, -1, 0]),
                    ("r_ankle", [0, -1, 0])):
        o = tp.offsets[tp.index(name)]
        np.testing.assert_allclose(o / np.linalg.norm(o), d, atol=1e-9)
    assert exact.offsets[exact.index("l_elbow")][1] < -0.2  # the file's arm hangs down
    tpos = tp.rest_positions() + tp.ends
    assert abs(min(tp.rest_positions()[:, 1].min(), tpos[:, 1].min())) < 1e-9  # stands on y=0
    assert 1.1 < tp.height() < 2.0
    assert tp.ends[tp.index("head")][1] > 0.05 and tp.ends[tp.index("l_ankle")][2] > 0.05


def test_retarget_error_per_clip_and_preset(clips):
    results = {}
    for name, b in clips.items():
        skel = skeleton_from_bvh(b)
        for preset in ("full", "38", "25"):
            dofs = make_dofs(skel, preset)
            params = retarget(b, skel, dofs)
            assert params.shape == (b.n_frames, dofs.size) and np.all(np.isfinite(params))
            assert np.all(params >= dofs.lower) and np.all(params <= dofs.upper)
            results[name, preset] = retarget_error(b, skel, dofs, params)
    for name in CLIPS:
        full = results[name, "full"]
        assert full["mean_mm"] < 10.0, (name, full)
        assert full["per_joint_mm"]["pelvis"] < 1e-6  # root translation is copied
        assert results[name, "25"]["mean_mm"] > full["mean_mm"]
        assert results[name, "38"]["mean_mm"] > full["mean_mm"]


def test_rest_bvh_body_also_retargets(clips):
    b = clips["cmu_02_01_walk.bvh"]
    skel = skeleton_from_bvh(b, rest="bvh")
    dofs = make_dofs(skel, "full")
    e = retarget_error(b, skel, dofs, retarget(b, skel, dofs))
    assert e["mean_mm"] < 10.0


def test_ik_improves_reduced_preset(clips):
    b = clips["cmu_02_01_walk.bvh"].select_frames(slice(1, 25))
    skel = skeleton_from_bvh(b)
    dofs = make_dofs(skel, "25")
    rot = retarget_error(b, skel, dofs, retarget(b, skel, dofs))
    ik_params = retarget(b, skel, dofs, method="ik")
    assert np.all(ik_params >= dofs.lower) and np.all(ik_params <= dofs.upper)
    ik = retarget_error(b, skel, dofs, ik_params)
    assert ik["mean_mm"] < 0.8 * rot["mean_mm"], (ik["mean_mm"], rot["mean_mm"])
    # a body with other proportions: IK still beats copying rotations
    other = default_skeleton(1.6)
    od = make_dofs(other, "full")
    e_rot = retarget_error(b, other, od, retarget(b, other, od))["mean_mm"]
    e_ik = retarget_error(b, other, od, retarget(b, other, od, method="ik", max_nfev=10))["mean_mm"]
    assert e_ik < e_rot


def test_load_motion_cuts_and_resamples(shared, tmp_path):
    path = shared / "mocap" / "cmu_02_01_walk.bvh"
    skel, dofs, params, fps = load_motion(path, preset="38", fps=30, frames=(1, 121))
    assert fps == 30 and dofs.preset == "38"
    assert params.shape == (30, dofs.size)
    # same as doing it by hand
    b = resample(read_bvh(path).select_frames(slice(1, 121)), 120, 30)
    np.testing.assert_allclose(params, retarget(b, skel, dofs), atol=1e-12)
    # root translation of output frame k is the BVH root at source frame 1 + 4k
    P = read_bvh(path).fk(frames=slice(1, 121, 4))[0]
    np.testing.assert_allclose(params[:, :3], P[:, 0], atol=1e-12)
    _, _, p_all, fps_all = load_motion(path, frames="1:")
    assert fps_all == pytest.approx(120, rel=1e-4) and p_all.shape[0] == 343
    # a written, re-read clip gives the same motion
    out = tmp_path / "w.bvh"
    write_bvh(out, read_bvh(path))
    _, _, p_back, _ = load_motion(out, preset="38", fps=30, frames=(1, 121))
    np.testing.assert_allclose(p_back, params, atol=1e-6)


def test_results_bvh_reads_back_as_gltrack_convention(tmp_path, rng):
    """poses.bvh written by gltrack itself retargets onto the same body exactly."""
    from gltrack.body.model import BodyModel
    from gltrack.export.bvh import write_params_bvh
    from gltrack.motion.names import detect_convention
    from gltrack.motion.retarget import load_motion

    body = BodyModel.build()
    P = body.dofs.validate(body.dofs.zero(body.skeleton) + rng.normal(size=(6, body.dofs.size)) * 0.3)
    path = tmp_path / "poses.bvh"
    write_params_bvh(path, body, P, 30.0)
    assert detect_convention(body.skeleton.names) == "gltrack"
    sk, dofs, params, fps = load_motion(path, preset="full")
    assert params.shape == P.shape and fps == pytest.approx(30.0)
