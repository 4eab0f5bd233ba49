"""BVH reader/writer, forward kinematics, unit detection and resampling."""
import re

import numpy as np
import pytest

from gltrack.motion.bvh import CMU_UNIT, Bvh, read_bvh, resample, write_bvh

CLIPS = {
    "cmu_02_01_walk.bvh": CMU_UNIT,
    "cmu_131_01_start_walk_stop_max.bvh": CMU_UNIT,
    "cmu_131_03_start_hop_stop_max.bvh": CMU_UNIT,
    "cmu_131_03_start_hop_stop_max_metres.bvh": 1.0,
    "cmu_60_10_salsa_daz_metres.bvh": 1.0,
}

# Two frames; lengths in centimetres (rest height 170 cm); odd whitespace and brace placement on
# purpose; every joint uses a different rotation order.
TINY = """HIERARCHY
ROOT root
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT up{
\tOFFSET 0   80 0
\t\tCHANNELS 3 Xrotation Yrotation Zrotation
    JOINT top
    {
      OFFSET 0 10 0
      CHANNELS 3 Yrotation Zrotation Xrotation
      End Site
      {
        OFFSET 0 0 10
      }
    }
  }
  JOINT leg
  {
    OFFSET 10 -70 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site { OFFSET 0 -20 0 }
  }
}
MOTION
Frames:   2
Frame Time: 0.0333333
1 90 2   0 0 0   0 0 0   0 0 0   0 0 0
-5 95 3   90 0 0   30 20 10   15 25 35   0 0 90
"""


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _write(tmp_path, text, name="t.bvh"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_tiny_hierarchy_channels_and_units(tmp_path):
    b = read_bvh(_write(tmp_path, TINY))
    assert b.names == ["root", "up", "top", "leg"]
    assert list(b.parents) == [-1, 0, 1, 0]
    assert [b.rotation_order(j) for j in range(4)] == ["ZXY", "XYZ", "YZX", "ZYX"]
    assert b.scale_applied == pytest.approx(0.01)  # 170 "units" tall: centimetres
    np.testing.assert_allclose(b.offsets[3], [0.1, -0.7, 0.0])
    np.testing.assert_allclose(b.end_sites["top"], [0, 0, 0.1])
    np.testing.assert_allclose(b.end_sites["leg"], [0, -0.2, 0])
    assert b.motion.shape == (2, 15) and b.frame_time == pytest.approx(0.0333333)
    np.testing.assert_allclose(b.motion[1, :3], [-0.05, 0.95, 0.03])  # positions scaled
    np.testing.assert_allclose(b.motion[1, 3:], [90, 0, 0, 30, 20, 10, 15, 25, 35, 0, 0, 90])
    raw = read_bvh(_write(tmp_path, TINY), scale=1.0)
    assert raw.scale_applied == 1.0 and raw.offsets[1, 1] == 80.0


def test_fk_matches_hand_written_matrices(tmp_path):
    b = read_bvh(_write(tmp_path, TINY))
    P, W = b.fk()
    d = np.radians
    # frame 1 by hand: channel order is the multiplication order
    R0 = _rz(d(90)) @ _rx(d(0)) @ _ry(d(0))
    R1 = _rx(d(30)) @ _ry(d(20)) @ _rz(d(10))
    R2 = _ry(d(15)) @ _rz(d(25)) @ _rx(d(35))
    R3 = _rz(d(0)) @ _ry(d(0)) @ _rx(d(90))
    p0 = np.array([-0.05, 0.95, 0.03])
    p1 = p0 + R0 @ [0, 0.8, 0]
    p2 = p1 + R0 @ R1 @ [0, 0.1, 0]
    p3 = p0 + R0 @ [0.1, -0.7, 0]
    np.testing.assert_allclose(P[1], [p0, p1, p2, p3], atol=1e-12)
    np.testing.assert_allclose(W[1, 2], R0 @ R1 @ R2, atol=1e-12)
    np.testing.assert_allclose(W[1, 3], R0 @ R3, atol=1e-12)
    tips = b.end_site_positions()
    np.testing.assert_allclose(tips["top"][1], p2 + R0 @ R1 @ R2 @ [0, 0, 0.1], atol=1e-12)
    # frame 0 is the rest pose shifted by the root position
    np.testing.assert_allclose(P[0], b.rest_positions() + [0.01, 0.9, 0.02], atol=1e-12)
    # the same angles in another channel order give another pose
    other = TINY.replace("CHANNELS 3 Xrotation Yrotation Zrotation",
                         "CHANNELS 3 Zrotation Yrotation Xrotation")
    P2, _ = read_bvh(_write(tmp_path, other, "o.bvh")).fk()
    assert np.linalg.norm(P2[1, 2] - P[1, 2]) > 1e-3
    L = b.local_rotations(frames=1)
    np.testing.assert_allclose(L[0, 1], R1, atol=1e-12)


def _line_of(text, fragment):
    return next(i for i, l in enumerate(text.splitlines(), 1) if fragment in l)


F1 = _line_of(TINY, "-5 95 3")
FT = _line_of(TINY, "Frame Time")
LEG = _line_of(TINY, "OFFSET 10 -70 0")
UP = _line_of(TINY, "Xrotation Yrotation Zrotation")


@pytest.mark.parametrize("mutate, pattern", [
    (lambda t: t.replace("MOTION", "MOTON"), r"t\.bvh, line \d+: no MOTION section"),
    (lambda t: t.replace("-5 95 3   90", "-5 95 3"), rf"line {F1}: frame 1 has 14 values, expected 15"),
    (lambda t: t.replace("15 25 35", "15 abc 35"), rf"line {F1}: frame 1: 'abc' is not a number"),
    (lambda t: t.replace("Frames:   2", "Frames: 3"), r"file truncated: Frames: says 3 but 2 frame"),
    (lambda t: t.replace("Frames:   2", "Frames: 1"), r"Frames: says 1 but 2 frame lines"),
    (lambda t: t.replace("OFFSET 10 -70 0", "OFFSET 10 -70"),
     rf"line {LEG + 1}: OFFSET of 'leg': 'CHANNELS' is not a number"),
    (lambda t: t.replace("Xrotation Yrotation Zrotation", "Xrotation Yrotation Wrotation"),
     rf"line {UP}: joint 'up': unknown channel 'Wrotation'"),
    (lambda t: t.split("MOTION")[0].rsplit("}", 3)[0] + "\nMOTION\nFrames: 0\nFrame Time: 0.1\n",
     r"file truncated: expected"),
    (lambda t: t.replace("Frame Time: 0.0333333", "Frame Time: fast"), rf"line {FT}: Frame Time: 'fast'"),
    (lambda t: t[:t.index("-5 95 3") + 12], rf"line {F1}: frame 1 has 4 values, expected 15"),
])
def test_malformed_files_name_file_line_and_problem(tmp_path, mutate, pattern):
    p = _write(tmp_path, mutate(TINY))
    with pytest.raises(ValueError, match=pattern) as e:
        read_bvh(p)
    assert str(p) in str(e.value)


def test_writer_layout_and_round_trip_tiny(tmp_path):
    b = read_bvh(_write(tmp_path, TINY))
    out = tmp_path / "w.bvh"
    write_bvh(out, b)
    text = out.read_text()
    lines = [l.strip() for l in text.splitlines()]
    assert lines[:3] == ["HIERARCHY", "ROOT root", "{"]
    assert "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" in lines
    assert lines.count("End Site") == 2 and "MOTION" in lines
    assert re.search(r"^Frames: 2$", text, re.M) and re.search(r"^Frame Time: 0\.03333", text, re.M)
    assert "e-" not in text and "e+" not in text  # fixed notation only
    back = read_bvh(out)
    assert back.scale_applied == 1.0  # written in metres
    np.testing.assert_allclose(back.fk()[0], b.fk()[0], atol=1e-9)
    assert back.names == b.names and back.channels == b.channels


def test_all_shared_clips_read_with_plausible_units(shared):
    for name, unit in CLIPS.items():
        b = read_bvh(shared / "mocap" / name)
        assert b.scale_applied == pytest.approx(unit), name
        # rest extents (foot tip to highest end site) are 1.19-1.42 m for these CMU subjects
        assert 1.1 < b.height() < 2.0, (name, b.height())
        P, W = b.fk(frames=slice(0, 50))
        assert P.shape == (50, b.n_joints, 3) and W.shape == (50, b.n_joints, 3, 3)
        assert 0.5 < P[:, 0, 1].mean() < 1.2, name  # hips height in metres
        np.testing.assert_allclose(W[0] @ np.swapaxes(W[0], -1, -2),
                                   np.broadcast_to(np.eye(3), W[0].shape), atol=1e-9)
    assert len(read_bvh(shared / "mocap" / "cmu_60_10_salsa_daz_metres.bvh").names) == 43


def test_round_trip_real_clip(shared, tmp_path):
    b = read_bvh(shared / "mocap" / "cmu_02_01_walk.bvh")
    out = tmp_path / "walk_m.bvh"
    write_bvh(out, b)
    back = read_bvh(out)
    assert back.n_frames == b.n_frames == 344
    assert back.frame_time == pytest.approx(b.frame_time, abs=1e-9)
    err = np.abs(back.fk()[0] - b.fk()[0]).max()
    assert err < 1e-6, err
    assert back.end_sites.keys() == b.end_sites.keys()


def test_resample_120_to_30_keeps_coinciding_frames(shared):
    b = read_bvh(shared / "mocap" / "cmu_131_03_start_hop_stop_max_metres.bvh")
    b = b.select_frames(slice(0, 241))
    r = resample(b, 120, 30)
    assert r.n_frames == 61 and r.fps == pytest.approx(30)
    P, Pr = b.fk()[0], r.fk()[0]
    np.testing.assert_array_equal(r.motion, b.motion[::4])
    np.testing.assert_allclose(Pr, P[::4], atol=1e-12)
    # 120 -> 40 fps: every third frame coincides, the others are in between their neighbours
    r40 = resample(b, 120, 40)
    np.testing.assert_allclose(r40.fk()[0], P[::3], atol=1e-12)
    r50 = resample(b, 120, 50)  # 2.4 source frames per output frame: interpolated frames
    Q = r50.fk()[0]
    assert Q.shape[0] == 101
    np.testing.assert_allclose(Q[5], P[12], atol=1e-12)
    mid = 0.5 * (P[2] + P[3])
    assert np.abs(Q[1] - mid).max() < 0.01  # frame 2.4 lies near frames 2..3


def test_resample_slerps_rotations_and_lerps_positions(tmp_path):
    text = TINY.replace("Frames:   2", "Frames: 2").replace("Frame Time: 0.0333333", "Frame Time: 1")
    text = text.replace("-5 95 3   90 0 0", "-5 95 3   0 0 170").replace("1 90 2   0 0 0", "1 90 2   0 0 -170")
    b = read_bvh(_write(tmp_path, text))
    r = resample(b, 1.0, 2.0)
    assert r.n_frames == 3
    np.testing.assert_allclose(r.motion[1, :3], 0.5 * (b.motion[0, :3] + b.motion[1, :3]))
    # -170 deg -> 170 deg about Y takes the short way through 180, not through 0
    W = r.fk()[1]
    np.testing.assert_allclose(W[1, 0], _ry(np.pi), atol=1e-9)
    assert abs(abs(r.motion[1, 5]) - 180) < 1e-6
    # arrays: rotation matrices are slerped, anything else linear
    Rs = np.stack([np.eye(3), _rz(np.pi / 2)])[:, None]
    mid = resample(Rs, 1, 2)[1, 0]
    np.testing.assert_allclose(mid, _rz(np.pi / 4), atol=1e-12)
    x = np.array([[0.0, 10.0], [1.0, 20.0]])
    np.testing.assert_allclose(resample(x, 1, 4), [[0, 10], [0.25, 12.5], [0.5, 15], [0.75, 17.5], [1, 20]])
    with pytest.raises(ValueError, match="positive"):
        resample(x, 0, 30)


def test_bvh_dataclass_validates_shapes():
    with pytest.raises(ValueError, match="motion must be"):
        Bvh(["a"], [-1], [[0, 0, 0]], [["Xrotation"]], {}, 0.1, np.zeros((2, 3)))
