"""Run a tracker over a dataset and write the results folder frame by frame (crash-safe).

``METHODS`` maps each ``--method`` name to the rig it needs and a factory. The runner owns the
GL context, the results writer (``frames.jsonl`` appended per frame, ``--resume`` continues after
the last finished frame) and the final ``poses.npz`` / ``timing.json`` / ``poses.bvh``.
"""
from __future__ import annotations

import importlib
import logging
import time
from pathlib import Path

import numpy as np

from gltrack.body.model import body_from_meta
from gltrack.data.dataset import Dataset
from gltrack.data.results import ResultsWriter

from .base import options_from_dict

log = logging.getLogger(__name__)

#: method -> (rig, "module:Class", "module:OptionsClass")
METHODS = {
    "hc": ("depth", "gltrack.track.depth:HillClimbDepthTracker", "gltrack.track.depth:DepthOptions"),
}


def register(name, rig, tracker, options):
    """Add a tracking method (used by the tracker modules that extend the registry)."""
    METHODS[name] = (rig, tracker, options)


def _load(spec):
    mod, _, attr = spec.partition(":")
    return getattr(importlib.import_module(mod), attr)


def _extend_registry():
    # Trackers beyond plain HC live in optional modules that add themselves when imported.
    for mod in ("gltrack.track.ep", "gltrack.track.multiview", "gltrack.track.vlmm",
                "gltrack.track.blobfilter"):
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:
            if exc.name != mod:
                raise


def available_methods() -> dict:
    _extend_registry()
    return dict(METHODS)


def options_class(method: str):
    """The options dataclass of ``method`` (its fields are the method's ``--config`` keys)."""
    methods = available_methods()
    if method not in methods:
        raise ValueError(f"unknown method {method!r}; available: {', '.join(sorted(methods))}")
    return _load(methods[method][2])


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
    if arr.shape != (body.dofs.size,):
        raise ValueError(f"{path}: pose has shape {arr.shape}, expected ({body.dofs.size},)")
    return arr


def track(dataset_path, method: str, out, *, options: dict | None = None, init: str = "groundtruth",
          resume: bool = False, overwrite: bool = False, frames: tuple | None = None,
          preset: str | None = None, seed: int = 0, progress: bool = True, ctx=None) -> dict:
    """Track ``dataset_path`` with ``method`` and write the results folder ``out``.

    Parameters
    ----------
    options : dict, tracker options (``--config`` table); unknown keys are errors
    init : "groundtruth", "auto" or a pose file
    resume : continue an interrupted run in ``out``
    frames : (start, stop), optional sub-range of the dataset's frames
    preset : DOF preset overriding the dataset's body record
    progress : show a tqdm progress bar

    Returns
    -------
    dict, the ``timing.json`` contents plus ``out``.
    """
    from tqdm import tqdm

    from gltrack.gl.context import shared_context
    from gltrack.motion.export import write_params_bvh

    methods = available_methods()
    if method not in methods:
        raise ValueError(f"unknown method {method!r}; available: {', '.join(sorted(methods))}")
    rig, tracker_spec, options_spec = methods[method]
    ds = Dataset.open(dataset_path)
    if ds.rig != rig:
        raise ValueError(f"{ds.path}: method {method!r} needs a {rig} dataset, this one is {ds.rig!r}")
    opts = options_from_dict(_load(options_spec), options, where=f"options for {method}")
    body = body_from_meta(ds.body, preset, where=str(Path(ds.path) / "meta.json"))
    start, stop = (0, ds.frames) if frames is None else frames
    if not (0 <= start < stop <= ds.frames):
        raise ValueError(f"frames {start}:{stop} outside the dataset's 0:{ds.frames}")
    ctx = ctx or shared_context()
    rng = np.random.default_rng(seed)
    tracker = _load(tracker_spec)(ds, body, ctx, opts, rng)
    writer = ResultsWriter(out, method, list(body.skeleton.names), list(body.markers.names),
                           resume=resume, overwrite=overwrite)
    try:
        done = writer.done_frames
        if resume and done:
            last = writer.last()
            first = int(last["frame"]) + 1
            tracker.start(first - 1, np.asarray(last["params"]))
            log.info("resuming after frame %d", first - 1)
        else:
            first = start
            t0 = time.perf_counter()
            x0 = initial_pose(init, ds, body, tracker, start)
            tracker.start(start, x0)
            log.info("initialised (%s) in %.2f s", init, time.perf_counter() - t0)
        bar = tqdm(range(first, stop), desc=f"{method} {Path(ds.path).name}", unit="frame",
                   disable=not progress, leave=False)
        for f in bar:
            t0 = time.perf_counter()
            est = tracker.step(f)
            secs = time.perf_counter() - t0
            p = est.params[None]
            writer.append(f, est.params, body.joints(p)[0], body.marker_positions(p)[0],
                          est.score, est.evaluations, secs, info=est.info)
            bar.set_postfix(evals=est.evaluations, s=f"{secs:.2f}")
        timing = writer.finish()
        arrays = writer.arrays()
        write_params_bvh(Path(out) / "poses.bvh", body, arrays["params"], ds.fps)
    finally:
        tracker.close()
        writer.close()
    timing = dict(timing)
    timing["out"] = str(out)
    return timing
