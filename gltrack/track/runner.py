"""Run a tracker over a dataset and write the results folder frame by frame (crash-safe).

The method comes from :data:`gltrack.track.registry.METHODS`. The runner owns the GL context,
the results writer (``body.json``, the body tracked with, when the run starts;
``frames.jsonl`` appended per frame, ``--resume`` continues after the last
finished frame from the tracker state checkpointed after it, :mod:`gltrack.track.checkpoint`)
and the final ``poses.npz`` / ``timing.json`` / ``poses.bvh``.

Hooks: ``track(..., hooks=[h])`` calls ``h(tracker, frame)`` before every frame is tracked;
the benches inject faults this way (``gltrack.bench.faults``) without the trackers knowing.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from gltrack.body.dofs import make_dofs
from gltrack.body.skeleton import default_skeleton
from gltrack.data.dataset import Dataset
from gltrack.data.provenance import recorded_range, run_provenance
from gltrack.data.results import BODY, ResultsWriter, load_body_record
from gltrack.export.bvh import write_params_bvh
from gltrack.render.engine import ENGINE_STATS

from . import checkpoint
from .bodies import hold_seat, resolve_body, seat_of, seated
from .body_estimate import FRAMING_PRESETS
from .base import NoPersonError
from .lost import LossWatch
from .registry import method as lookup

log = logging.getLogger(__name__)

#: seconds after which the progress bar shows up: bad input (a body or pose file that is
#: missing or of the wrong shape, a results folder in the way) fails faster, and its one-line
#: error then stands alone, in a log file too; what the bar tells before the first frame takes
#: far longer (a body estimate: 40-100 s on a real take on software GL)
BAR_DELAY = 2.0


class _Progress:
    """The run's progress bar (tqdm), opened on the first report after :data:`BAR_DELAY`
    seconds or when the frames begin; before the first frame it says what the run does."""

    def __init__(self, desc: str, total: int, enabled: bool):
        self.desc, self.total, self.enabled = desc, int(total), bool(enabled)
        self.t0 = time.perf_counter()
        self.bar = None

    def _open(self):
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=self.total, desc=self.desc, unit="frame",
                            disable=not self.enabled, leave=False)
        return self.bar

    def say(self, text: str) -> None:
        """Show ``text`` after the counts (before the delay: only on a bar already open)."""
        if self.bar is not None or time.perf_counter() - self.t0 >= BAR_DELAY:
            self._open().set_postfix_str(text)

    def frames(self, n: int):
        """The bar, counting ``n`` frames from 0 (the rate and the time left count tracked
        frames only)."""
        bar = self._open()
        bar.reset(total=n)
        return bar

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def initial_poses(init, dataset, body, tracker, start: int, check: bool = True) -> list[np.ndarray]:
    """The poses (D,) to start from, best first: the tracker's start hypotheses for ``"auto"``;
    the true pose for ``"groundtruth"``; for a pose file, its pose followed by the automatic
    start's hypotheses (a given start may be wrong: the runner tracks each for a few frames
    and keeps the best, see :func:`track`); ``check`` False: the pose file's pose alone."""
    if init == "auto":
        return tracker.start_hypotheses(start)
    given = initial_pose(init, dataset, body, tracker, start)
    if init == "groundtruth" or not check:
        return [given]
    try:
        return [given, *tracker.start_hypotheses(start)]
    except NoPersonError as exc:
        log.warning("frame %d: the given start pose cannot be checked (%s)", start, exc)
    except ValueError as exc:  # a method without an automatic start
        log.info("the given start pose is not checked: %s", exc)
    return [given]


def initial_pose(init, dataset, body, tracker, start: int) -> np.ndarray:
    """The pose to start from: ``"groundtruth"``, ``"auto"`` or a path to a .npy/.npz pose file."""
    if init == "groundtruth":
        gt = dataset.groundtruth()
        if gt is None or "params" not in gt:
            raise ValueError(f"{dataset.path}: --init groundtruth needs groundtruth.npz with params; "
                             "use --init auto or --init POSE.npy")
        p = np.asarray(gt["params"][start], dtype=np.float64)
        if p.shape != (body.dofs.size,):
            raise ValueError(f"{dataset.path}/groundtruth.npz: params have {p.shape[-1]} DOF, the "
                             f"{body.dofs.preset!r} body has {body.dofs.size}; pass the matching --dof")
        return p
    if init == "auto":
        return tracker.auto_init(start)
    return read_pose_file(init, body.dofs.size)


def read_pose_file(init, size) -> np.ndarray:
    """(D,) the first pose of the .npy/.npz pose file ``init`` (a pose (D,), poses (N, D), or
    an .npz with ``params``); ValueError naming the file when it is not one, or when D is not
    ``size`` (an int, or a tuple of the sizes accepted)."""
    path = Path(init)
    if not path.is_file():
        raise ValueError(f"--init: {init!r} is neither groundtruth, auto nor a pose file")
    arr = np.load(path, allow_pickle=False)
    if isinstance(arr, np.lib.npyio.NpzFile):
        if "params" not in arr:
            raise ValueError(f"{path}: no 'params' array")
        arr = arr["params"]
    arr = np.asarray(arr, dtype=np.float64)
    arr = arr[0] if arr.ndim == 2 else arr
    sizes = (size,) if np.isscalar(size) else tuple(size)
    if arr.ndim != 1 or arr.shape[0] not in sizes:
        expected = " or ".join(f"({n},)" for n in sizes)
        raise ValueError(f"{path}: pose has shape {arr.shape}, expected {expected}")
    return arr


def _first_pose(init, dataset, body, tracker, start: int, stop: int, max_search: int,
                check: bool = True):
    """(frame, poses) to start from; an automatic start that finds no person tries the next
    frames (up to ``max_search`` of them) with a warning, then gives up naming the range."""
    for f in range(start, min(stop, start + max(int(max_search), 1))):
        try:
            return f, initial_poses(init, dataset, body, tracker, f, check)
        except NoPersonError as exc:
            log.warning("%s; trying frame %d", exc, f + 1)
    raise ValueError(f"{dataset.path}: no person found to start from in frames {start}.."
                     f"{min(stop, start + max(int(max_search), 1)) - 1} (--init {init})")


def _step(tracker, f: int, hooks):
    """(estimate, seconds) of frame ``f``, the hooks run first."""
    for hook in hooks:
        hook(tracker, f)
    snap = ENGINE_STATS.snapshot()
    t0 = time.perf_counter()
    est = tracker.step(f)
    secs = time.perf_counter() - t0
    used = ENGINE_STATS.since(snap)
    est.engine_calls, est.engine_seconds = used["calls"], used["seconds"]
    return est, secs


#: Mean qualities within this fraction of the best are a tie: the evidence does not tell the
#: hypotheses apart, and the direction of travel decides. One depth camera separates a body
#: from its turned-round twin by a few per cent at most: on the demo's walks the true first pose
#: scored 4 % better than its refined twin, and the tracked twins differed by 0.4 % and 9 %, the
#: wrong one better both times (the body was estimated on frames it had fitted facing away).
TIE = 0.10
#: Root travel (m) over the decision frames that counts as walking: sustained gait (0.3 m in
#: the 10 frames of a 30 fps decision is 0.9 m/s), not swaying, stepping or dancing on the spot.
WALKED_M = 0.3


def _walking_direction(body, run) -> float | None:
    """Cosine between the body's mean facing direction and its horizontal travel over ``run``
    (a list of (estimate, seconds)); None when the root moved less than :data:`WALKED_M` or
    the skeleton has no hips to face by.

    Facing is the horizontal normal of the hip line (``l_hip - r_hip``) crossed with the
    internal frame's up axis (+Y): at heading 0 the model faces +Z with its left hip at +X.
    """
    names = list(body.skeleton.names)
    if "l_hip" not in names or "r_hip" not in names:
        return None
    P = np.stack([e.params for e, _ in run])
    travel = P[-1, :3] - P[0, :3]
    travel[1] = 0.0
    if np.linalg.norm(travel) < WALKED_M:
        return None
    J = body.joints(P)
    facing = np.cross(J[:, names.index("l_hip")] - J[:, names.index("r_hip")], [0.0, 1.0, 0.0]).mean(0)
    facing[1] = 0.0
    return float(facing @ travel / (np.linalg.norm(facing) * np.linalg.norm(travel) + 1e-12))


#: Share of the knees' decision frames at the extension limit (within half a frame's sigma of
#: it) by which a tied hypothesis must exceed another to lose to it (:func:`_knees_at_limit`).
#: Measured on nine honest depth datasets (walk, hop and salsa, MakeHuman subject, noise seeds
#: 0-2, ``hc+ep``, 10 decision frames): tracks turned round 0.50-1.00, tracks facing the right
#: way 0.00-0.35, and the twins of one dataset 0.35 apart or more.
KNEES_PINNED = 0.25


def _knees_at_limit(body, run) -> float | None:
    """Share of ``run``'s frames (a list of (estimate, seconds)) in which the knees sit at their
    extension limit (the lower one: flexion is positive), within half a frame's sigma of it,
    averaged over the knee DOFs; None when the body has no knee DOF.

    A knee bends one way. A body seen from behind with its knees bent is, to a camera that
    cannot tell front from back, a body facing it with its knees bent backwards; the turned
    twin cannot bend them so and holds them straight against the limit, as far as it can get.
    """
    dofs = body.dofs
    knees = [i for i, n in enumerate(dofs.names) if "knee" in n]
    if not knees:
        return None
    P = np.stack([e.params for e, _ in run])[:, knees]
    return float(np.mean(P < dofs.lower[knees] + 0.5 * dofs.sigma30[knees]))


def _decide(trackers, frames, hooks, incumbent: int | None = None):
    """Track ``frames`` with each started tracker; the index of the one whose mean quality
    (``info["quality"]`` when every frame has one, else the score; lower = better) is lowest,
    and every tracker's (estimate, seconds) per frame.

    ``incumbent``: the index of the hypothesis with the better evidence behind it, kept when
    its mean is within :data:`TIE` of the best: a tie is what a body and its turned-round twin
    give, and then evidence the qualities do not count decides.

    - A re-start's lost tracker, which goes on from its own track: the track's continuity.
      Measured: on the hop clip (noise seed 0) a false alarm (quality 0.47-0.50 on a track
      0.05-0.09 m off) tied 0.431 against the twin's 0.430, the twin was kept and the track
      was 0.3-0.5 m off for 35 frames.
    - The first start, the automatic start's best (:meth:`~gltrack.track.base.Tracker.
      start_hypotheses` ranks its hypotheses by a search on the start frame far wider than a
      tracker's step: each seed refined on its own, limbs mirrored and swept). Measured: on the
      seated caliscope take the start's best faced the cameras, the turned-round twin tied
      (0.330 against 0.359 over 10 frames, as the masks lost the torso) and was kept, and the
      whole take was tracked facing away, 498 mm from the hand-labelled joints against 366
      with the start's best. On 6 simulated walk, hop and salsa datasets (hps) the start's best
      won the means outright or lost them by more than the margin; in the depth bench's honest
      protocol the rule fired once in nine starts (the salsa, ep).

    A tie between a hypothesis whose knees sit at their extension limit and one whose knees
    bend (:func:`_knees_at_limit`, :data:`KNEES_PINNED` apart) goes to the one whose knees
    bend, the incumbent or not: that is the turned twin straining against the knee's hinge.
    Measured on nine honest depth datasets (``hc+ep``): the salsa's start tied on two noise
    seeds (0.245 / 0.233 and 0.247 / 0.245), the incumbent was the turned twin (knees at the
    limit in 75 % and 100 % of the frames against 0 %) and was kept, 0.251 and 0.254 m from the
    markers against 0.122 and 0.141 for the other hypothesis; on the walk's tie (seed 0) the
    incumbent was right and bent its knees (35 % at the limit against its twin's 85 %).

    A tie (means within :data:`TIE` of the best) between a hypothesis that walks forwards and
    one that walks backwards (:func:`_walking_direction`, cosines beyond +-0.5) goes to the one
    walking forwards: people walk forwards far more often than backwards, and on a tie that
    prior is the only evidence left. A body that stands, sways or steps sideways is decided by
    the scores alone.
    """
    runs = [[_step(tr, f, hooks) for f in frames] for tr in trackers]
    means, measure = _means(runs)
    k = int(np.argmin(means))
    tied = [j for j, m in enumerate(means) if m - means[k] <= TIE * abs(means[k])]
    if incumbent is not None and incumbent in tied and incumbent != k:
        log.info("hypotheses %d and %d score within %.0f %%; %d has the better evidence behind "
                 "it and is kept", k, incumbent, 100 * TIE, incumbent)
        k = incumbent
    body = getattr(trackers[k], "body", None)
    pinned = {j: _knees_at_limit(body, runs[j]) for j in tied} if body is not None else {}
    if pinned.get(k) is not None:
        bent = min(tied, key=lambda j: (pinned[j], means[j]))
        if pinned[k] - pinned[bent] >= KNEES_PINNED:
            log.info("start hypotheses %d and %d score within %.0f %%; %d holds its knees at "
                     "the limit in %.0f %% of the frames, %d in %.0f %%, and %d is kept", k,
                     bent, 100 * TIE, k, 100 * pinned[k], bent, 100 * pinned[bent], bent)
            k = bent
    if body is not None and len(runs[0]) > 1:
        cos = {j: _walking_direction(body, runs[j]) for j in tied}
        forwards = [j for j in tied if cos[j] is not None and cos[j] > 0.5]
        if cos[k] is not None and cos[k] < -0.5 and forwards:
            j = min(forwards, key=lambda i: means[i])
            log.info("start hypotheses %d and %d score within %.0f %%; %d walks forwards and is "
                     "kept", k, j, 100 * TIE, j)
            k = j
    log.info("start hypotheses tracked over %d frames: mean %s %s; kept %d",
             len(runs[0]), measure, ", ".join(f"{m:.4g}" for m in means), k)
    return k, runs


def _means(runs) -> tuple[list[float], str]:
    """Each run's mean per-frame figure (lower = better) and its name: ``"quality"`` where
    every frame of every run has one, else ``"score"``.

    The quality is preferred: the score is measured against what each tracker itself observes
    (a multi-view tracker's colour model decides which foreground it scores), the quality also
    counts what that observation left out.
    """
    quality = all(isinstance((e.info or {}).get("quality"), (int, float)) for run in runs
                  for e, _ in run)
    means = [float(np.nanmean([e.info["quality"] if quality else e.score for e, _ in run]))
             for run in runs]
    return means, "quality" if quality else "score"


def _verdict(trackers, runs, k: int) -> dict:
    """What a choice between start hypotheses rested on (JSON-able, for the kept first frame's
    ``info``): how many hypotheses over how many frames, each one's mean, which was kept,
    whether another came within :data:`TIE` of it (``uncertain``: the evidence hardly told them
    apart, whichever rule then chose) and, where the body has a heading DOF, how far each
    hypothesis's first pose is turned from the kept one's (degrees, -180..180) and, where it
    has knees, the share of each hypothesis's frames with its knees at their extension limit
    (``knees_at_limit``, :func:`_knees_at_limit`)."""
    means, measure = _means(runs)
    lowest = min(means)
    uncertain = any(j != k and abs(m - means[k]) <= TIE * abs(lowest) for j, m in enumerate(means))
    rec = {"hypotheses": len(runs), "frames": len(runs[0]), "measure": measure,
           "means": [round(m, 4) for m in means], "kept": int(k), "uncertain": bool(uncertain)}
    body = getattr(trackers[k], "body", None)
    if body is not None and "pelvis_ry" in body.dofs.names:
        yaw = body.dofs.index("pelvis_ry")
        ref = runs[k][0][0].params[yaw]
        rec["turned_deg"] = [round(float(np.degrees(np.angle(np.exp(1j * (run[0][0].params[yaw]
                                                                         - ref))))), 1)
                             for run in runs]
    if body is not None and _knees_at_limit(body, runs[k]) is not None:
        rec["knees_at_limit"] = [round(_knees_at_limit(body, run), 3) for run in runs]
    return rec


def _choose_start(tracker, make, starts, first: int, frames, hooks, incumbent=None):
    """Start ``tracker`` and one new tracker (``make(k)``) per further start hypothesis at
    ``first``, track ``frames`` with all of them and keep the best (the others are closed;
    ``incumbent`` as in :func:`_decide`).

    Returns
    -------
    tracker : the kept tracker
    decided : dict frame -> (estimate, seconds) of the kept tracker's frames
    verdict : dict, what the choice rested on (:func:`_verdict`)
    """
    others = [make(k) for k in range(1, len(starts))]
    everyone = [tracker, *others]
    try:
        for tr, x in zip(others, starts[1:]):
            tr.start(first, x)
        k, runs = _decide(everyone, frames, hooks, incumbent)
    except BaseException:
        for tr in others:
            tr.close()
        raise
    for other in everyone[:k] + everyone[k + 1:]:
        other.close()
    return everyone[k], dict(zip(frames, runs[k])), _verdict(everyone, runs, k)


def _pick_start(starts, k: int, frame: int):
    """The start hypothesis ``k`` alone, and its record for the first frame's ``info``
    (``hypotheses``, ``kept``, ``chosen``); ValueError when there is no hypothesis ``k``."""
    n = len(starts)
    if not 0 <= k < n:
        raise ValueError(f"--start-hypothesis {k}: the start at frame {frame} has {n} "
                         f"hypothes{'is' if n == 1 else 'es'} (0..{n - 1})")
    log.info("frame %d: start hypothesis %d of %d kept (--start-hypothesis)", frame, k, n)
    return [starts[k]], {"hypotheses": n, "kept": int(k), "chosen": "--start-hypothesis"}


def _warn_uncertain_start(first: int, verdict: dict) -> None:
    """Say that the start hypotheses tied (``verdict`` from :func:`_verdict`): the evidence
    hardly chose the kept one, and a body tracked turned round is a whole take lost, so the
    user should look before trusting it."""
    means = ", ".join(f"{m:.3f}" for m in verdict["means"])
    turned = verdict.get("turned_deg")
    apart = "" if turned is None else " (turned " + ", ".join(f"{t:.0f}" for t in turned) + \
        " deg from the kept one)"
    log.warning("frame %d: the %d start hypotheses%s explained frames %d-%d about equally well "
                "(mean %s %s, within %.0f %%); kept %d. A body and its turned-round twin fit "
                "the images about equally well: look at the overlay (gltrack render) to see "
                "that the body faces the right way (if not, track again with "
                "--start-hypothesis %d)", first, verdict["hypotheses"], apart, first,
                first + verdict["frames"] - 1, verdict["measure"], means, 100 * TIE,
                verdict["kept"], next(j for j in range(verdict["hypotheses"])
                                      if j != verdict["kept"]))


def _restart(tracker, make, frame: int, frames, hooks):
    """Re-start a tracker that lost the body: its automatic start on ``frame`` gives new
    hypotheses, each started on a new tracker (``make(k)``); they and the lost tracker (which
    may only have been through a hard stretch) track ``frames`` and the best is kept.

    Returns (tracker, decided) as :func:`_choose_start`; the lost tracker itself when the
    automatic start finds nobody.
    """
    try:
        starts = tracker.start_hypotheses(frame)
    except NoPersonError as exc:
        log.warning("frame %d: lost, and no person to re-start from (%s)", frame, exc)
        return tracker, {}
    # hypothesis 0 is the lost tracker, going on from its own state
    kept, decided, verdict = _choose_start(tracker, make, [None, *starts], frame, frames, hooks,
                                           incumbent=0)
    first = min(decided) if decided else None
    if first is not None:
        restarted = kept is not tracker
        decided[first][0].info["restart"] = {"frame": frame, "hypotheses": len(starts),
                                              "restarted": restarted, "decision": verdict}
        log.warning("frame %d: the body looked lost for a while; %s", frame,
                    "re-started from the automatic start" if restarted
                    else "the current track explains the next frames best and goes on")
    return kept, decided


#: BLAS threads while tracking. gltrack's matrix products are small (a few thousand rows by 10
#: or 15 columns: blob fits, rankings, skinning), where OpenBLAS's threads cost more in
#: hand-off than they save, and they spin on the cores that the next frame's reconstruction
#: (a worker thread, :meth:`BlobEvidence.set_frame
#: <gltrack.observe.blob_evidence.BlobEvidence.set_frame>`) and the GL engine's worker
#: processes need. bench vlmm's loop on a 2-core VM: 19.7 -> 25.3 frames/s with the
#: chi-square segmentation; bench depth --quick unchanged (hc+ep 4.97-6.74 against 5.11-6.59)
TRACK_BLAS_THREADS = 1


@threadpool_limits.wrap(limits=TRACK_BLAS_THREADS, user_api="blas")
def track(dataset_path, method: str, out, *, options: dict | None = None, init: str = "auto",
          resume: bool = False, overwrite: bool = False, frames: tuple | None = None,
          preset: str | None = None, seed: int = 0, progress: bool = True, ctx=None,
          hooks=(), body: str = "estimate", max_search: int = 30,
          decide_frames: int = 10, lost_frames: int = 3, check_start: bool = True,
          force: bool = False, start_hypothesis: int | None = None) -> dict:
    """Track ``dataset_path`` with ``method`` and write the results folder ``out``.

    Parameters
    ----------
    options : dict, tracker options (``--config`` table); unknown keys are errors
    init : "auto" (find the body from nothing, default), "groundtruth" (the true first pose:
        an oracle, for ablations) or a pose file (checked against the automatic start: both
        are tracked ``decide_frames`` frames and the better is kept)
    resume : continue an interrupted run in ``out``
    frames : (start, stop), optional sub-range of the dataset's frames
    preset : DOF preset overriding the body record's
    body : "estimate" (measured from the first frames, default), "dataset" (meta.json's body
        record: an oracle for synthetic data) or a body file
        (:func:`gltrack.track.bodies.resolve_body`); recorded in ``out/body.json``; a resumed
        run keeps the body its results folder records
    progress : show a tqdm progress bar
    hooks : callables ``hook(tracker, frame)`` run before each frame is tracked (fault injection)
    max_search : with ``init="auto"``, frames tried from the first one when a frame shows no
        person (each tried frame logs a warning; tracking starts at the first with a person)
    decide_frames : with ``init="auto"`` and a tracker that returns two start hypotheses (a
        body and its turned-round twin fit one frame about equally well), each is tracked this
        many frames and the one with the lower mean score is kept (its frames are the ones
        written); 0 keeps the first hypothesis
    lost_frames : a tracker whose frames' quality (``info["quality"]``) stays worse than its
        lost limit (:class:`gltrack.track.lost.LossWatch`: the tracker's
        :meth:`~gltrack.track.base.Tracker.lost_threshold`, or twice the recent good frames'
        quality, whichever is lower) for this many frames in a row is
        re-started: its automatic start on that frame and the current track are each tracked
        ``decide_frames`` frames and the best is kept (:func:`_restart`); a check that keeps
        the current track raises the limit to the quality it was kept at, plus its spread
        (:meth:`~gltrack.track.lost.LossWatch.confirm`); 0 never re-starts
    check_start : with a pose file as ``init``, also try the automatic start (False: trust the
        file, e.g. a bench's true first pose in another DOF preset)
    start_hypothesis : keep this start hypothesis (an index into the automatic start's
        hypotheses, after a pose file's pose when ``init`` is one) instead of deciding
        between them over ``decide_frames`` frames; the first frame's ``info["start"]``
        records it (``chosen``). ValueError when the start has fewer hypotheses
    force : with ``resume``, accept a dataset whose fingerprint differs from the one recorded
        in ``out/run.json`` (:mod:`gltrack.data.provenance`; another dataset, first frame, seed
        or options are refused, and a resume without ``frames`` tracks the recorded range)

    Returns
    -------
    dict, the ``timing.json`` contents plus ``out``.
    """
    from gltrack.gl.context import shared_context

    m = lookup(method)
    ds = Dataset.open(dataset_path)
    if ds.rig != m.rig:
        raise ValueError(f"{ds.path}: method {method!r} needs a {m.rig} dataset, this one is {ds.rig!r}")
    opts = m.options.from_dict(options, where=f"options for {method}")
    if resume and frames is None:  # the range the run was started with
        frames = recorded_range(out, ds.frames)
    start, stop = (0, ds.frames) if frames is None else frames
    if not (0 <= start < stop <= ds.frames):
        raise ValueError(f"{ds.path}: frames {start}:{stop} (--frames) outside the dataset's "
                         f"0:{ds.frames}")
    ctx = ctx or shared_context()
    # the body estimate and the automatic start take a minute or two on a real take before
    # the first frame: the bar says what is being done
    shown = _Progress(f"{method} {Path(ds.path).name}", stop - start, progress)
    try:
        if resume and body == "estimate" and (Path(out) / BODY).is_file():
            # the body estimated when the run began, not a new estimate
            body, body_rec = load_body_record(out)
        else:  # the --body choice -> the BodyModel; the estimate's generator is its own
            if body == "estimate" and init not in ("auto", "groundtruth"):
                # a pose file that cannot start this body is refused now, not after the
                # estimate (a minute or more); an estimated body has the canonical joints.
                # Without --dof the estimate picks the preset from the framing, so a file
                # sized for either preset it can pick passes here and is checked again after
                read_pose_file(init, tuple(make_dofs(default_skeleton(), p).size
                                           for p in ((preset,) if preset else FRAMING_PRESETS)))
            shown.say(f"--body {body}")
            body, body_rec = resolve_body(body, ds, preset, ctx=ctx, frames=(start, stop),
                                          rng=np.random.default_rng([seed, 7]),
                                          report=shown.say)
        if resume and (Path(out) / BODY).is_file():
            # the seat the run's start found (a seated subject): the same limits as before
            seat = load_body_record(out)[1].get("seat")
            if seat is not None:
                hold_seat(body, seat, where=f"{Path(out) / BODY}: field 'seat'")
                body_rec = dict(body_rec, seat=seat)
        rng = np.random.default_rng(seed)
        tracker = m.tracker(ds, body, ctx, opts, rng)
        writer = ResultsWriter(out, method, list(body.skeleton.names), list(body.markers.names),
                               resume=resume, overwrite=overwrite, body=body_rec,
                               world=ds.meta.get("world"),  # joints/markers in the user's frame
                               provenance=run_provenance(ds, dataclasses.asdict(opts), seed,
                                                         init, (start, stop), body_rec),
                               force=force)
    except BaseException:
        shown.close()
        raise
    decided = {}  # frames already tracked while deciding between start hypotheses
    chosen = None  # the record of a start hypothesis kept by start_hypothesis, for frame one
    watch = LossWatch(tracker.lost_threshold(), tracker.relative_loss)
    finished = {}  # resumed: frame -> written params of the frames tracked again, not written
    try:
        done = writer.done_frames
        if resume and done:
            last = writer.last()
            first = int(last["frame"]) + 1
            arrays = writer.arrays()
            written = dict(zip(arrays["frame"].tolist(), arrays["params"]))
            saved = checkpoint.load(out, method, written)
            if saved is not None:  # the state the uninterrupted run had: bit-identical frames
                decided = checkpoint.restore(saved, tracker, watch)
                finished = {f: written[f] for f in range(saved["frame"] + 1, first)}
                first = saved["frame"] + 1
            else:
                tracker.start(first - 1, np.asarray(last["params"]))
            log.info("resuming after frame %d%s", first - 1,
                     " from its checkpoint" if saved is not None else "")
        else:
            checkpoint.discard(out)
            t0 = time.perf_counter()
            shown.say(f"--init {init}: finding the start")
            first, starts = _first_pose(init, ds, body, tracker, start, stop, max_search,
                                        check_start)
            if start_hypothesis is not None:
                starts, chosen = _pick_start(starts, start_hypothesis, first)
            if seated(body.dofs.preset):
                # seen from the waist up: seated, so the pelvis stays near where it starts
                # (SEAT_REACH); body.json records the seat, a resumed run holds it too
                body_rec = dict(body_rec, seat=seat_of(starts[0]))
                hold_seat(body, body_rec["seat"])
                writer.update_body(body_rec)
                log.info("seated: the pelvis is held within %.2f m of %s", body_rec["seat"]["reach"],
                         np.round(np.asarray(starts[0][:3]), 3).tolist())
            tracker.start(first, starts[0])
            if len(starts) > 1 and decide_frames > 0:
                shown.say(f"--init {init}: {len(starts)} start hypotheses, each "
                          f"tracked {min(stop - first, decide_frames)} frames")
                # each other hypothesis gets its own tracker and a generator derived from the
                # seed, so the choice and what follows are reproducible
                make = (lambda k: m.tracker(ds, body, ctx, opts, np.random.default_rng([seed, k])))
                # a tie keeps the start's own best (see _decide)
                tracker, decided, verdict = _choose_start(
                    tracker, make, starts, first, range(first, min(stop, first + decide_frames)),
                    hooks, incumbent=0)
                decided[first][0].info["start"] = verdict
                if verdict["uncertain"]:
                    _warn_uncertain_start(first, verdict)
            log.info("initialised (%s) at frame %d in %.2f s", init, first,
                     time.perf_counter() - t0)
        bar = shown.frames(stop - first)
        for f in range(first, stop):
            est, secs = decided.pop(f) if f in decided else _step(tracker, f, hooks)
            if chosen is not None:
                est.info["start"], chosen = chosen, None
            p = est.params[None]
            if f in finished:  # written before a kill that came before its checkpoint
                checkpoint.replayed(f, est, finished)
            else:
                writer.append(f, est.params, body.joints(p)[0], body.marker_positions(p)[0],
                              est.score, est.evaluations, secs, info=est.info,
                              engine_calls=est.engine_calls, engine_seconds=est.engine_seconds)
            bar.update(1)
            bar.set_postfix(evals=est.evaluations, s=f"{secs:.2f}")
            bad = watch.update(est.info.get("quality"))
            if lost_frames > 0 and bad >= lost_frames and not decided and f + 1 < stop:
                shown.say(f"frame {f} looks lost: re-start check")
                watch.reset()
                make = (lambda k, f=f: m.tracker(ds, body, ctx, opts,
                                                 np.random.default_rng([seed, f, k])))
                kept, decided = _restart(tracker, make, f,
                                         range(f + 1, min(stop, f + 1 + max(decide_frames, 1))),
                                         hooks)
                if kept is tracker and decided:  # nothing explained the frames better
                    watch.confirm([e.info.get("quality") for e, _ in decided.values()])
                tracker = kept
            checkpoint.save(out, method, f, est.params, tracker, watch, decided)
        timing = writer.finish()
        arrays = writer.arrays()
        write_params_bvh(Path(out) / "poses.bvh", body, arrays["params"], ds.fps)
    finally:
        tracker.close()
        writer.close()
        shown.close()
    timing = dict(timing)
    timing["out"] = str(out)
    return timing
