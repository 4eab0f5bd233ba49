"""Behaviour prior vs Gaussian diffusion: evaluations needed for a given accuracy (Caillette 2008).

The paper reports that its VLMM prediction keeps accuracy with 25 times fewer particle
evaluations than Condensation. This bench measures the same trade-off here:

1. learn a behaviour model from the first part of a CMU clip (``../shared/mocap``);
2. synthesise a held-out later part of the clip as a multi-view sequence with the sensor
   simulator (:func:`gltrack.data.simulate.synthesize_in_subprocess`, four colour cameras,
   cluttered room, MOG2 background-subtraction masks: ``data="simulate"``, the default), or,
   where the simulator is unavailable (``data="render"``), as clean foreground masks of the
   skinned body from four ring cameras (CPU reference rasteriser);
3. track it with the same particle filter (GPU silhouette cost, SIR, best particle) using either
   plain Gaussian diffusion (per-DOF sigmas of :mod:`gltrack.body.dofs`) or the VLMM prior
   (:class:`gltrack.track.vlmm.VlmmPrior`), at several particle counts, from the true first pose;
4. report the mean joint error of each run, the evaluations each method needs to reach a target
   error, and the errors at equal evaluations.

The synthetic-data helpers here are also used by the tests.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

CLIP = "mocap/cmu_60_10_salsa_daz_metres.bvh"
TILE = 64


# ------------------------------------------------------------------------ synthetic data
def ring_cameras(target, n: int = 4, radius: float = 4.0, height: float = 2.0, width: int = 128,
                 height_px: int = 96, fov_y_deg: float = 55.0):
    """``n`` colour cameras on a circle around ``target`` (3,), metres, looking at it."""
    from gltrack.camera import look_at_camera

    t = np.asarray(target, dtype=np.float64)
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.4
        eye = (t[0] + radius * np.sin(a), height + 0.3 * (i % 2), t[2] + radius * np.cos(a))
        cams.append(look_at_camera(f"cam{i}", eye, t, width, height_px, fov_y_deg))
    return cams


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
def run_filter(body, engine, gt_joints, start, n, rng, prior=None, survival=0.3):
    """Track with SIR on the engine's silhouette cost (masks already uploaded per frame by
    ``engine_frames``); returns (mean joint error m, per-frame errors, evaluations)."""
    from gltrack.sample.diffusion import StateSpace, diffuse
    from gltrack.sample.resampling import systematic_resample
    from gltrack.sample.weights import Weights, annealing_exponent

    d = body.dofs
    P = np.repeat(d.validate(start), n, axis=0)
    space = StateSpace.from_dofs(d, engine.fps)
    if prior is not None:
        prior.reset(P, rng)
    errs, evals = [], 0
    for f in range(len(gt_joints)):
        engine.upload(f)
        P = prior.predict(P, rng) if prior is not None else diffuse(P, rng, space)
        cost = engine.score(body.skinning(P), ["silhouette"])[:, :, 1].sum(axis=1)
        evals += len(P)
        best = int(np.argmin(cost))
        errs.append(float(np.linalg.norm(body.joints(P[best:best + 1])[0] - gt_joints[f],
                                         axis=1).mean()))
        lw = -(cost - cost.min())
        w = Weights(annealing_exponent(lw, survival) * lw)
        idx = systematic_resample(w.W, rng, len(P))
        P = P[idx]
        if prior is not None:
            prior.select(idx)
    return float(np.mean(errs)), errs, evals


class _Frames:
    """A scoring engine with per-frame mask upload (the bench's observation)."""

    def __init__(self, ctx, body, cameras, masks, fps, tile):
        from gltrack.render.engine import ScoringEngine

        self.e = ScoringEngine(ctx, body.mesh, body.skeleton.n_joints, cameras, tile=tile)
        self.masks, self.fps, self.cur = masks, fps, None

    def upload(self, f):
        if self.cur != f:
            for c, m in enumerate(self.masks[f]):
                self.e.set_masks(c, m)
            self.cur = f

    def score(self, S, ch):
        return self.e.score(S, ch)

    def release(self):
        self.e.release()


def _evals_to_reach(runs, target):
    """Fewest evaluations per frame whose mean error (over seeds) is <= target, else None."""
    ok = [r["particles"] for r in runs if r["mean_error_m"] <= target]
    return min(ok) if ok else None


def simulated_observation(params, skeleton, dofs, fps, out, seed: int = 0):
    """Synthesise ``params`` (T, D) with the multi-view sensor simulator into ``out``.

    Returns
    -------
    cameras : list of 4 undistorted colour Camera
    masks : list over frames of lists over cameras of (H, W) bool background-subtraction masks
        (undistorted with nearest neighbour)
    params : (T, D) float64, the ground-truth parameters as the body was posed (clamped)
    """
    import cv2

    from gltrack.data.dataset import Dataset
    from gltrack.data.simulate import synthesize_in_subprocess

    path = synthesize_in_subprocess(params, skeleton, dofs, fps, "multiview", str(out), seed=seed,
                                    progress=False, overwrite=True, lod=0)
    ds = Dataset.open(path)
    try:
        cams = list(ds.cameras)
        masks = []
        for f in range(ds.frames):
            row = []
            for i, c in enumerate(cams):
                m = ds.mask(f, i)
                if m is None:
                    raise ValueError(f"{path}: camera {c.name} has no masks")
                if np.any(c.dist):
                    m = c.undistort_image(m.astype(np.uint8), cv2.INTER_NEAREST) > 0
                row.append(np.asarray(m, bool))
            masks.append(row)
        gt = np.asarray(ds.groundtruth()["params"], dtype=np.float64)
    finally:
        ds.close()
    return [c.undistorted() for c in cams], masks, gt


def bench_vlmm(quick: bool = False, seed: int = 0, shared=None, data: str = "simulate") -> dict:
    """Measure the VLMM prior against Gaussian diffusion (see module docstring).

    Parameters
    ----------
    quick : bool, shorter sequence, fewer particle counts and seeds (noisier)
    seed : int
    shared : path of the shared reference folder (default: GLTRACK_SHARED or ../shared)
    data : "simulate" (sensor simulator, falls back to "render" when pyrender is missing) or
        "render" (clean silhouettes from the CPU reference rasteriser)

    Returns
    -------
    dict (JSON-able) with the model report, the per-run errors and the summary.

    Raises
    ------
    FileNotFoundError when the CMU clip is absent.
    """
    from gltrack.body.model import BodyModel
    from gltrack.gl.context import shared_context
    from gltrack.motion.behaviour import BehaviourModel
    from gltrack.motion.retarget import load_motion
    from gltrack.track.vlmm import VlmmPrior

    from . import machine_name, shared_dir

    if data not in ("simulate", "render"):
        raise ValueError(f"data must be 'simulate' or 'render', got {data!r}")
    root = Path(shared) if shared else shared_dir()
    clip = root / CLIP if root else None
    if clip is None or not clip.is_file():
        raise FileNotFoundError(f"bench vlmm needs {CLIP} in the shared folder "
                                "(GLTRACK_SHARED or ../shared)")
    fps = 30.0
    sk, dofs, params, _ = load_motion(clip, "25", fps=fps)
    cut = int(0.6 * len(params))
    train, test = params[:cut], params[cut:]
    n_frames = min(len(test), 15 if quick else 30)
    test = test[:n_frames]
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    model = BehaviourModel.fit(train, fps, rng, holdout=0.0, dof_names=dofs.names[6:])
    learn_s = time.perf_counter() - t0
    body = BodyModel.build(sk, "25", lod=0)
    if data == "simulate":
        import importlib.util

        # Only look for pyrender: importing it here would pin PyOpenGL's platform in this
        # process, which holds a moderngl context (the simulator runs in a spawn child).
        if importlib.util.find_spec("pyrender") is None:
            log.warning("sensor simulator unavailable (no pyrender): rendering clean masks")
            data = "render"
    if data == "simulate":
        import tempfile

        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix="gltrack-bench-vlmm-") as tmp:
            cams, masks, test = simulated_observation(test, sk, dofs, fps, Path(tmp) / "ds", seed)
        log.info("simulated %d frames in %.1f s", len(test), time.perf_counter() - t0)
    else:
        cams = ring_cameras(test[:, :3].mean(axis=0) + np.array([0.0, -0.1, 0.0]))
        masks = render_masks(body, test, cams)
    gt = body.joints(test)
    counts_vlmm = [25, 50, 100] if quick else [25, 50, 100, 200]
    counts_diff = [50, 200, 800] if quick else [50, 100, 200, 400, 800, 1600]
    seeds = [seed] if quick else [seed, seed + 1]
    ctx = shared_context()
    eng = _Frames(ctx, body, cams, masks, fps, tile=TILE)
    runs = {"vlmm": [], "diffusion": []}
    try:
        for name, counts in (("vlmm", counts_vlmm), ("diffusion", counts_diff)):
            for n in counts:
                errs, secs = [], 0.0
                for s in seeds:
                    r = np.random.default_rng(1000 + s)
                    prior = VlmmPrior(model, dofs, fps) if name == "vlmm" else None
                    t = time.perf_counter()
                    e, _, ev = run_filter(body, eng, gt, test[0], n, r, prior)
                    secs += time.perf_counter() - t
                    errs.append(e)
                runs[name].append({"particles": n, "evaluations_per_frame": n,
                                   "mean_error_m": float(np.mean(errs)),
                                   "errors_per_seed_m": errs,
                                   "seconds_per_frame": secs / (len(seeds) * n_frames)})
                log.info("%s N=%d: %.4f m", name, n, np.mean(errs))
    finally:
        eng.release()
    best_vlmm = min(r["mean_error_m"] for r in runs["vlmm"])
    best_diff = min(r["mean_error_m"] for r in runs["diffusion"])
    targets = sorted({round(best_vlmm * 1.25, 4), round(max(best_vlmm, best_diff) * 1.1, 4)})
    reach = []
    for tgt in targets:
        a, b = _evals_to_reach(runs["vlmm"], tgt), _evals_to_reach(runs["diffusion"], tgt)
        reach.append({"target_error_m": tgt, "vlmm_evaluations_per_frame": a,
                      "diffusion_evaluations_per_frame": b,
                      "ratio": (b / a) if a and b else None})
    equal = []
    by_n = {r["particles"]: r["mean_error_m"] for r in runs["diffusion"]}
    for r in runs["vlmm"]:
        if r["particles"] in by_n:
            equal.append({"evaluations_per_frame": r["particles"],
                          "vlmm_error_m": r["mean_error_m"],
                          "diffusion_error_m": by_n[r["particles"]]})
    return {"machine": machine_name(), "clip": CLIP, "data": data, "fps": fps,
            "train_frames": int(cut),
            "test_frames": int(n_frames), "cameras": len(cams), "tile": TILE,
            "fixed_pose_error_m": float(np.linalg.norm(gt - gt[:1], axis=2).mean()), "seeds": seeds,
            "learn_seconds": learn_s, "model": model.report(), "runs": runs,
            "evaluations_to_reach": reach, "equal_evaluations": equal,
            "note": "a ratio of None means one method never reached the target error at the "
                    "particle counts tried"}
