"""Leading discontinuities of motion clips (a CMU clip's T-pose frame 0) are found and skipped."""
import logging

import numpy as np
import pytest

from gltrack.body.model import BodyModel
from gltrack.export.bvh import params_to_bvh
from gltrack.motion.bvh import leading_jumps, read_bvh, write_bvh
from gltrack.motion.retarget import load_motion

FPS = 30


def _clip(path, T=20, tpose=True):
    """A slow walk of the default body written as BVH; frame 0 a T-pose when ``tpose``."""
    body = BodyModel.build()
    d = body.dofs
    p = np.tile(d.zero(body.skeleton), (T, 1))
    t = np.arange(T) / FPS
    p[:, 2] += 0.4 * t
    for side, sign in (("l", 1), ("r", -1)):
        p[:, d.index(f"{side}_hip_rx")] = sign * 0.35 * np.sin(2 * np.pi * t)
        p[:, d.index(f"{side}_shoulder_rz")] = -sign * 1.2  # arms down
    if tpose:
        for side in "lr":
            p[0, d.index(f"{side}_hip_rx")] = 0.0
            p[0, d.index(f"{side}_shoulder_rz")] = 0.0  # arms out: the hands jump ~0.6 m
    write_bvh(path, params_to_bvh(body, p, FPS))
    return path


def test_constructed_tpose_frame_is_skipped_with_a_warning(tmp_path, caplog):
    path = _clip(tmp_path / "tpose.bvh")
    n_skip, jump, typical = leading_jumps(read_bvh(path))
    assert n_skip == 1 and jump > 0.3 and jump > 10 * typical
    _, _, all_frames, _ = load_motion(path)
    with caplog.at_level(logging.WARNING, logger="gltrack.motion.retarget"):
        _, _, skipped, _ = load_motion(path, skip_jumps=True)
    assert "skipped source frame 0" in caplog.text and "tpose.bvh" in caplog.text
    _, _, later, _ = load_motion(path, frames=(1, 20))
    assert len(all_frames) == 20 and len(skipped) == 19
    np.testing.assert_array_equal(skipped, later)
    # a range that starts after the jump, or one of too few frames, is left alone
    _, _, mid, _ = load_motion(path, frames=(2, 12), skip_jumps=True)
    assert len(mid) == 10
    _, _, short, _ = load_motion(path, frames=(0, 2), skip_jumps=True)
    assert len(short) == 2


def test_smooth_clip_is_untouched(tmp_path, caplog):
    path = _clip(tmp_path / "smooth.bvh", tpose=False)
    assert leading_jumps(read_bvh(path))[0] == 0
    with caplog.at_level(logging.WARNING):
        _, _, params, _ = load_motion(path, frames=(0, 20), skip_jumps=True)
    assert len(params) == 20 and "skipped" not in caplog.text


def test_cmu_walk_tpose_frame_is_skipped(shared):
    walk = shared / "mocap" / "cmu_02_01_walk.bvh"
    hop = shared / "mocap" / "cmu_131_03_start_hop_stop_max_metres.bvh"
    if not (walk.is_file() and hop.is_file()):
        pytest.skip(f"{walk} or {hop} absent")
    bvh = read_bvh(walk)
    n_skip, jump, _ = leading_jumps(bvh)
    assert n_skip == 1 and jump > 0.5  # the T-pose frame 0: a 0.6 m jump to frame 1
    P, _ = bvh.fk(slice(0, 40))
    _, _, params, _ = load_motion(walk, frames=(0, 40), skip_jumps=True)
    _, _, later, _ = load_motion(walk, frames=(1, 40))
    np.testing.assert_array_equal(params, later)
    steps = np.linalg.norm(np.diff(P[1:], axis=0), axis=2).max(axis=1)
    assert steps.max() < 0.1  # what is left moves smoothly
    assert leading_jumps(read_bvh(hop))[0] == 0  # a clip without a T-pose keeps its frame 0


def test_fast_smooth_motion_is_no_discontinuity(tmp_path):
    """Hands swinging 0.1-0.2 m a frame all along: a jump out of frame 0 as big as every other."""
    body = BodyModel.build()
    d = body.dofs
    T = 30
    p = np.tile(d.zero(body.skeleton), (T, 1))
    t = np.arange(T) / FPS
    for side, sign in (("l", 1), ("r", -1)):
        p[:, d.index(f"{side}_shoulder_rz")] = -sign * (0.2 + 1.2 * (1 + np.sin(6 * np.pi * t)))
    path = tmp_path / "fast.bvh"
    write_bvh(path, params_to_bvh(body, p, FPS))
    n_skip, jump, typical = leading_jumps(read_bvh(path))
    assert jump > 0.1 and n_skip == 0, (jump, typical)
