"""The depth tracker end to end through the CLI: track, evaluate, resume after a kill."""
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
from gltrack.data.dataset import Dataset
from gltrack.data.results import load_results
from gltrack.eval.metrics import evaluate

sys.path.insert(0, str(Path(__file__).parent))
from trackdata import make_depth_dataset, smooth_motion  # noqa: E402


@pytest.fixture(scope="module")
def depth_ds(tmp_path_factory):
    out = tmp_path_factory.mktemp("depth") / "ds"
    make_depth_dataset(out, n=12)
    return out


def _metrics(res, ds):
    from gltrack.data.dataset import Dataset

    return evaluate(load_results(res), Dataset.open(ds).groundtruth())


def test_hc_tracks_and_beats_a_frozen_pose(depth_ds, tmp_path):
    out = tmp_path / "hc"
    assert main(["-q", "track", str(depth_ds), "--method", "hc", "--out", str(out)]) == 0
    for name in ("poses.npz", "poses.bvh", "timing.json", "frames.jsonl"):
        assert (out / name).is_file(), name
    timing = json.loads((out / "timing.json").read_text())
    assert timing["frames"] == 12 and timing["evaluations"] > 12 * 100
    m = _metrics(out, depth_ds)
    assert m["mean_joint_error_mm"] < 40
    assert m["frac_markers_failed"] == 0.0
    # The same run with the pose frozen at frame 0 is clearly worse: tracking did something.
    res = load_results(out)
    frozen = dict(res)
    frozen["joints"] = np.repeat(res["joints"][:1], len(res["joints"]), axis=0)
    frozen["markers"] = np.repeat(res["markers"][:1], len(res["markers"]), axis=0)
    from gltrack.data.dataset import Dataset

    m0 = evaluate(frozen, Dataset.open(depth_ds).groundtruth())
    assert m["mean_joint_error_mm"] < 0.7 * m0["mean_joint_error_mm"]
    assert main(["eval", str(out), str(depth_ds), "--json", str(tmp_path / "m.json")]) == 0
    keys = json.loads((tmp_path / "m.json").read_text())
    assert {"mean_joint_error_mm", "mpjpe_mm", "pa_mpjpe_mm", "marker_mean_m", "marker_max_m",
            "frac_markers_tracked", "frac_markers_failed", "frames"} <= set(keys)


def test_auto_init_finds_the_body(depth_ds, tmp_path):
    out = tmp_path / "auto"
    assert main(["-q", "track", "--body", "dataset", str(depth_ds), "--method", "hc", "--out", str(out), "--init", "auto",
                 "--frames", "0:3"]) == 0
    m = _metrics(out, depth_ds)
    assert m["frames"] == 3
    assert m["mean_joint_error_mm"] < 150, m  # the pose is found, not only the position


def test_options_are_validated(depth_ds, tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text("tile = 64\nno_such_option = 3\n")
    rc = main(["track", str(depth_ds), "--method", "hc", "--out", str(tmp_path / "x"), "--config", str(cfg)])
    assert rc == 1
    assert "no_such_option" in capsys.readouterr().err
    assert main(["track", str(depth_ds), "--method", "hc", "--out", str(tmp_path / "y"),
                 "--frames", "bad"]) == 2
    assert main(["track", str(tmp_path / "missing"), "--method", "hc", "--out", str(tmp_path / "z")]) == 1


def test_resume_after_kill_loses_no_frame(tmp_path):
    ds = tmp_path / "ds"
    make_depth_dataset(ds, n=40)
    out = tmp_path / "res"
    cmd = [sys.executable, "-m", "gltrack", "-q", "track", "--body", "dataset", str(ds), "--method", "hc", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    log = out / "frames.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline:
        if log.is_file() and len(log.read_text().splitlines()) >= 4:
            break
        if proc.poll() is not None:
            pytest.fail(f"tracker exited early: {proc.stderr.read().decode()}")
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    before = [json.loads(line) for line in log.read_text().splitlines() if line.strip().endswith("}")]
    assert 4 <= len(before) < 40, "the run must have been killed part-way"
    assert not (out / "poses.npz").exists()
    assert json.loads((out / "body.json").read_text())["source"] == "dataset"  # from the start
    rc = subprocess.run(cmd + ["--resume"], capture_output=True, timeout=300)
    assert rc.returncode == 0, rc.stderr.decode()
    after = [json.loads(line) for line in log.read_text().splitlines()]
    assert [r["frame"] for r in after] == list(range(40))
    for a, b in zip(before, after):
        assert a == b, "finished frames must survive unchanged"
    assert load_results(out)["params"].shape[0] == 40


@pytest.mark.parametrize("turn, shift", [(np.pi / 2, 0.0), (-2.0, 0.6)])
def test_auto_init_finds_a_turned_and_shifted_body(tmp_path, ctx, turn, shift):
    """--init auto from nothing: side-on (a view that fits about as well turned 180 degrees)
    and turned away and shifted, the library search plus hill climbing lands on the body."""
    from gltrack.body.model import BodyModel, body_to_meta
    from gltrack.camera import depth_camera_sr4000
    from gltrack.data.dataset import Dataset, DatasetWriter
    from gltrack.render import reference as ref
    from gltrack.track.depth import DepthOptions, HillClimbDepthTracker

    body = BodyModel.build()
    P = smooth_motion(body, 1, np.random.default_rng(0))
    P[:, body.dofs.index("pelvis_ry")] += turn
    P[:, 0] += shift
    cam = depth_camera_sr4000((0.3, 1.0, 3.2), (0.0, 0.9, 0.0))
    z, _ = ref.render_candidates(body.mesh, body.skinning(P), cam.K, cam.R, cam.t, cam.width,
                                 cam.height)
    with DatasetWriter(tmp_path / "ds", "depth", 30.0, [cam], body=body_to_meta(body.skeleton)) as w:
        w.write_depth(0, 0, z[0])
    tr = HillClimbDepthTracker(Dataset.open(tmp_path / "ds"), body, ctx, DepthOptions())
    try:
        x = tr.auto_init(0)
    finally:
        tr.close()
    err = np.linalg.norm(body.joints(x[None])[0] - body.joints(P)[0], axis=1)
    yaw = body.dofs.index("pelvis_ry")
    assert err.mean() < 0.06 and err.max() < 0.15, err
    assert abs(np.angle(np.exp(1j * (x[yaw] - P[0, yaw])))) < 0.3


def test_the_arm_sweep_finds_an_arm_lost_over_the_background(tmp_path, ctx):
    """An arm the track has flung out over the background (where the depth cost is flat and
    the prior holds it): the per-frame arm sweep (``arm_sweep``, scored by the depth cost
    alone) brings it back to the body within a frame and says which arm it moved; without the
    sweep the climb leaves it out. The sweep touches nothing when the arms are right."""
    from gltrack.track.depth import DepthOptions, HillClimbDepthTracker

    body, P = make_depth_dataset(tmp_path / "ds", n=3, seed=2)
    ds = Dataset.open(tmp_path / "ds")
    d = body.dofs
    w = body.skeleton.names.index("r_wrist")
    lost = P[0].copy()
    lost[d.index("r_shoulder_rz")] = lost[d.index("r_shoulder_ry")] = 0.0  # out sideways
    assert np.linalg.norm(body.joints(lost[None])[0, w] - body.joints(P[:1])[0, w]) > 0.4

    def track(opts, x0):
        tr = HillClimbDepthTracker(ds, body, ctx, opts)
        try:
            tr.start(0, x0)
            ests = [tr.step(f) for f in range(3)]
        finally:
            tr.close()
        err = [float(np.linalg.norm(body.joints(e.params[None])[0, w] - body.joints(P[f:f + 1])[0, w]))
               for f, e in enumerate(ests)]
        return ests, err

    _, err_off = track(DepthOptions(arm_sweep=0), lost)
    ests, err_on = track(DepthOptions(), lost)  # on by default
    assert err_off[-1] > 0.3, err_off  # the climb alone does not bring it back
    assert max(err_on) < 0.08, err_on
    assert "r_shoulder" in ests[0].info["swept"]
    assert ests[0].evaluations > 2 * (4 * DepthOptions().arm_sweep ** 2 + 1)
    right, _ = track(DepthOptions(), P[0])
    assert all(e.info["swept"] == [] for e in right), [e.info["swept"] for e in right]


def test_auto_start_waits_for_the_person(tmp_path, capsys, caplog):
    """Frames without a person before the subject walks in: the automatic start warns, tries
    the next frames and starts where the person is; a take with no person at all is a one-line
    error naming the frames."""
    from gltrack.body.model import BodyModel, body_to_meta
    from gltrack.camera import depth_camera_sr4000
    from gltrack.data.dataset import DatasetWriter
    from gltrack.render import reference as ref

    body = BodyModel.build()
    P = smooth_motion(body, 4, np.random.default_rng(0))
    cam = depth_camera_sr4000((0.3, 1.0, 3.2), (0.0, 0.9, 0.0))
    z, _ = ref.render_candidates(body.mesh, body.skinning(P), cam.K, cam.R, cam.t, cam.width,
                                 cam.height)
    for name, first in (("late", 2), ("empty", 4)):
        with DatasetWriter(tmp_path / name, "depth", 30.0, [cam],
                           body=body_to_meta(body.skeleton)) as w:
            for f in range(4):
                w.write_depth(f, 0, z[f] if f >= first else np.zeros_like(z[f]))
    out = tmp_path / "res"
    assert main(["-q", "track", "--body", "dataset", str(tmp_path / "late"), "--method", "hc", "--out", str(out)]) == 0
    assert "frame 0: too few foreground" in caplog.text and "trying frame 2" in caplog.text
    res = load_results(out)
    assert list(res["frame"]) == [2, 3]
    # the person is found where it is (trunk joints); seen face-on by one depth camera the
    # body fits about as well turned round, which this test does not judge
    trunk = [list(body.skeleton.names).index(n) for n in ("pelvis", "spine_lower", "spine_upper",
                                                          "neck", "head")]
    J = body.joints(P[2:])
    assert np.linalg.norm(res["joints"][:, trunk] - J[:, trunk], axis=2).mean() < 0.05
    rc = main(["-q", "track", "--body", "dataset", str(tmp_path / "empty"), "--method", "hc", "--out",
               str(tmp_path / "e")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and "no person found" in err[-1] and "frames 0..3" in err[-1]


def test_two_modes_keeps_the_turned_round_twin():
    from gltrack.track.base import two_modes

    X = np.zeros((4, 6))
    X[:, 3] = [0.1, 3.2, 0.2, -3.0]
    best, twin = two_modes(X, [2.0, 3.0, 1.0, 2.5], 3)
    assert best[3] == 0.2 and twin[3] == -3.0
    assert len(two_modes(X[[0, 2]], [2.0, 1.0], 3)) == 1


def test_auto_start_decides_between_a_body_and_its_twin(tmp_path, caplog, capsys, monkeypatch):
    """Face-on, one depth frame fits the body and its turned-round twin about equally; the
    runner tracks both for a few frames and keeps the one that explains them: the walk is
    tracked the right way round. On a tie the start's own best is kept (it is the decision's
    incumbent). The progress bar says what it does before the first frame (shown at once
    here: on a real take the start comes after its delay)."""
    import logging

    from gltrack.body.model import BodyModel
    from gltrack.track import runner
    from gltrack.track.runner import track

    monkeypatch.setattr(runner, "BAR_DELAY", 0.0)
    decide, incumbents = runner._decide, []

    def spy(trackers, frames, hooks, incumbent=None):
        incumbents.append(incumbent)
        return decide(trackers, frames, hooks, incumbent)

    monkeypatch.setattr(runner, "_decide", spy)

    make_depth_dataset(tmp_path / "ds", n=12)
    gt = Dataset.open(tmp_path / "ds").groundtruth()
    with caplog.at_level(logging.INFO, logger="gltrack.track.runner"):
        track(tmp_path / "ds", "hc", tmp_path / "res", body="dataset", progress=True, decide_frames=6)
    res = load_results(tmp_path / "res")
    err = np.linalg.norm(res["joints"] - gt["joints"][res["frame"]], axis=2).mean()
    assert err < 0.06, err
    assert "start hypotheses tracked over 6 frames" in caplog.text
    assert incumbents == [0]
    # the first frame records what the choice rested on
    first = json.loads((tmp_path / "res" / "frames.jsonl").read_text().splitlines()[0])
    verdict = first["info"]["start"]
    assert verdict["hypotheses"] == len(verdict["means"]) >= 2 and verdict["frames"] == 6
    assert verdict["measure"] == "quality" and verdict["turned_deg"][verdict["kept"]] == 0.0
    assert max(abs(t) for t in verdict["turned_deg"]) > 90  # the twin is turned round
    # the other hypothesis, kept by hand (no decision): the same start, the twin's heading
    other = next(j for j, t in enumerate(verdict["turned_deg"]) if abs(t) > 90)
    track(tmp_path / "ds", "hc", tmp_path / "twin", body="dataset", progress=False,
          frames=(0, 2), start_hypothesis=other)
    twin = json.loads((tmp_path / "twin" / "frames.jsonl").read_text().splitlines()[0])
    assert twin["info"]["start"] == {"hypotheses": verdict["hypotheses"], "kept": other,
                                     "chosen": "--start-hypothesis"}
    yaw = BodyModel.build().dofs.index("pelvis_ry")
    turned = np.angle(np.exp(1j * (twin["params"][yaw] - first["params"][yaw])))
    assert abs(np.degrees(turned)) > 90, np.degrees(turned)
    assert incumbents == [0]  # no decision this time
    bar = capsys.readouterr().err
    assert "--init auto: finding the start" in bar
    assert "start hypotheses, each tracked 6 frames" in bar


def test_decision_keeps_the_hypothesis_that_explains_the_frames():
    """The runner's choice between start hypotheses: lower mean score wins, every frame is
    stepped (hooks first) and kept for writing."""
    from gltrack.track.base import FrameEstimate
    from gltrack.track.runner import _decide

    class Scripted:  # a stand-in with scripted per-frame scores; no GL involved
        def __init__(self, scores):
            self.scores, self.seen = scores, []

        def step(self, f):
            self.seen.append(f)
            return FrameEstimate(np.zeros(3), self.scores[f], 1)

    a, b = Scripted([5.0, 4.0, 6.0]), Scripted([5.5, 3.0, 4.0])
    hooked = []
    k, runs = _decide([a, b], range(3), [lambda tr, f: hooked.append(f)])
    assert k == 1 and a.seen == b.seen == [0, 1, 2] and hooked == [0, 1, 2, 0, 1, 2]
    assert [e.score for e, _ in runs[1]] == [5.5, 3.0, 4.0]


def test_a_restart_keeps_the_going_track_on_a_tie():
    """A re-start's lost tracker (the incumbent) is kept when its mean is within the tie margin
    of the best (a body and its turned-round twin tie; the track's continuity decides), but not
    when another hypothesis is clearly better; without an incumbent the lowest mean wins."""
    from gltrack.track.base import FrameEstimate
    from gltrack.track.runner import TIE, _decide

    class Scripted:  # constant scripted scores; no GL involved
        def __init__(self, score):
            self.score = score

        def step(self, f):
            return FrameEstimate(np.zeros(3), self.score, 1)

    tied = 1.0 + 0.5 * TIE
    assert _decide([Scripted(tied), Scripted(1.0)], range(3), [])[0] == 1
    assert _decide([Scripted(tied), Scripted(1.0)], range(3), [], incumbent=0)[0] == 0
    assert _decide([Scripted(1.0 + 2 * TIE), Scripted(1.0)], range(3), [], incumbent=0)[0] == 1
    assert _decide([Scripted(1.0), Scripted(tied)], range(3), [], incumbent=1)[0] == 1


def test_a_tied_start_is_recorded_and_said(caplog):
    """The choice between start hypotheses is recorded (means, kept, how far each is turned
    from the kept one) and flagged uncertain when another came within the tie margin; the
    runner's warning says so and names the frames. A clear winner is not flagged."""
    import logging

    from gltrack.body.model import BodyModel
    from gltrack.track.base import FrameEstimate
    from gltrack.track.runner import TIE, _verdict, _warn_uncertain_start

    body = BodyModel.build()
    yaw = body.dofs.index("pelvis_ry")

    def run(heading, quality, n=5):
        p = np.zeros(body.dofs.size)
        p[1], p[yaw] = 0.98, heading
        return [(FrameEstimate(p, 0.0, 1, info={"quality": quality}), 0.1) for _ in range(n)]

    class Holder:  # the verdict reads the kept tracker's body only
        pass

    trackers = [Holder(), Holder()]
    trackers[0].body = trackers[1].body = body
    tied = _verdict(trackers, [run(0.3, 0.40), run(0.3 + np.pi, 0.40 * (1 + 0.5 * TIE))], 0)
    assert tied["uncertain"] and tied["kept"] == 0 and tied["measure"] == "quality"
    assert tied["means"] == [0.4, round(0.4 * (1 + 0.5 * TIE), 4)]
    assert tied["turned_deg"][0] == 0.0 and abs(tied["turned_deg"][1]) == 180.0
    clear = _verdict(trackers, [run(0.3, 0.40 * (1 + 3 * TIE)), run(-1.0, 0.40)], 1)
    assert not clear["uncertain"] and clear["turned_deg"] == [74.5, 0.0]
    with caplog.at_level(logging.WARNING, logger="gltrack.track.runner"):
        _warn_uncertain_start(7, tied)
    assert "frame 7: the 2 start hypotheses (turned 0, 180 deg from the kept one) explained " \
        "frames 7-11 about equally well" in caplog.text


def test_a_tie_between_twins_goes_to_the_one_walking_forwards():
    """Two hypotheses whose mean scores differ by less than the tie margin: the one whose
    travel points the way it faces is kept even with the (slightly) higher score; a clear
    score difference, or a body that does not travel, is decided by the scores alone."""
    from gltrack.body.model import BodyModel
    from gltrack.track.base import FrameEstimate
    from gltrack.track.runner import _decide

    body = BodyModel.build()
    yaw = body.dofs.index("pelvis_ry")

    class Walker:  # scripted poses and scores; no GL involved
        def __init__(self, heading, speed, score):
            self.body, self.heading, self.speed, self.score = body, heading, speed, score

        def step(self, f):
            p = np.zeros(body.dofs.size)
            p[1], p[2], p[yaw] = 0.98, self.speed * f, self.heading  # travels along +Z
            return FrameEstimate(p, self.score, 1)

    facing_away = Walker(np.pi, 0.08, 100.0)  # walks backwards, scores lowest
    facing_on = Walker(0.0, 0.08, 100.5)      # faces +Z, the way it travels
    assert _decide([facing_away, facing_on], range(10), [])[0] == 1
    assert _decide([Walker(np.pi, 0.08, 100.0), Walker(0.0, 0.08, 115.0)], range(10), [])[0] == 0
    assert _decide([Walker(np.pi, 0.0, 100.0), Walker(0.0, 0.0, 100.5)], range(10), [])[0] == 0


def test_a_tie_goes_to_the_twin_that_bends_its_knees():
    """Two tied hypotheses, one holding its knees straight against their extension limit (what
    a body turned round does when the person's knees are bent): the one that bends them is kept,
    even against the incumbent, and the verdict records both shares; a clear score difference,
    knees that both bend, or a body without knee DOFs leave the decision to the other rules."""
    from gltrack.body.model import BodyModel
    from gltrack.track.base import FrameEstimate
    from gltrack.track.runner import KNEES_PINNED, TIE, _decide, _knees_at_limit, _verdict

    def stander(body, knee, score):
        class Scripted:  # scripted poses and scores; no GL involved
            def step(self, f):
                p = np.zeros(body.dofs.size)
                p[1] = 0.98
                for i, n in enumerate(body.dofs.names):
                    if "knee" in n:
                        p[i] = knee
                return FrameEstimate(p, score, 1)
        tr = Scripted()
        tr.body = body
        return tr

    body = BodyModel.build()
    lo = body.dofs.lower[body.dofs.index("l_knee_rx")]
    tied = 1.0 + 0.5 * TIE
    straight, bent = lo, 0.5  # at the limit; 29 degrees of flexion
    assert _decide([stander(body, straight, 1.0), stander(body, bent, tied)], range(4), [],
                   incumbent=0)[0] == 1
    assert _decide([stander(body, bent, tied), stander(body, straight, 1.0)], range(4), [])[0] == 0
    # the score decides when the twins do not tie, and the incumbent when both knees bend
    assert _decide([stander(body, straight, 1.0), stander(body, bent, 1.0 + 2 * TIE)],
                   range(4), [])[0] == 0
    assert _decide([stander(body, 0.3, 1.0), stander(body, bent, tied)], range(4), [],
                   incumbent=0)[0] == 0
    runs = [[(stander(body, straight, 1.0).step(f), 0.1) for f in range(4)],
            [(stander(body, bent, tied).step(f), 0.1) for f in range(4)]]
    assert _knees_at_limit(body, runs[0]) == 1.0 and _knees_at_limit(body, runs[1]) == 0.0
    assert KNEES_PINNED < 1.0
    trackers = [stander(body, straight, 1.0), stander(body, bent, tied)]
    assert _verdict(trackers, runs, 1)["knees_at_limit"] == [1.0, 0.0]
    # a body seen from the waist up has no knees to tell by: the incumbent stays
    upper = BodyModel.build(preset="upper")
    assert _knees_at_limit(upper, [(stander(upper, 0.0, 1.0).step(0), 0.1)]) is None
    assert _decide([stander(upper, 0.0, 1.0), stander(upper, 0.0, tied)], range(3), [],
                   incumbent=0)[0] == 0
    assert _decide([stander(upper, 0.0, tied), stander(upper, 0.0, 1.0)], range(3), [],
                   incumbent=0)[0] == 0


def test_a_lost_track_is_restarted(tmp_path, caplog):
    """The whole state turned 90 degrees at frame 2 (the tracker lost the body): the frames'
    quality rises over the tracker's lost threshold, the runner re-starts it from its automatic
    start, and the last frames are tracked again. With re-starts off the track stays lost."""
    import logging

    from gltrack.bench.faults import set_fault
    from gltrack.track.runner import track

    make_depth_dataset(tmp_path / "ds", n=14)
    gt = Dataset.open(tmp_path / "ds").groundtruth()
    errs = {}
    for lost_frames in (0, 3):
        out = tmp_path / f"res{lost_frames}"
        with caplog.at_level(logging.INFO, logger="gltrack.track.runner"):
            # the one-DOF-at-a-time climb: it stays lost without a re-start (the default stage
            # climb half climbs back from this fault by itself: 0.05 m after 8 frames)
            track(tmp_path / "ds", "hc", out, body="dataset", init="groundtruth",
                  progress=False, decide_frames=4, lost_frames=lost_frames,
                  hooks=[set_fault(2, np.pi / 2, 0.4)], options={"stages": "chain"})
        res = load_results(out)
        errs[lost_frames] = np.linalg.norm(res["joints"] - gt["joints"][res["frame"]], axis=2).mean(1)
        frames = [json.loads(line) for line in (out / "frames.jsonl").read_text().splitlines()]
        restarts = [f["info"]["restart"] for f in frames if "restart" in f["info"]]
        assert all("quality" in f["info"] for f in frames)
        if lost_frames:
            assert restarts and restarts[0]["restarted"], restarts
            assert "re-started from the automatic start" in caplog.text
        else:
            assert not restarts
    assert errs[0][2] > 0.15  # the fault threw the body off
    # without re-starts the climb half undoes it and stays there (about 0.1 m); re-started,
    # the track is back on the body
    assert errs[3][-4:].mean() < min(0.04, 0.5 * errs[0][-4:].mean()), (errs[0], errs[3])


def test_a_wrong_start_file_is_checked_against_the_automatic_start(tmp_path):
    """A start pose turned 90 degrees from the truth, given as a file: the runner also tracks
    the automatic start's hypotheses and keeps the one that explains the first frames; without
    the check the wrong start is tracked as given."""
    from gltrack.body.model import BodyModel
    from gltrack.track.runner import track

    make_depth_dataset(tmp_path / "ds", n=10)
    gt = Dataset.open(tmp_path / "ds").groundtruth()
    x0 = np.array(gt["params"][0])
    x0[BodyModel.build().dofs.index("pelvis_ry")] += np.pi / 2
    np.save(tmp_path / "wrong.npy", x0)
    err = {}
    for check in (False, True):
        out = tmp_path / f"res{check}"
        track(tmp_path / "ds", "hc", out, body="dataset", init=str(tmp_path / "wrong.npy"),
              progress=False, decide_frames=5, lost_frames=0, check_start=check)
        res = load_results(out)
        err[check] = np.linalg.norm(res["joints"] - gt["joints"][res["frame"]], axis=2).mean(1)
    assert err[False][0] > 0.1, err[False]  # the given start, as given
    assert err[True][0] < 0.5 * err[False][0] and err[True].mean() < 0.06, err[True]


@pytest.mark.parametrize("turn", [0.0, np.pi / 2])
def test_auto_init_tries_the_other_leg_forward(tmp_path, ctx, monkeypatch, turn):
    """A walker in mid-stride (left leg and right arm forward), face-on and side-on to the
    depth camera, and a pose library that holds only the mirror-image stride: only the start's
    limb exchange (``init_exchange``: each heading's best climbed pose mirrored and climbed
    again) offers a start hypothesis facing the right way with the legs on the right sides.
    Without the exchange none does."""
    import gltrack.track.depth as dt
    from gltrack.body.model import BodyModel, body_to_meta
    from gltrack.camera import depth_camera_sr4000
    from gltrack.data.dataset import DatasetWriter
    from gltrack.render import reference as ref
    from gltrack.sample.partitions import exchange_limbs, limb_pairs

    from trackdata import legs_right_way, mid_stride

    body = BodyModel.build()
    d, sk = body.dofs, body.skeleton
    P = mid_stride(body, pelvis_tx=0.0, pelvis_ty=0.95, pelvis_tz=0.0, pelvis_ry=turn)
    mirror = d.validate(exchange_limbs(P, limb_pairs(d)))
    monkeypatch.setattr(dt, "canonical_poses", lambda dofs, skeleton=None: (["stride"], mirror))
    cam = depth_camera_sr4000((0.3, 1.0, 3.2), (0.0, 0.9, 0.0))
    z, _ = ref.render_candidates(body.mesh, body.skinning(P), cam.K, cam.R, cam.t, cam.width,
                                 cam.height)
    with DatasetWriter(tmp_path / "ds", "depth", 30.0, [cam], body=body_to_meta(sk)) as w:
        w.write_depth(0, 0, z[0])
    want = body.joints(P)[0]

    def right_way(x):
        return legs_right_way(body, x, P[0])

    def hypotheses(exchange):
        tr = dt.HillClimbDepthTracker(Dataset.open(tmp_path / "ds"), body, ctx,
                                      dt.DepthOptions(init_headings=1, init_exchange=exchange))
        try:
            return tr.start_hypotheses(0)
        finally:
            tr.close()

    found = [x for x in hypotheses(True) if right_way(x)]
    assert found
    assert min(np.linalg.norm(body.joints(x[None])[0] - want, axis=1).mean() for x in found) < 0.12
    assert not any(right_way(x) for x in hypotheses(False))
