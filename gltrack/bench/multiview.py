"""``gltrack bench multiview``: accuracy of the multi-view samplers at equal evaluation budget.

Bandouch et al. (2009) compare APF (10 layers x 800 particles), PS (1600 particles) and their
hierarchical sampler (HPS, 800 and 200 particles) by mean 3D joint error. This bench repeats that
on 4-camera datasets synthesised from the CMU clips in ``../shared/mocap`` (walk, hop, salsa) with
``gltrack synth --rig multiview``, scaled down to what a software-GL machine runs in minutes:

* every method gets the same number of candidate evaluations per frame, ``budget`` (default 2000;
  the paper's APF is 8000): SIR ``budget`` particles, APF 10 layers of ``budget / 10``, PS
  ``budget / P`` particles (P = number of partitions, 10), HPS ``budget / 15`` particles (6 torso
  layers + 8 limb layers + 1 combination re-weighting per particle), and HPS with a quarter of
  that ("hps/4", the paper's 200-of-800 run);
* both DOF presets: ``full`` (48 DOF) and ``38`` (37 DOF). The data always moves all 48 DOF (as a
  real person would); the 38-DOF model starts from the ground-truth pose projected onto its DOFs;
* the environment cases ``--occluder table`` and ``--distractor box`` (walk clip, HPS), with and
  without the environment layers (occluder polygons, non-human foreground removal);
* a "static" row: the initial pose held fixed, the error of doing nothing.

Figures are the mean 3D joint error (mm) over the tracked frames (:func:`gltrack.eval.metrics.evaluate`),
with evaluations per frame and seconds per frame. Datasets and results go to a temporary folder
(or ``workdir``) and are deleted unless ``keep``.

When the simulator is not installed the clips are rendered with the CPU reference rasteriser
(:func:`render_dataset`: per-part clothing colours, dataset masks = true silhouettes) and the
environment cases are skipped.
"""
from __future__ import annotations

import json
import logging
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gltrack.eval.report import body_error_text

from . import machine_name, shared_dir
from .depth import WRONG_START_RAD, by_joint, engine_use, settled_frames
from .protocols import HONEST, ORACLE, PROTOCOLS, body_error_of

log = logging.getLogger(__name__)

#: Clip name -> (BVH file in shared/mocap, first source frame at 120 frames/s). The first
#: frames of the walk and salsa files jump from a calibration pose (10-25 inter-frame sigmas);
#: the salsa starts at 400, as in the depth bench: livelier than its opening, and clear of the
#: mocap glitches near source frames 300-365.
CLIPS = {
    "walk": ("cmu_02_01_walk.bvh", 8),
    "hop": ("cmu_131_03_start_hop_stop_max_metres.bvh", 160),
    "salsa": ("cmu_60_10_salsa_daz_metres.bvh", 400),
}
ENV_CASES = {"table": ["--occluder", "table"], "distractor": ["--distractor", "box"]}
#: Evaluations per particle and frame of HPS with the default pipelines (see module docstring).
HPS_EVALS_PER_PARTICLE = 15
#: the honest protocol's target for hps (full DOF, the bench budget): mean joint error, mm
HONEST_HPS_MM = 40.0
#: Bandouch's APF budget: particles, annealing layers (8000 evaluations per frame)
PAPER_APF = (800, 10)
#: issue 15's speed target for that APF on a 2-core software-GL machine, seconds per frame
PAPER_APF_SECONDS = 5.0


def method_configs(budget: int, n_partitions: int = 10) -> dict:
    """Tracker runs at equal evaluation budget: name -> (method, options)."""
    b = int(budget)
    hps = max(6, b // HPS_EVALS_PER_PARTICLE)
    return {
        "sir": ("sir", {"particles": b}),
        "apf": ("apf", {"particles": max(2, b // 10), "layers": 10}),
        "ps": ("ps", {"particles": max(2, b // n_partitions)}),
        "hps": ("hps", {"particles": hps}),
        "hps/4": ("hps", {"particles": max(6, hps // 4)}),
    }


# ---------------------------------------------------------------------------------------------
# datasets


def synth(bvh: Path, out: Path, frames: tuple, *, fps: float = 30.0, seed: int = 0,
          size=(320, 240), extra=()) -> Path:
    """Run ``gltrack synth --rig multiview`` in a subprocess (it needs its own GL platform).

    ``frames`` counts source-clip frames.
    """
    cmd = [sys.executable, "-m", "gltrack", "-q", "synth", "--motion", str(bvh), "--rig",
           "multiview", "--out", str(out), "--frames", f"{frames[0]}:{frames[1]}", "--fps",
           str(fps), "--seed", str(seed), "--size", f"{size[0]}x{size[1]}", "--cameras", "4",
           "--overwrite", *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"gltrack synth failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return out


#: The camera ring of the datasets the tests draw with :func:`render_dataset`
#: (:func:`gltrack.bench.rigs.ring_cameras` arguments): all cameras 3.5 m from the subject at
#: 1.8 m height, the first at 45 degrees azimuth.
RING = {"radius": 3.5, "height": 1.8, "fov_y_deg": 50.0, "first_angle": 0.25 * np.pi,
        "height_step": 0.0}

#: BGR clothing colours by body part of :data:`gltrack.body.mesh.PARTS`.
PART_COLOURS = {
    "head": (60, 110, 190), "torso": (40, 40, 200), "pelvis": (120, 60, 30),
    "l_upper_arm": (40, 40, 200), "l_forearm": (70, 130, 210), "l_hand": (90, 150, 220),
    "r_upper_arm": (40, 40, 200), "r_forearm": (70, 130, 210), "r_hand": (90, 150, 220),
    "l_thigh": (120, 60, 30), "l_shin": (120, 60, 30), "l_foot": (30, 30, 30),
    "r_thigh": (120, 60, 30), "r_shin": (120, 60, 30), "r_foot": (30, 30, 30),
}


def render_dataset(out, body, params, cameras, fps: float, rng: np.random.Generator, *,
                   noise: float = 4.0, mask_flip: float = 0.0, overwrite: bool = False) -> Path:
    """A multiview dataset rendered with the CPU reference rasteriser (no simulator, no GL).

    The person wears :data:`PART_COLOURS` over a static random-texture background; each frame adds
    Gaussian sensor noise. Foreground masks are the true silhouettes with a fraction ``mask_flip``
    of random pixels flipped.

    Parameters
    ----------
    out : path, dataset folder to write
    body : gltrack.body.model.BodyModel
    params : (T, D) float, the motion
    cameras : list of colour Camera (no distortion)
    fps : float
    rng : numpy.random.Generator
    noise : float, sensor noise standard deviation, grey levels
    mask_flip : float in [0, 1), fraction of mask pixels flipped

    Returns
    -------
    Path of the dataset
    """
    from gltrack.body.mesh import PARTS
    from gltrack.body.model import body_to_meta
    from gltrack.data.dataset import DatasetWriter
    from gltrack.render import reference as ref

    P = body.dofs.validate(params)
    S = body.skinning(P)
    face_part = body.mesh.part[body.mesh.faces[:, 0]]
    palette = np.array([PART_COLOURS[p] for p in PARTS], np.float64)[face_part]
    meta = body_to_meta(body.skeleton, body.dofs.preset, body.lod)
    with DatasetWriter(out, "multiview", fps, cameras, body=meta, overwrite=overwrite) as w:
        for c, cam in enumerate(cameras):
            bg = rng.uniform(60, 200, size=(cam.height // 8 + 1, cam.width // 8 + 1, 3))
            bg = np.kron(bg, np.ones((8, 8, 1)))[:cam.height, :cam.width]
            w.write_background(c, np.clip(bg, 0, 255).astype(np.uint8))
            _, tri = ref.render_candidates(body.mesh, S, cam.K, cam.R, cam.t, cam.width, cam.height)
            for f in range(len(P)):
                on = tri[f] >= 0
                img = bg.copy()
                img[on] = palette[tri[f][on]]
                img += rng.normal(0.0, noise, img.shape)
                w.write_colour(f, c, np.clip(img, 0, 255).round().astype(np.uint8))
                flip = rng.random(on.shape) < mask_flip
                w.write_mask(f, c, on ^ flip)
                w.write_gtmask(f, c, on)
        w.write_groundtruth(body.joints(P), list(body.skeleton.names), body.marker_positions(P), P)
    return Path(out)


def _project_pose(x_full, names_full, dofs) -> np.ndarray:
    """The values of ``dofs``' DOFs taken from a pose of another preset (missing DOFs: 0)."""
    where = {n: i for i, n in enumerate(names_full)}
    return np.array([x_full[where[n]] if n in where else 0.0 for n in dofs.names])


# ---------------------------------------------------------------------------------------------
# runs


def _run(ds_path, method, options, out, preset, start_pose, ctx, seed,
         protocol=ORACLE) -> dict:
    """Track and score one run. ``start_pose`` (D,): the oracle's true first pose (in
    ``preset``), or with the honest protocol a deliberately wrong start (None: automatic)."""
    from gltrack.data.dataset import Dataset
    from gltrack.data.results import load_results
    from gltrack.eval.metrics import evaluate
    from gltrack.track.runner import track

    args = protocol.track_args()
    if start_pose is not None:
        init = Path(out).with_suffix(".init.npy")
        init.parent.mkdir(parents=True, exist_ok=True)
        np.save(init, start_pose)
        # the oracle's start is the truth: not second-guessed by the automatic start
        args.update(init=str(init), check_start=protocol is not ORACLE)
    t0 = time.perf_counter()
    timing = track(ds_path, method, out, options=options, overwrite=True, preset=preset,
                   seed=seed, progress=False, ctx=ctx, **args)
    secs = time.perf_counter() - t0
    ds = Dataset.open(ds_path)
    m = evaluate(load_results(out), ds.groundtruth())
    ds.close()
    n = max(int(timing.get("frames", 0)), 1)
    return {"mean_joint_error_mm": round(float(m["mean_joint_error_mm"]), 1),
            "joint_error_by_joint_mm": by_joint(m),
            "max_frame_error_mm": round(float(np.nanmax(m["per_frame"]["joint_error_mm"])), 1),
            "frac_turned_round": round(float(m["frac_turned_round"]), 3),
            "joint_error_mm": [round(float(e), 1) for e in m["per_frame"]["joint_error_mm"]],
            "evaluations_per_frame": round(int(timing.get("evaluations", 0)) / n),
            "seconds_per_frame": round(secs / n, 2), "options": options,
            **{k: (None if v is None else round(v, 3)) for k, v in engine_use(timing).items()}}


def _bench_honest(shared, bvh, src, work, budget, ctx, seed) -> dict:
    """The honest protocol on one clip (MakeHuman subject, estimated body, automatic start):
    ``hps`` at the budget, full DOF; and ``hps`` from the true first pose turned by
    :data:`WRONG_START_RAD` (a pose file, which the runner checks against its automatic
    start)."""
    from gltrack.body.model import body_from_meta
    from gltrack.data.dataset import Dataset

    ds = synth(bvh, work / "honest_ds", src, seed=seed, extra=HONEST.synth_flags(shared))
    method, opts = method_configs(budget)["hps"]
    out = {"hps": _run(ds, method, opts, work / "honest_hps", "full", None, ctx, seed,
                       protocol=HONEST)}
    out["body_error"] = body_error_of(work / "honest_hps", ds)
    with Dataset.open(ds) as d:
        # the landmark network's record (None: not installed, silhouettes only)
        out["keypoints"] = d.meta.get("keypoints")
        x0 = np.array(d.groundtruth()["params"][0], dtype=np.float64)
        x0[body_from_meta(d.body).dofs.index("pelvis_ry")] += WRONG_START_RAD
    row = _run(ds, method, opts, work / "honest_wrong_start", "full", x0, ctx, seed,
               protocol=HONEST)
    err = np.asarray(row["joint_error_mm"]) / 1000.0
    k = settled_frames(err, 0, 0.1)
    row["wrong_start_frames"] = k
    row["text"] = (f"back under 0.1 m for good after {k} frames" if k is not None
                   else f"not back under 0.1 m by the last of {len(err)} frames")
    out["wrong_start"] = row
    return out


def _static_error(ds_path) -> float:
    from gltrack.data.dataset import Dataset
    from gltrack.eval.metrics import evaluate

    ds = Dataset.open(ds_path)
    gt = ds.groundtruth()
    ds.close()
    still = {"joints": np.repeat(gt["joints"][:1], len(gt["joints"]), axis=0),
             "joint_names": gt["joint_names"]}
    return round(float(evaluate(still, gt)["mean_joint_error_mm"]), 1)


def bench_multiview(quick: bool = False, clips=None, *, budget: int | None = None,
                    frames: int | None = None, presets=("full", "38"), environment: bool = True,
                    seed: int = 0, workdir=None, keep: bool = False,
                    protocols=tuple(PROTOCOLS), paper_budget: bool = True) -> dict:
    """Mean 3D joint error of SIR / APF / PS / HPS at equal evaluation budget.

    Parameters
    ----------
    quick : bool, fewer frames (5) and a smaller budget (800 evaluations per frame)
    clips : sequence of names of :data:`CLIPS`, default all
    budget : int, candidate evaluations per frame and method (default 2000, quick 800)
    frames : int, frames tracked per clip at 30 frames/s (default 15, quick 5)
    presets : DOF presets to track with
    environment : also run the table / distractor cases (needs the simulator)
    seed : int, synthesis and tracking seed
    workdir : path, where datasets and results go (default a temporary folder)
    keep : keep ``workdir``'s contents
    protocols : names of :data:`gltrack.bench.protocols.PROTOCOLS`: ``oracle`` (every method
        and preset from the true first pose with the true body, own mesh) and ``honest``
        (MakeHuman subject, estimated body, automatic start: ``hps`` full DOF, and a start
        turned 90 degrees)
    paper_budget : with ``oracle`` and the walk clip, also time ``apf`` at Bandouch's budget
        (:data:`PAPER_APF`) with the defaults, with every layer on the default mesh and
        with every layer on the coarse one (``mesh_lod`` 0), against
        :data:`PAPER_APF_SECONDS`

    Returns
    -------
    dict, JSON-serialisable: ``machine``, ``renderer``, ``budget``, ``frames``, ``clips``
    (clip -> preset -> run -> figures, plus ``static_mm`` and ``honest``: {``hps``,
    ``body_error``, ``wrong_start``}), ``honest_targets``, ``paper_budget``
    (:func:`_bench_paper_budget`), ``environment`` (case -> figures), ``skipped`` (reasons),
    ``seconds``.
    """
    from gltrack.gl.context import shared_context

    t_start = time.perf_counter()
    budget = int(budget or (800 if quick else 2000))
    n_frames = int(frames or (5 if quick else 15))
    clips = list(clips or CLIPS)
    bad = [p for p in protocols if p not in PROTOCOLS]
    if bad:
        raise ValueError(f"unknown protocol(s) {bad}; choose from {list(PROTOCOLS)}")
    unknown = [c for c in clips if c not in CLIPS]
    if unknown:
        raise ValueError(f"unknown clips {unknown}; choose from {', '.join(CLIPS)}")
    res = {"budget": budget, "frames": n_frames, "fps": 30.0, "clips": {}, "environment": {},
           "skipped": [], "protocols": list(protocols)}
    shared = shared_dir()
    if shared is None:
        res["skipped"].append("../shared (or GLTRACK_SHARED) is absent: no mocap clips")
        return res
    res["data"] = "gltrack synth --rig multiview"
    own_dir = workdir is None
    work = Path(tempfile.mkdtemp(prefix="gltrack-bench-mv-") if own_dir else workdir)
    work.mkdir(parents=True, exist_ok=True)
    ctx = shared_context()
    res["machine"] = machine_name()
    res["renderer"] = ctx.info.get("GL_RENDERER", "?")
    for clip in clips:
        bvh_name, first = CLIPS[clip]
        bvh = shared / "mocap" / bvh_name
        if not bvh.is_file():
            res["skipped"].append(f"{clip}: {bvh} missing")
            continue
        src = (first, first + 4 * n_frames)  # 120 frames/s source -> n_frames at 30 frames/s
        entry = {}
        if "oracle" in protocols:
            ds = work / f"{clip}_ds"
            t0 = time.perf_counter()
            synth(bvh, ds, src, seed=seed)
            log.info("%s: dataset in %.1f s", clip, time.perf_counter() - t0)
            entry = _bench_clip(ds, work / clip, budget, presets, ctx, seed)
        if "honest" in protocols:
            entry["honest"] = _bench_honest(shared, bvh, src, work / clip, budget, ctx, seed)
        res["clips"][clip] = entry
    res["honest_targets"] = _honest_targets(res["clips"])
    walk_ds = work / "walk_ds"
    if paper_budget and "oracle" in protocols and (walk_ds / "meta.json").is_file():
        res["paper_budget"] = _bench_paper_budget(walk_ds, work / "walk", ctx, seed)
    if environment and "oracle" in protocols and "walk" in CLIPS:
        res["environment"] = _bench_environment(shared, work, budget, n_frames, ctx, seed)
    if own_dir and not keep:  # every protocol's datasets, not only after the environment cases
        shutil.rmtree(work, ignore_errors=True)
    res["seconds"] = round(time.perf_counter() - t_start, 1)
    return res


def _bench_paper_budget(ds_path, out_dir, ctx, seed) -> dict:
    """``apf`` at :data:`PAPER_APF` (full DOF, the oracle's true start) on one clip with the
    defaults (the early layers on the coarse mesh, :attr:`ApfOptions.fine_layers`), with every
    layer on the default mesh (``fine_layers`` 0: the code before it), and with the coarse mesh
    throughout (``mesh_lod`` 0): seconds per frame against :data:`PAPER_APF_SECONDS`, and the
    accuracy each buys. ``met``: the default's."""
    from gltrack.body.model import body_from_meta
    from gltrack.data.dataset import Dataset

    with Dataset.open(ds_path) as d:
        body = body_from_meta(d.body, "full")
    x0 = _start_pose(ds_path, body.dofs.names, body)
    particles, layers = PAPER_APF
    variants = {"default": {}, "fine_layers_0": {"fine_layers": 0}, "mesh_lod_0": {"mesh_lod": 0}}
    runs = {}
    for name, extra in variants.items():
        opts = {"particles": particles, "layers": layers, **extra}
        runs[name] = _run(ds_path, "apf", opts, out_dir / f"paper_apf_{name}", "full", x0, ctx,
                          seed)
        log.info("apf %dx%d, %s: %.2f s/frame, %.1f mm", particles, layers, name,
                 runs[name]["seconds_per_frame"], runs[name]["mean_joint_error_mm"])
    s = runs["default"]["seconds_per_frame"]
    return {"method": "apf", "particles": particles, "layers": layers, "runs": runs,
            "target_seconds_per_frame": PAPER_APF_SECONDS, "met": s <= PAPER_APF_SECONDS}


def _honest_targets(clips: dict) -> dict:
    """hps (honest, full DOF) mean joint error <= :data:`HONEST_HPS_MM`; the wrong start back
    under 0.1 m within :data:`gltrack.bench.depth.WRONG_START_FRAMES` frames."""
    from .depth import WRONG_START_FRAMES

    per = {}
    for c, e in clips.items():
        h = e.get("honest")
        if not h:
            continue
        k = h["wrong_start"]["wrong_start_frames"]
        per[c] = {"hps_mm": h["hps"]["mean_joint_error_mm"],
                  "hps_ok": h["hps"]["mean_joint_error_mm"] <= HONEST_HPS_MM,
                  "wrong_start_frames": k,
                  "wrong_start_ok": k is not None and k <= WRONG_START_FRAMES}
    return {"per_clip": per, "all_met": bool(per) and all(
        p["hps_ok"] and p["wrong_start_ok"] for p in per.values())}


def _start_pose(ds_path, dofs_names_full, body):
    from gltrack.data.dataset import Dataset

    ds = Dataset.open(ds_path)
    gt = ds.groundtruth()
    ds.close()
    return _project_pose(np.asarray(gt["params"][0]), dofs_names_full, body.dofs)


def _bench_clip(ds_path, out_dir, budget, presets, ctx, seed) -> dict:
    from gltrack.body.model import body_from_meta
    from gltrack.data.dataset import Dataset
    from gltrack.sample.partitions import fine_partitions

    ds = Dataset.open(ds_path)
    meta = ds.body
    ds.close()
    full = body_from_meta(meta, "full")
    out = {"static_mm": _static_error(ds_path)}
    for preset in presets:
        body = body_from_meta(meta, preset)
        x0 = _start_pose(ds_path, full.dofs.names, body)
        configs = method_configs(budget, len(fine_partitions(body.dofs)))
        runs = {}
        for name, (method, opts) in configs.items():
            runs[name] = _run(ds_path, method, opts, out_dir / f"{preset}_{name.replace('/', '_')}",
                              preset, x0, ctx, seed)
            log.info("%s %s %s: %.1f mm", Path(ds_path).name, preset, name,
                     runs[name]["mean_joint_error_mm"])
        out[preset] = runs
    return out


def _bench_environment(shared, work, budget, n_frames, ctx, seed) -> dict:
    from gltrack.body.model import body_from_meta
    from gltrack.data.dataset import Dataset

    bvh_name, first = CLIPS["walk"]
    method, opts = method_configs(budget)["hps"]
    out = {}
    for case, flags in ENV_CASES.items():
        ds_path = synth(shared / "mocap" / bvh_name, work / f"env_{case}_ds",
                        (first, first + 4 * n_frames), seed=seed, extra=flags)
        ds = Dataset.open(ds_path)
        meta = ds.body
        ds.close()
        body = body_from_meta(meta, "full")
        x0 = _start_pose(ds_path, body.dofs.names, body)
        out[case] = {"static_mm": _static_error(ds_path)}
        for label, env in (("with_layers", True), ("without_layers", False)):
            out[case][label] = _run(ds_path, method, dict(opts, environment=env),
                                    work / f"env_{case}_{label}", "full", x0, ctx, seed)
    return out


def _use(run: dict) -> str:
    c, k, e = (run.get(x) for x in ("calls_per_frame", "candidates_per_call", "engine_share"))
    if c is None:
        return "-"
    return f"{c:.0f}/{k or 0:.0f}/{100 * (e or 0):.0f}% ({run['seconds_per_frame']:.2f} s/f)"


def table(res: dict) -> str:
    """A plain-text table of :func:`bench_multiview`'s figures (mean joint error, mm)."""
    lines = [f"machine:  {res.get('machine', '?')}", f"renderer: {res.get('renderer', '?')}",
             f"data:     {res.get('data', '?')}",
             f"budget:   {res['budget']} evaluations per frame, {res['frames']} frames at 30 fps", ""]
    names = list(method_configs(res["budget"]))
    lines.append(f"{'clip':8s} {'dof':5s} {'static':>7s} " + " ".join(f"{n:>7s}" for n in names))
    for clip, r in res.get("clips", {}).items():
        for preset, runs in r.items():
            if preset in ("static_mm", "honest"):
                continue
            lines.append(f"{clip:8s} {preset:5s} {r['static_mm']:7.1f} " + " ".join(
                f"{runs[n]['mean_joint_error_mm']:7.1f}" if n in runs else "    n/a" for n in names))
    lines.append("engine use (calls per frame / candidates per call / % of time in the engine):")
    for clip, r in res.get("clips", {}).items():
        for preset, runs in r.items():
            if preset in ("static_mm", "honest"):
                continue
            lines.append(f"{clip:8s} {preset:5s} " + "  ".join(
                f"{n} {_use(runs[n])}" for n in names if n in runs))
    for clip, r in res.get("clips", {}).items():
        h = r.get("honest")
        if not h:
            continue
        b, w = h.get("body_error"), h["wrong_start"]
        cue = "keypoints" if h.get("keypoints") else "no keypoints"
        lines.append(f"{clip:8s} honest hps {h['hps']['mean_joint_error_mm']:.1f} mm "
                     f"(<= {HONEST_HPS_MM:g}; {cue}); start turned 90 deg: {w['text']} "
                     f"({w['mean_joint_error_mm']:.1f} mm)")
        if b:
            lines.append(f"{clip:8s} honest body estimate: {body_error_text(b)}")
    t = res.get("honest_targets", {})
    if t.get("per_clip"):
        lines.append(f"honest targets all met: {t['all_met']}")
    pb = res.get("paper_budget")
    if pb:
        lines.append(f"apf at the paper's budget ({pb['particles']} particles x {pb['layers']} "
                     f"layers), walk, target <= {pb['target_seconds_per_frame']:g} s/frame: "
                     + ("met" if pb["met"] else "missed"))
        for name, r in pb["runs"].items():
            ok = "met" if r["seconds_per_frame"] <= pb["target_seconds_per_frame"] else "missed"
            lines.append(f"  {name}: {r['seconds_per_frame']:.2f} s/frame ({ok}), "
                         f"{r['mean_joint_error_mm']:.1f} mm")
    for case, r in res.get("environment", {}).items():
        lines.append(f"env {case:10s} static {r['static_mm']:.1f}  hps with layers "
                     f"{r['with_layers']['mean_joint_error_mm']:.1f}  without "
                     f"{r['without_layers']['mean_joint_error_mm']:.1f}")
    for s in res.get("skipped", []):
        lines.append(f"skipped: {s}")
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover - manual runs: python -m gltrack.bench.multiview
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--clips", nargs="*")
    ap.add_argument("--budget", type=int)
    ap.add_argument("--frames", type=int)
    ap.add_argument("--json")
    a = ap.parse_args()
    logging.basicConfig(level=logging.INFO)
    r = bench_multiview(a.quick, a.clips, budget=a.budget, frames=a.frames)
    if a.json:
        Path(a.json).write_text(json.dumps(r, indent=2) + "\n")
    sys.stdout.write(table(r) + "\n")
