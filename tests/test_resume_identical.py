"""kill -9 and ``--resume`` give the poses of an uninterrupted run, bit for bit (issue 14, point 3).

A real kill: ``python -m gltrack track`` in a child process, SIGKILL once ``frames.jsonl`` holds
a few frames, then ``--resume``; the uninterrupted run is tracked in this process (so the test
also checks that two processes agree). The runner restores the tracker from
``checkpoint.npz`` (:mod:`gltrack.track.checkpoint`); without it a resumed run re-starts
from the last pose and differs from the first resumed frame on.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gltrack.cli import main
from gltrack.data.results import load_results

sys.path.insert(0, str(Path(__file__).parent))
from trackdata import make_depth_dataset  # noqa: E402


def _lines(path):
    if not path.is_file():
        return []
    return [s for s in path.read_text().splitlines() if s.strip().endswith("}")]


def _kill_after(args, out, k, timeout=300):
    """Run ``gltrack track ARGS`` in a child and SIGKILL it once ``k`` frames are written."""
    env = dict(os.environ)
    proc = subprocess.Popen([sys.executable, "-m", "gltrack", "-q", "track", *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    log = Path(out) / "frames.jsonl"
    deadline = time.time() + timeout
    try:
        while len(_lines(log)) < k:
            if proc.poll() is not None:
                pytest.fail(f"tracker exited early: {proc.stderr.read().decode()[-2000:]}")
            if time.time() > deadline:
                pytest.fail("tracker too slow")
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
        proc.stderr.close()
    return len(_lines(log))


def _resume_matches(args, tmp_path, n_frames, k):
    full, part = tmp_path / "full", tmp_path / "part"
    assert main(["-q", "track", *args, "--out", str(full)]) == 0
    done = _kill_after([*args, "--out", str(part)], part, k)
    assert k <= done < n_frames, f"the run must be killed part-way ({done} of {n_frames})"
    assert not (part / "poses.npz").exists()
    assert (part / "checkpoint.npz").is_file()
    rc = subprocess.run([sys.executable, "-m", "gltrack", "track", *args, "--out", str(part),
                         "--resume"], capture_output=True, text=True, timeout=600)
    assert rc.returncode == 0, rc.stderr
    # the checkpoint was used, and a frame tracked again after it (a kill between a frame's
    # line and its checkpoint) came out as written
    assert "re-starts from" not in rc.stderr and "tracked again" not in rc.stderr, rc.stderr
    a, b = load_results(full)["params"], load_results(part)["params"]
    assert a.shape == b.shape == (n_frames, a.shape[1])
    differ = np.flatnonzero(np.any(a != b, axis=1))
    assert differ.size == 0, (f"resumed after frame {done - 1}: frames {differ.tolist()} differ, "
                              f"up to {np.abs(a - b).max():.3g}")
    scores = [json.loads(s)["score"] for s in _lines(part / "frames.jsonl")]
    assert scores == [json.loads(s)["score"] for s in _lines(full / "frames.jsonl")]


def test_hc_ep_kill_and_resume_is_bit_identical(tmp_path):
    ds = tmp_path / "ds"
    make_depth_dataset(ds, n=8)
    _resume_matches([str(ds), "--method", "hc+ep", "--body", "dataset", "--init", "groundtruth",
                     "--seed", "3"], tmp_path, 8, 3)


@pytest.fixture(scope="module")
def blobs(tmp_path_factory):
    """A 4-camera walk with masks and a behaviour model learnt from the same kind of motion."""
    from gltrack.bench.rigs import ring_cameras
    from gltrack.bench.vlmm import make_multiview_dataset, periodic_motion
    from gltrack.body.model import BodyModel
    from gltrack.motion.behaviour import BehaviourModel

    root = tmp_path_factory.mktemp("resume_mv")
    body = BodyModel.build(preset="25", lod=0)
    model = BehaviourModel.fit(periodic_motion(body, 120, period=0.8), 30.0,
                               np.random.default_rng(0), holdout=0.0,
                               dof_names=body.dofs.names[6:])
    model.save(root / "model.npz")
    test = periodic_motion(body, 7, phase=1.0, period=0.8)
    test[:, 0] += 0.2
    make_multiview_dataset(root / "ds", body, test,
                           ring_cameras((0.2, 0.9, 0.0), width=160, height_px=120))
    return root


@pytest.mark.parametrize("method", ["hps", "vlmm"])
def test_particle_filters_kill_and_resume_is_bit_identical(blobs, tmp_path, method):
    """Particle sets, the generator, appearance colours and VLMM histories come back."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("particles = 60\n" + (f'model = "{blobs / "model.npz"}"\n'
                                          if method == "vlmm" else ""))
    _resume_matches([str(blobs / "ds"), "--method", method, "--body", "dataset", "--init",
                     "groundtruth", "--config", str(cfg), "--seed", "3"], tmp_path, 7, 3)


class _Crash(Exception):
    pass


def _crash_at(frame):
    def hook(tracker, f):
        if f == frame:
            raise _Crash(f)
    return hook


def test_a_checkpoint_behind_the_frame_log_is_caught_up_by_tracking_again(tmp_path, caplog):
    """A kill between a frame's line and its checkpoint: the checkpoint is one frame behind
    ``frames.jsonl``; the resumed run tracks that frame again (not writing it) and goes on
    bit for bit. A checkpoint of another pose is not used (warning, old behaviour)."""
    import shutil

    from gltrack.track.runner import track

    ds = tmp_path / "ds"
    make_depth_dataset(ds, n=6)
    kw = dict(body="dataset", init="groundtruth", progress=False, seed=5,
              options={"heading_hypotheses": 1, "levels": 2})
    track(ds, "hc", tmp_path / "full", **kw)
    part = tmp_path / "part"
    with pytest.raises(_Crash):
        track(ds, "hc", part, hooks=[_crash_at(2)], **kw)  # frames 0, 1 and checkpoint 1
    behind = tmp_path / "behind.npz"
    shutil.copy(part / "checkpoint.npz", behind)
    with pytest.raises(_Crash):
        track(ds, "hc", part, resume=True, hooks=[_crash_at(3)], **kw)  # frame 2, checkpoint 2
    shutil.copy(behind, part / "checkpoint.npz")
    lines = (part / "frames.jsonl").read_text()
    caplog.clear()
    track(ds, "hc", part, resume=True, **kw)
    assert "tracked again" not in caplog.text and "re-starts" not in caplog.text, caplog.text
    assert (part / "frames.jsonl").read_text().startswith(lines)  # written frames untouched
    a, b = load_results(tmp_path / "full")["params"], load_results(part)["params"]
    assert np.array_equal(a, b)
    # a checkpoint whose pose is not the log's: not used
    other = tmp_path / "other"
    with pytest.raises(_Crash):
        track(ds, "hc", other, hooks=[_crash_at(2)], **kw)
    shutil.copy(tmp_path / "full" / "checkpoint.npz", other / "checkpoint.npz")  # frame 5's
    caplog.clear()
    track(ds, "hc", other, resume=True, **kw)
    assert "re-starts from frame 1's pose" in caplog.text
