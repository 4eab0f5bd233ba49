"""``gltrack bench vlmm``: the behaviour-model tracker of Caillette, Galata & Howard (2008).

The model is learnt from the training takes of one salsa dancer (:data:`TRAIN_DIR`: CMU subject
60, eleven takes, retargeted to the 25-DOF body at 30 frames/s, each take its own sequence) and
tested on a take it never saw (:data:`CLIP`, cmu_60_10), synthesised as a multi-view dataset
with the sensor simulator (four colour cameras, cluttered room, MOG2 masks). Reported:

* the model: clusters picked by the Figueiredo-Jain MML criterion, VLMM states, learning time,
  entropy (eq. 2) on the training takes and on the unseen take, and against the maximal memory;
* **protocol 1, motion models only** (the paper's Fig. 12): the blob fit of every frame starts
  from the *true* pose (``fit_from = "groundtruth"``, a labelled oracle of the protocol itself,
  not of the tracker), so every method weighs against the same good but noisy evidence, and the
  trackers start from the true first pose; ``vlmm`` 200 particles against ``condensation`` 5000
  and ``apf-blobs`` 1000 x 5 layers, RMS joint position error over the frames, several seeds;
* **protocol 2, the whole system** (Fig. 11): the blob fit starts from the trackers' own
  predictions (for ``vlmm``: the predicted poses of the best-supported clusters, plus its
  ``fit_prototypes`` cluster means placed on the voxels; the best voxel likelihood wins), the
  trackers start from nothing (``--init auto``); ``vlmm`` 1000 against the same baselines; then
  recovery (a labelled ablation: true start): at tracked frame :data:`FAIL_AT` the particle set
  is turned by 2.5 rad (:data:`FAIL_RAD`) and moved by 0.5 m
  (:func:`gltrack.bench.faults.set_fault`) and the frames until the RMS joint error is back
  under :data:`RECOVERED_M` are counted (``vlmm`` recovers by itself; ``condensation`` has no
  recovery); the same with the set turned round (:data:`FAIL_TURNED_ROUND`), reported beside
  it; then the honest protocol (:data:`HONEST_RUNS`), and its VLMM run again with the true
  body (a labelled ablation: what the body estimate costs, joint by joint).

Frames per second and the time of each stage (voxels at depth 7, blob fit, particle filter) are
reported for every run. ``--quick`` uses 20 frames, one seed and smaller particle counts (not
the issue's figures). The synthetic-data helpers at the top are also used by the tests.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from .faults import set_fault

log = logging.getLogger(__name__)

CLIP = "mocap/cmu_60_10_salsa_daz_metres.bvh"
#: training takes of the same dancer (relative to the shared folder); CLIP is not among them
TRAIN_DIR = "mocap/cmu_60_salsa"
TILE = 64


# ------------------------------------------------------------------------ synthetic data
def render_masks(body, params, cameras) -> list:
    """Foreground masks of the skinned body: list over frames of lists over cameras of (H, W)
    bool (CPU reference rasteriser)."""
    from gltrack.render import reference as ref

    S = body.skinning(params)
    out = [[None] * len(cameras) for _ in range(len(S))]
    for c, cam in enumerate(cameras):
        z, _ = ref.render_candidates(body.mesh, S, cam.K, cam.R, cam.t, cam.width, cam.height)
        for f in range(len(S)):
            out[f][c] = z[f] > 0
    return out


def make_multiview_dataset(out, body, params, cameras, fps: float = 30.0):
    """Write a multi-view dataset (grey-on-black colour frames, masks, ground truth) of
    ``params`` (T, D) posed on ``body``; returns the masks as :func:`render_masks`."""
    from gltrack.body.model import body_to_meta
    from gltrack.data.dataset import DatasetWriter

    masks = render_masks(body, params, cameras)
    with DatasetWriter(out, "multiview", fps, cameras,
                       body={**body_to_meta(body.skeleton, body.dofs.preset, body.lod)}) as w:
        for f, ms in enumerate(masks):
            for c, m in enumerate(ms):
                w.write_colour(f, c, np.repeat((m * 180 + 30).astype(np.uint8)[..., None], 3, 2))
                w.write_mask(f, c, m)
        w.write_groundtruth(body.joints(params), list(body.skeleton.names),
                            body.marker_positions(params), params)
    return masks


def periodic_motion(body, n: int, fps: float = 30.0, phase: float = 0.0,
                    period: float = 1.2) -> np.ndarray:
    """A walk-like cycle in place: (n, D) params of ``body`` (any preset with hips, knees,
    shoulders and elbows), ``period`` seconds per cycle, starting at ``phase`` radians."""
    d, sk = body.dofs, body.skeleton
    w = 2 * np.pi * (np.arange(n) / fps) / period + phase
    P = np.repeat(d.zero(sk)[None], n, axis=0)
    P[:, d.index("pelvis_ry")] = 0.3
    P[:, 1] += 0.02 * np.cos(2 * w)
    for side, s in (("l", 1.0), ("r", -1.0)):
        P[:, d.index(f"{side}_hip_rx")] = -0.5 * s * np.sin(w)
        P[:, d.index(f"{side}_knee_rx")] = 0.6 + 0.5 * np.sin(w + s * 1.2)
        P[:, d.index(f"{side}_shoulder_rz")] = -s * 1.2
        P[:, d.index(f"{side}_shoulder_ry")] = 0.7 * s * np.sin(w)
        P[:, d.index(f"{side}_elbow_ry")] = -s * (0.6 + 0.4 * np.sin(w + 0.5))
    return d.validate(P)


# ------------------------------------------------------------------------------ the bench
#: protocol 1 (motion models only): (label, method, options), full and quick
PROTOCOL1 = {
    False: [("vlmm_200", "vlmm", {"particles": 200}),
            # ablations: the paper's velocity random walk (eq. 4), the walk with the
            # velocities kept inside a cluster (see VlmmPrior's velocity and lam_dx), and the
            # paper's root diffusion instead of the learnt root dynamics (VlmmPrior's root)
            ("vlmm_200_walk", "vlmm", {"particles": 200, "velocity": "walk"}),
            ("vlmm_200_root_walk", "vlmm", {"particles": 200, "root": "walk"}),
            ("vlmm_200_lam_dx0", "vlmm", {"particles": 200, "velocity": "walk", "lam_dx": 0.0}),
            # the local dynamics' noise from the clusters' diagonal covariances (the default
            # before the full ones), and the full ones with the velocity regressed on the
            # angles (VlmmPrior's local)
            ("vlmm_200_diag", "vlmm", {"particles": 200, "local": "diag"}),
            ("vlmm_200_regressed", "vlmm", {"particles": 200, "local": "regressed"}),
            # the behaviour prior as the first of 5 annealing layers (option layers), against
            # the diffusion filter with the same 1000 evaluations a frame
            ("vlmm_200x5", "vlmm", {"particles": 200, "layers": 5}),
            ("condensation_5000", "condensation", {"particles": 5000}),
            ("apf_1000x5", "apf-blobs", {"particles": 1000, "layers": 5}),
            ("apf_200x5", "apf-blobs", {"particles": 200, "layers": 5}),
            # the three filters with the closed-form root translation (option root_align, off
            # by default: the paper's filters sample it like any other DOF, and aligned, a lost
            # set no longer looks lost to the vlmm tracker's loss test)
            ("vlmm_200_align", "vlmm", {"particles": 200, "root_align": True}),
            ("condensation_5000_align", "condensation",
             {"particles": 5000, "root_align": True}),
            ("apf_1000x5_align", "apf-blobs",
             {"particles": 1000, "layers": 5, "root_align": True})],
    True: [("vlmm_200", "vlmm", {"particles": 200}),
           ("condensation_1000", "condensation", {"particles": 1000}),
           ("apf_200x5", "apf-blobs", {"particles": 200, "layers": 5})],
}
#: protocol 2 (the whole system); the first row is the VLMM of the targets, the third the
#: diffusion baseline of the recovery runs
PROTOCOL2 = {
    False: [("vlmm_1000", "vlmm", {"particles": 1000}),
            # the same with the paper's own segmentation (chi-square test against the
            # background frames instead of the dataset's masks): the loop's other speed target
            ("vlmm_1000_colour", "vlmm", {"particles": 1000, "segmentation": "colour"}),
            ("vlmm_200", "vlmm", {"particles": 200}),
            # the clusters' diagonal covariances for the local dynamics (the default before)
            ("vlmm_1000_diag", "vlmm", {"particles": 1000, "local": "diag"}),
            # with the closed-form root translation (option root_align)
            ("vlmm_1000_align", "vlmm", {"particles": 1000, "root_align": True}),
            # annealing after the prediction, at the diffusion baselines' 5000 evaluations
            ("vlmm_1000x5", "vlmm", {"particles": 1000, "layers": 5}),
            ("condensation_5000", "condensation", {"particles": 5000}),
            ("apf_1000x5", "apf-blobs", {"particles": 1000, "layers": 5})],
    True: [("vlmm_200", "vlmm", {"particles": 200}),
           ("condensation_1000", "condensation", {"particles": 1000}),
           ("apf_200x5", "apf-blobs", {"particles": 200, "layers": 5})],
}
#: the honest protocol (issue 12): the whole system as protocol 2, on a subject drawn with a
#: rigged MakeHuman mesh (not the tracker's), with the body estimated from the first frames
#: and the automatic start; the VLMM of the targets and the two diffusion baselines
HONEST_RUNS = {
    False: [("vlmm_1000", "vlmm", {"particles": 1000}),
            ("condensation_5000", "condensation", {"particles": 5000}),
            ("apf_1000x5", "apf-blobs", {"particles": 1000, "layers": 5})],
    True: [("vlmm_200", "vlmm", {"particles": 200}),
           ("condensation_1000", "condensation", {"particles": 1000})],
}
#: the honest protocol's wrong start: the true first pose turned this far about the vertical
#: (issue 12: detected, and back under RECOVERED_M within TARGET_WRONG_START frames)
WRONG_START_RAD = np.pi / 2
TARGET_WRONG_START = 15
#: failure injected at this tracked frame in the recovery runs
FAIL_AT = 10
#: the injected failure: the particle set turned by this many radians and moved this far (m).
#: 2.5 rad, not the 1.5 of before: with ``root_align`` the shift is absorbed in the frame it
#: strikes, and a 1.5 rad turn alone puts the joints only ~0.11 m RMS off, on the 0.1 m
#: threshold of recovery itself (Condensation, which cannot recover, then "recovered" to
#: 0.098 m and stayed there); 2.5 rad puts them 0.17 m off, a failure either way
FAIL_RAD, FAIL_SHIFT = 2.5, 0.5
#: a second failure, reported beside it: the set turned round (pi), the blob evidence's
#: ambiguous twin (it fits a body facing the other way about as well); the blob KL's loss
#: test does not see it (nor a 2.5 rad turn without the shift: docs/measurements.md)
FAIL_TURNED_ROUND = np.pi
RECOVERED_M = 0.1
#: protocol 2 target (issue 16): VLMM-1000 RMS joint error over the take, metres
TARGET_RMS_M = 0.1
#: recovery target, frames
TARGET_RECOVERY = 30
TARGET_FPS = 10.0


def joint_errors(res, gt) -> tuple[list, np.ndarray]:
    """The joints of :data:`gltrack.eval.metrics.EVAL_JOINTS` present on both sides, and their
    (N, J) position errors in each result frame, metres."""
    from gltrack.eval.metrics import EVAL_JOINTS, common_names

    names, ip, ig = common_names(res["joint_names"], gt["joint_names"], EVAL_JOINTS)
    frame = np.asarray(res.get("frame", np.arange(len(res["joints"]))), dtype=np.int64)
    d = np.asarray(res["joints"])[:, ip] - np.asarray(gt["joints"])[frame][:, ig]
    return names, np.linalg.norm(d, axis=-1)


def rms_joint_error(res, gt) -> np.ndarray:
    """(N,) root-mean-square joint position error of each result frame, metres (the joints of
    :func:`joint_errors`)."""
    _, e = joint_errors(res, gt)
    return np.sqrt(np.mean(e * e, axis=1))


def _track_run(ds, method, opts, out, seed, hooks=(), init="groundtruth", body="dataset",
               preset=None):
    """Track ``ds`` with ``method`` into ``out`` from ``init`` (a mode or a pose file) with
    ``body`` (and DOF ``preset``, default the body's); returns (row dict, per-frame RMS
    errors)."""
    from gltrack.data.dataset import Dataset
    from gltrack.data.results import load_results
    from gltrack.eval.metrics import evaluate
    from gltrack.track.runner import track

    t0 = time.perf_counter()
    # protocols 1 and 2 give the dataset's true body (they compare motion models, not the
    # body estimate); the honest protocol estimates it
    timing = track(ds, method, out, options=opts, overwrite=True, progress=False, seed=seed,
                   hooks=hooks, init=str(init), body=body, preset=preset)
    wall = time.perf_counter() - t0
    res = load_results(out)
    with Dataset.open(ds) as d:
        gt = d.groundtruth()
    m = evaluate(res, gt)
    names, err = joint_errors(res, gt)
    rms = np.sqrt(np.mean(err * err, axis=1))  # as rms_joint_error
    frames = int(timing["frames"])
    row = {"method": method, "seed": int(seed), "init": str(init), "body": body,
           "options": {k: v for k, v in opts.items() if k != "model"},
           "rms_joint_error_m": float(rms.mean()),
           "mean_joint_error_mm": float(m["mean_joint_error_mm"]),
           "marker_mean_m": float(m["marker_mean_m"]),
           # facing the wrong way: the blob evidence fits a body's turned-round twin about as
           # well, which is where protocol 2 loses the dancer (after the spins)
           "frac_turned_round": float(m["frac_turned_round"]),
           "evaluations_per_frame": timing["evaluations"] / max(frames, 1),
           "fps": float(timing.get("fps") or frames / max(wall, 1e-9)),
           "rms_over_time_m": [round(float(e), 4) for e in rms],
           # mean over the frames per joint: where one run loses against another
           "joint_error_mm": {n: round(1000.0 * float(v), 1) for n, v in zip(names, err.mean(0))}}
    stages = timing.get("stage_seconds")
    if stages:
        row["stage_seconds_per_frame"] = {k: v / max(frames, 1) for k, v in stages.items()}
    return row, rms


def test_take_path(root: Path, take: str | None = None) -> Path:
    """The test take: :data:`CLIP`, or the take of :data:`TRAIN_DIR` whose file name starts with
    ``take`` (e.g. ``"cmu_60_13"``; it then leaves the training set and CLIP joins it).

    Raises
    ------
    FileNotFoundError naming the takes there are when none (or several) match.
    """
    if not take:
        return root / CLIP
    found = sorted((root / TRAIN_DIR).glob(f"{take}*.bvh"))
    if len(found) != 1:
        names = ", ".join(f.stem for f in sorted((root / TRAIN_DIR).glob("*.bvh"))) or "none"
        raise FileNotFoundError(f"--test-take {take!r}: {len(found)} takes of {TRAIN_DIR} match "
                                f"(there are: {names})")
    return found[0]


def training_files(root: Path, test: Path | None = None) -> list[Path]:
    """The training takes under ``root``: those of :data:`TRAIN_DIR` and :data:`CLIP` that exist,
    less the test take ``test`` (default CLIP), which is never trained on."""
    files = sorted((root / TRAIN_DIR).glob("*.bvh")) + [root / CLIP]
    test = Path(test or root / CLIP).resolve()
    return [f for f in files if f.is_file() and f.resolve() != test]


def load_training(root: Path, fps: float = 30.0, preset: str = "25", test: Path | None = None):
    """The :func:`training_files` as (list of (T_i, D) params, list of file names, DofSet); each
    take is its own sequence (no transition across takes)."""
    from gltrack.motion.retarget import load_motion

    files = training_files(root, test)
    if not files:
        raise FileNotFoundError(f"bench vlmm needs the training takes {TRAIN_DIR}/*.bvh in the "
                                "shared folder (GLTRACK_SHARED or ../shared)")
    seqs, dofs = [], None
    for f in files:
        _, dofs, p, _ = load_motion(f, preset, fps=fps, skip_jumps=True)
        seqs.append(p)
    return seqs, [f.name for f in files], dofs


def _summary(rows: list) -> dict:
    """Mean and spread over seeds of the runs of one configuration."""
    rms = np.array([r["rms_joint_error_m"] for r in rows])
    return {"method": rows[0]["method"], "options": rows[0]["options"],
            "seeds": [r["seed"] for r in rows], "rms_joint_error_m": float(rms.mean()),
            "rms_joint_error_std_m": float(rms.std()), "rms_per_seed_m": rms.tolist(),
            "mean_joint_error_mm": float(np.mean([r["mean_joint_error_mm"] for r in rows])),
            "frac_turned_round": float(np.mean([r["frac_turned_round"] for r in rows])),
            "evaluations_per_frame": float(np.mean([r["evaluations_per_frame"] for r in rows])),
            "fps": float(np.mean([r["fps"] for r in rows])),
            "stage_seconds_per_frame": {
                k: float(np.mean([r.get("stage_seconds_per_frame", {}).get(k, 0.0)
                                  for r in rows]))
                for k in ("voxels", "blob_fit", "particle_filter")},
            "joint_error_mm": {n: float(np.mean([r["joint_error_mm"][n] for r in rows]))
                               for n in rows[0].get("joint_error_mm", {})
                               if all(n in r.get("joint_error_mm", {}) for r in rows)},
            "rms_over_time_m": rows[0]["rms_over_time_m"], "runs": rows}


def bench_vlmm(quick: bool = False, seed: int = 0, shared=None, frames: int | None = None,
               seeds: int | None = None, first: int = 0, protocols=(1, 2),
               vlmm_options: dict | None = None, only=None, test_take: str | None = None,
               learn_options: dict | None = None) -> dict:
    """The measurements of Caillette et al.'s behaviour-model tracker (see module docstring).

    Parameters
    ----------
    quick : bool, 20 frames, one seed, smaller particle counts (not the issue's figures)
    seed : int, seeds the clustering and the simulator; tracker seeds are seed, seed + 1, ...
    shared : path of the shared reference folder (default: GLTRACK_SHARED or ../shared)
    frames : frames of the test take to track (default 20 quick, 150 full: 5 s at 30 fps)
    seeds : tracker seeds per configuration (default 1 quick, 3 full)
    first : first frame of the test take (after its leading T-pose is skipped)
    protocols : which protocols to run: 1, 2 and "honest" (:data:`HONEST_RUNS`: protocol 2 on
        a MakeHuman subject with the estimated body, and :data:`WRONG_START_RAD`'s wrong start)
    vlmm_options : extra options of every ``vlmm`` run (to measure a change of the tracker)
    only : labels of the runs to do (default all), e.g. ``["vlmm_1000"]``
    learn_options : extra keyword arguments of :meth:`BehaviourModel.fit` (e.g. ``k_max``)
    test_take : test on this take of :data:`TRAIN_DIR` instead of :data:`CLIP`, which is then
        trained on (:func:`test_take_path`): the same measurement on another unseen take

    Returns
    -------
    dict (JSON-able): ``model`` (the report of the model learnt from the training takes, with
    the held-out entropy on the test take), ``learn_seconds``, ``entropy_vs_memory``,
    ``protocol1`` and ``protocol2`` (one summary per configuration: RMS joint error mean and
    spread over seeds, per seed and over time, evaluations per frame, fps, stage times),
    ``recovery``, ``targets``.

    Raises
    ------
    FileNotFoundError when the test take or the training takes are absent; RuntimeError when
    the simulator is missing.
    """
    import importlib.util
    import tempfile

    from gltrack.data.simulate import synthesize_in_subprocess
    from gltrack.motion.behaviour import BehaviourModel
    from gltrack.motion.retarget import load_motion

    from . import machine_name, shared_dir

    for name, value, least in (("frames", frames, 2), ("seeds", seeds, 1)):
        if value is not None and value < least:
            raise ValueError(f"--{name} {value}: must be at least {least}")
    root = Path(shared) if shared else shared_dir()
    clip = test_take_path(root, test_take) if root else None
    if clip is None or not clip.is_file():
        raise FileNotFoundError(f"bench vlmm needs {CLIP} in the shared folder "
                                "(GLTRACK_SHARED or ../shared)")
    # Only look for pyrender: importing it here would pin PyOpenGL's platform in this
    # process, which holds a moderngl context (the simulator runs in a spawn child).
    if importlib.util.find_spec("pyrender") is None:
        raise RuntimeError("bench vlmm synthesises its test sequence with the sensor simulator, "
                           "which needs pyrender (pip install pyrender)")
    fps = 30.0
    t0 = time.perf_counter()
    train, train_files, dofs = load_training(root, fps, test=clip)
    sk, _, test_all, _ = load_motion(clip, "25", fps=fps, skip_jumps=True)
    model = BehaviourModel.fit(train, fps, np.random.default_rng(seed), held_out=[test_all],
                               dof_names=dofs.names[6:], **(learn_options or {}))
    learn_s = time.perf_counter() - t0
    sweep = model.memory_sweep(train, [test_all], [0, 1, 2, 3, 5, 8, 10] if quick else
                               list(range(0, 16)))
    n_frames = min(len(test_all) - first, frames or (20 if quick else 150))
    test = test_all[first:first + n_frames]
    seeds = seeds or (1 if quick else 3)
    out = {"machine": machine_name(), "clip": str(clip.relative_to(root)),
           "train_takes": train_files, "fps": fps,
           "train_frames": int(sum(len(s) for s in train)), "test_frames": int(n_frames),
           "test_first_frame": int(first), "test_take_frames": int(len(test_all)),
           "seed": seed, "seeds": int(seeds), "quick": bool(quick), "learn_seconds": learn_s,
           "vlmm_options": dict(vlmm_options or {}),
           "learn_options": dict(learn_options or {}),
           "model": model.report(), "entropy_vs_memory": sweep, "protocol1": {},
           "protocol2": {}, "recovery": {}}
    with tempfile.TemporaryDirectory(prefix="gltrack-bench-vlmm-") as tmp:
        tmp = Path(tmp)
        model_path = tmp / "model.npz"
        model.save(model_path)
        t0 = time.perf_counter()
        if {1, 2} & set(protocols):  # the honest protocol draws its own subject
            ds = synthesize_in_subprocess(test, sk, dofs, fps, "multiview", str(tmp / "ds"),
                                          seed=seed, progress=False, overwrite=True, lod=0)
            log.info("simulated %d frames in %.1f s", n_frames, time.perf_counter() - t0)

        def opts_of(method, opts, fit_from):
            o = dict(opts, fit_from=fit_from)
            if method == "vlmm":
                o.update(vlmm_options or {}, model=str(model_path))
            return o

        # protocol 1: the blob fit from the true pose (oracle of the protocol), true start
        # protocol 2: the blob fit from the predictions, automatic start
        for pn, runs, fit_from, init in ((1, PROTOCOL1[quick], "groundtruth", "groundtruth"),
                                         (2, PROTOCOL2[quick], "predictions", "auto")):
            if pn not in protocols:
                continue
            for label, method, opts in runs:
                if only is not None and label not in only:
                    continue
                rows = []
                for s in range(seed, seed + seeds):
                    row, _ = _track_run(ds, method, opts_of(method, opts, fit_from),
                                        tmp / f"p{pn}_{label}_{s}", s, init=init)
                    rows.append(row)
                    log.info("protocol %d %s seed %d: RMS %.1f mm, %.2f fps", pn, label, s,
                             1000 * row["rms_joint_error_m"], row["fps"])
                out[f"protocol{pn}"][label] = _summary(rows)
        if 2 in protocols and n_frames > FAIL_AT + 1:
            rec_runs = [PROTOCOL2[quick][0],  # the VLMM of the targets, then the diffusion
                        next(r for r in PROTOCOL2[quick] if r[1] == "condensation")]
            # the targets read the first entry (the VLMM, the main failure)
            cases = [(label, method, opts, suffix, rad)
                     for suffix, rad in (("", FAIL_RAD), ("_turned_round", FAIL_TURNED_ROUND))
                     for label, method, opts in rec_runs]
            for label, method, opts, suffix, rad in cases:
                if only is not None and label not in only:
                    continue
                row, rms = _track_run(ds, method, opts_of(method, opts, "predictions"),
                                      tmp / f"recovery_{label}{suffix}", seed,
                                      init="groundtruth",
                                      hooks=[set_fault(FAIL_AT, rad, FAIL_SHIFT)])
                after = rms[FAIL_AT:]
                ok = np.nonzero(after < RECOVERED_M)[0]
                out["recovery"][label + suffix] = {
                    "failure_at_frame": FAIL_AT, "turned_rad": float(rad),
                    "shift_m": FAIL_SHIFT,
                    "rms_at_failure_m": float(after[0]) if len(after) else None,
                    "frames_to_recover": int(ok[0]) if len(ok) else None,
                    "frames_observed": int(len(after)), "threshold_m": RECOVERED_M,
                    "rms_over_time_m": row["rms_over_time_m"]}
        if "honest" in protocols:
            out["honest"] = _bench_honest(root, test, sk, dofs, fps, tmp, seed, seeds,
                                          HONEST_RUNS[quick], opts_of, only)
    out["targets"] = _vlmm_targets(out, quick)
    return out


def _bench_honest(root, test, sk, dofs, fps, tmp, seed, seeds, runs, opts_of, only) -> dict:
    """The honest protocol: ``runs`` (protocol 2's blob fit from the predictions) on ``test``
    drawn with :data:`gltrack.bench.protocols.SUBJECT_MESH`, each with the estimated body and
    the automatic start; then the first run again with the dataset's true body (a labelled
    ablation, never a target: how much of the loss is the body estimate's, joint by joint);
    then the first run from the true first pose turned by :data:`WRONG_START_RAD` (a pose
    file, checked against the automatic start as a user's would be). Returns {"runs": {label:
    summary + body_error}, "true_body": {"run": label, **summary}, "wrong_start": {...}}.

    Raises
    ------
    FileNotFoundError when the subject mesh is not in ``root``.
    """
    from gltrack.data.simulate import synthesize_in_subprocess

    from .protocols import HONEST, body_error_of

    subject = Path(root) / HONEST.subject
    if not subject.is_file():
        raise FileNotFoundError(f"{subject}: the honest protocol's subject mesh is missing")
    ds = synthesize_in_subprocess(test, sk, dofs, fps, "multiview", str(tmp / "honest_ds"),
                                  seed=seed, progress=False, overwrite=True, lod=0,
                                  subject=str(subject))
    res = {"subject": HONEST.subject, "runs": {}}

    def seeds_of(label, method, opts, body):
        rows = []
        for s in range(seed, seed + seeds):
            out = tmp / f"honest_{label}_{body}_{s}"
            # the behaviour model's DOF preset, as protocols 1 and 2 track with (the estimated
            # body's default is the full preset): only the body, start and subject differ
            row, _ = _track_run(ds, method, opts_of(method, opts, "predictions"), out, s,
                                init=HONEST.init, body=body, preset=dofs.preset)
            row["body_error"] = body_error_of(out, ds)
            rows.append(row)
            log.info("honest %s, body %s, seed %d: RMS %.1f mm", label, body, s,
                     1000 * row["rms_joint_error_m"])
        return dict(_summary(rows), body_error=rows[0]["body_error"])

    for label, method, opts in runs:
        if only is None or label in only:
            res["runs"][label] = seeds_of(label, method, opts, HONEST.body)
    if not res["runs"]:
        return res
    label, method, opts = next(r for r in runs if r[0] in res["runs"])
    # an ablation (labelled, never a target): the same run with the dataset's true body, so
    # the table says how much of the honest protocol's loss is the body estimate's
    res["true_body"] = {"run": label, **seeds_of(label, method, opts, "dataset")}
    x0 = np.array(test[0], dtype=np.float64)
    x0[dofs.index("pelvis_ry")] += WRONG_START_RAD
    pose = tmp / "honest_wrong_start.npy"
    np.save(pose, x0)
    row, rms = _track_run(ds, method, opts_of(method, opts, "predictions"),
                          tmp / "honest_wrong_start", seed, init=pose, body=HONEST.body,
                          preset=dofs.preset)
    ok = np.nonzero(rms < RECOVERED_M)[0]
    res["wrong_start"] = {"run": label, "turned_rad": WRONG_START_RAD,
                          "threshold_m": RECOVERED_M,
                          "frames_to_recover": int(ok[0]) if len(ok) else None,
                          "rms_joint_error_m": row["rms_joint_error_m"],
                          "rms_over_time_m": row["rms_over_time_m"]}
    return res


def _vlmm_targets(out: dict, quick: bool) -> dict:
    """The issue's targets evaluated on the measured rows (None where a run is missing)."""
    p1, p2 = out.get("protocol1", {}), out.get("protocol2", {})

    def rms(tab, label):
        """The row ``label``, else the first whose label starts with it (quick runs' counts)."""
        if label in tab:
            return tab[label]["rms_joint_error_m"]
        return next((r["rms_joint_error_m"] for k, r in tab.items() if k.startswith(label)),
                    None)

    # the paper's comparison: the 5000-evaluation baselines (not the equal-evaluation apf_200x5)
    v200, cond = rms(p1, "vlmm_200"), rms(p1, "condensation")
    apf = rms(p1, "apf" if quick else "apf_1000x5")
    v_sys = rms(p2, "vlmm_1000" if not quick else "vlmm_200")
    # the one-layer filter's rate (the annealed rows spend several evaluations a particle)
    loop = next((r["fps"] for k, r in p2.items() if k.startswith("vlmm")
                 and not k.endswith(("_colour", "x5"))), None)
    loop_colour = next((r["fps"] for k, r in p2.items() if k.startswith("vlmm")
                        and k.endswith("_colour")), None)
    rec = next(iter(out.get("recovery", {}).values()), {}).get("frames_to_recover")
    honest = out.get("honest") or {}
    h_sys = rms(honest.get("runs", {}), "vlmm")
    wrong = (honest.get("wrong_start") or {})
    return {
        "p1_vlmm_le_condensation": None if None in (v200, cond) else bool(v200 <= cond),
        "p1_vlmm_le_1.2_apf": None if None in (v200, apf) else bool(v200 <= 1.2 * apf),
        "p2_vlmm_rms_m": v_sys, "p2_target_rms_m": TARGET_RMS_M,
        "p2_vlmm_rms_met": None if v_sys is None else bool(v_sys <= TARGET_RMS_M),
        "recovery_frames": rec,
        "recovery_within_30": None if not out.get("recovery") else
        bool(rec is not None and rec <= TARGET_RECOVERY),
        "loop_fps": loop, "loop_fps_colour": loop_colour, "loop_fps_target": TARGET_FPS,
        "honest_vlmm_rms_m": h_sys,
        "honest_vlmm_rms_met": None if h_sys is None else bool(h_sys <= TARGET_RMS_M),
        "honest_wrong_start_frames": wrong.get("frames_to_recover"),
        "honest_wrong_start_within_15": None if not wrong else
        bool(wrong.get("frames_to_recover") is not None
             and wrong["frames_to_recover"] <= TARGET_WRONG_START),
        "note": "quick run: smaller particle counts than the issue's" if quick else "",
    }


def _table_rows(tab: dict) -> list:
    lines = [f"{'run':20s} {'RMS mm':>7s} {'+-':>5s} {'joint mm':>8s} {'turned':>6s} "
             f"{'evals/f':>8s} {'fps':>6s} {'voxels':>7s} {'fit':>7s} {'filter':>7s}  "
             "(turned: share of frames facing > 90 deg off; stage s/frame)"]
    for label, r in tab.items():
        st = r.get("stage_seconds_per_frame", {})
        cells = [f"{st.get(k, 0.0):7.3f}" for k in ("voxels", "blob_fit", "particle_filter")]
        lines.append(f"{label:20s} {1000 * r['rms_joint_error_m']:7.1f} "
                     f"{1000 * r['rms_joint_error_std_m']:5.1f} {r['mean_joint_error_mm']:8.1f} "
                     f"{r.get('frac_turned_round', float('nan')):6.2f} "
                     f"{r['evaluations_per_frame']:8.0f} {r['fps']:6.2f} " + " ".join(cells))
    return lines


def _true_body_lines(honest: dict, worst: int = 5) -> list:
    """The honest section's true-body ablation (``honest["true_body"]``): its RMS against the
    estimated body's, and the joints where the estimate loses most (mean error, mm)."""
    tb = honest.get("true_body")
    run = (honest.get("runs") or {}).get((tb or {}).get("run"))
    if not tb or not run:
        return []
    lines = [f"ablation, {tb['run']} with the dataset's true body (an oracle; subject and start "
             f"as above): RMS {1000 * tb['rms_joint_error_m']:.1f} mm +- "
             f"{1000 * tb['rms_joint_error_std_m']:.1f}, turned {tb['frac_turned_round']:.2f}: "
             f"the body estimate costs "
             f"{1000 * (run['rms_joint_error_m'] - tb['rms_joint_error_m']):+.1f} mm"]
    est, true = run.get("joint_error_mm") or {}, tb.get("joint_error_mm") or {}
    diff = {n: est[n] - true[n] for n in est if n in true}
    if diff:
        top = sorted(diff, key=lambda n: -diff[n])[:worst]
        lines.append("  mean joint error, estimated body against true body: "
                     + ", ".join(f"{n} {est[n]:.0f} / {true[n]:.0f}" for n in top))
    return lines


def format_table(res: dict) -> str:
    """The bench's figures as text tables (one per protocol)."""
    from gltrack.eval.report import body_error_text

    m = res["model"]
    lines = [f"bench vlmm on {res['machine']}: model learnt from {len(res['train_takes'])} takes "
             f"({res['train_frames']} frames at {res['fps']:g} fps) in "
             f"{res['learn_seconds']:.1f} s; test {res['clip']} (never trained on), frames "
             f"{res['test_first_frame']}..{res['test_first_frame'] + res['test_frames'] - 1} of "
             f"{res['test_take_frames']}, {res['seeds']} seed(s)",
             f"model: {m['n_clusters']} clusters (MML), {m['n_states']} VLMM states, entropy "
             f"train {m['train_entropy']:.3f} / unseen take {m['heldout_entropy']:.3f} "
             "bits/frame", ""]
    if res["protocol1"]:
        lines += ["protocol 1, motion models only (blob fit from the TRUE pose every frame: an "
                  "oracle of the protocol; true start):"] + _table_rows(res["protocol1"]) + [""]
    if res["protocol2"]:
        lines += ["protocol 2, the whole system (blob fit from the predictions; automatic "
                  "start):"] + _table_rows(res["protocol2"]) + [""]
    honest = res.get("honest") or {}
    if honest.get("runs"):
        lines += [f"honest protocol, the whole system on a subject drawn with {honest['subject']} "
                  "(estimated body, automatic start, blob fit from the predictions):"]
        lines += _table_rows(honest["runs"])
        for label, r in honest["runs"].items():
            if r.get("body_error"):
                lines.append(f"{label}: body estimate {body_error_text(r['body_error'])}")
        lines += _true_body_lines(honest)
        w = honest.get("wrong_start")
        if w:
            n = w["frames_to_recover"]
            lines.append(f"wrong start ({w['run']}, the true first pose turned "
                         f"{np.degrees(w['turned_rad']):.0f} deg): "
                         + (f"under {1000 * w['threshold_m']:.0f} mm after {n} frames"
                            if n is not None else f"never under {1000 * w['threshold_m']:.0f} mm")
                         + f", RMS over the take {1000 * w['rms_joint_error_m']:.1f} mm")
        lines.append("")
    lines += ["entropy vs maximal memory (bits/frame):",
              f"{'memory':>6s} {'states':>7s} {'train':>7s} {'unseen':>8s}"]
    for e in res["entropy_vs_memory"]:
        ho = e["heldout_entropy"]
        lines.append(f"{e['max_memory']:6d} {e['n_states']:7d} {e['train_entropy']:7.3f} "
                     f"{'-' if ho is None else f'{ho:8.3f}':>8s}")
    lines.append("")
    for label, r in res["recovery"].items():
        n = r["frames_to_recover"]
        turn = (f"turned {r['turned_rad']:.2f} rad, moved {r['shift_m']:g} m, "
                if "turned_rad" in r else "")
        lines.append(f"recovery {label} (true start, fit from predictions): failure at frame "
                     f"{r['failure_at_frame']} ({turn}RMS "
                     f"{1000 * (r['rms_at_failure_m'] or 0):.0f} mm), "
                     + (f"back under {1000 * r['threshold_m']:.0f} mm after {n} frames"
                        if n is not None else
                        f"not back under {1000 * r['threshold_m']:.0f} mm within "
                        f"{r['frames_observed']} frames"))
    t = res["targets"]
    lines += ["", "targets: protocol 1 vlmm <= condensation: "
              f"{t['p1_vlmm_le_condensation']}, vlmm <= 1.2 x apf: {t['p1_vlmm_le_1.2_apf']}; "
              "protocol 2 vlmm RMS <= 100 mm: "
              + ("n/a" if t["p2_vlmm_rms_m"] is None else
                 f"{t['p2_vlmm_rms_met']} ({1000 * t['p2_vlmm_rms_m']:.0f} mm)")
              + f"; recovery within 30 frames: {t['recovery_within_30']}; loop "
              + ("n/a" if t["loop_fps"] is None else f"{t['loop_fps']:.2f}")
              + (" (colour segmentation: n/a)" if t.get("loop_fps_colour") is None else
                 f" (colour segmentation: {t['loop_fps_colour']:.2f})")
              + f" frames/s (target {t['loop_fps_target']:g})"
              + ("" if t.get("honest_vlmm_rms_m") is None else
                 f"; honest vlmm RMS <= 100 mm: {t['honest_vlmm_rms_met']} "
                 f"({1000 * t['honest_vlmm_rms_m']:.0f} mm), wrong start back within 15 "
                 f"frames: {t['honest_wrong_start_within_15']}")
              + (f"  [{t['note']}]" if t["note"] else "")]
    return "\n".join(lines)
