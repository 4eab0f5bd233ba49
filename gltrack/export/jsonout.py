"""Tracked motion -> one self-describing JSON file (for scripts, web viewers, other languages).

Schema (``"format": "gltrack-motion"``, ``"version": 1``)::

    {
      "format": "gltrack-motion", "version": 1,
      "method": "apf",                       tracker that produced the motion
      "fps": 30.0,                           frames per second; time = frame / fps
      "units": {"length": "m", "angle": "rad", "time": "s"},
      "axes": "right-handed, +Y up, body faces +Z at rest, subject's left is +X",
      "dof_preset": "full",                  DOF preset of "params" (null if unknown)
      "dof_names": ["pelvis_tx", ...],       (D,) names of the params entries
      "joint_names": ["pelvis", ...],        (J,)
      "joint_parents": [-1, 0, ...],         (J,) index into joint_names, -1 for a root;
                                             null when the body is unknown
      "marker_names": ["head_top", ...],     (M,), may be empty
      "frames": [
        {"frame": 0,                         dataset frame index (0-based)
         "time": 0.0,                        seconds
         "params": [D floats],               root translation (m), then angles (rad)
         "joints": [[x, y, z], ...],         (J, 3) metres, world
         "markers": [[x, y, z], ...],        (M, 3) metres, world
         "score": 0.93}                      tracker score of the pose
      ]
    }

A result in a user's frame (tracked on a dataset made by ``gltrack ingest``, see
:mod:`gltrack.data.results`) has, instead of the ``"axes"`` line above::

      "axes": "the user's calibration frame (up: z); params: gltrack's internal frame ...",
      "world": {"up": "z",                   the user frame's up axis
                "R_user_from_internal": 3x3} joints and markers are in the user's frame;
                                             params (root translation and angles) are in
                                             gltrack's internal +Y-up frame, and
                                             joints = R_user_from_internal @ FK(params)

Results without one (synthetic data) have no ``"world"``: their frame is gltrack's.

Non-finite numbers (a marker that was not available) are written as ``null`` so the file is
strict JSON.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

FORMAT = "gltrack-motion"
VERSION = 1


def _nulls(x):
    if isinstance(x, list):
        return [_nulls(v) for v in x]
    return None if isinstance(x, float) and not np.isfinite(x) else x


def motion_document(result: dict, fps: float, body=None) -> dict:
    """The JSON document (a dict) for a loaded result.

    Parameters
    ----------
    result : dict
        As returned by :func:`gltrack.data.results.load_results`.
    fps : float, frames per second
    body : gltrack.body.model.BodyModel, optional
        Supplies ``dof_preset``, ``dof_names`` and ``joint_parents``; without it those are null.
    """
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps!r}")
    params = np.asarray(result["params"], dtype=np.float64)
    joints = np.asarray(result["joints"], dtype=np.float64)
    markers = np.asarray(result["markers"], dtype=np.float64)
    frames = np.asarray(result["frame"], dtype=np.int64)
    score = np.asarray(result["score"], dtype=np.float64)
    jnames = [str(s) for s in result["joint_names"]]
    parents = None
    dof_names = preset = None
    if body is not None:
        if params.shape[1] != body.dofs.size:
            raise ValueError(f"params have {params.shape[1]} values, the {body.dofs.preset!r} "
                             f"body {body.dofs.size}")
        preset, dof_names = body.dofs.preset, list(body.dofs.names)
        sk = body.skeleton
        parents = []
        for n in jnames:
            # Results may hold a subset or another order of the skeleton's joints.
            p = int(sk.parents[sk.index(n)]) if n in sk.names else -1
            parents.append(jnames.index(sk.names[p]) if p >= 0 and sk.names[p] in jnames else -1)
    doc = {
        "format": FORMAT, "version": VERSION, "method": str(result.get("method", "")),
        "fps": float(fps),
        "units": {"length": "m", "angle": "rad", "time": "s"},
        "axes": "right-handed, +Y up, body faces +Z at rest, subject's left is +X",
        "dof_preset": preset, "dof_names": dof_names,
        "joint_names": jnames, "joint_parents": parents,
        "marker_names": [str(s) for s in result.get("marker_names", [])],
        "frames": [],
    }
    world = result.get("world")
    if world is not None:
        doc["axes"] = (f"the user's calibration frame (up: {world.get('up') or 'see world'}) "
                       "for joints and markers; params in gltrack's internal frame (right-handed, "
                       "+Y up, body faces +Z at rest): X_user = R_user_from_internal @ X_internal")
        doc["world"] = {"up": world.get("up"),
                        "R_user_from_internal": np.asarray(world["R_user_from_internal"],
                                                           dtype=np.float64).tolist()}
        doc["frames"] = doc.pop("frames")  # keep the frames last
    for i in range(len(params)):
        doc["frames"].append({
            "frame": int(frames[i]), "time": float(frames[i]) / float(fps),
            "params": _nulls(params[i].tolist()), "joints": _nulls(joints[i].tolist()),
            "markers": _nulls(markers[i].tolist()), "score": _nulls(float(score[i]))})
    return doc


def write_json(path, result: dict, fps: float, body=None) -> Path:
    """Write the motion of a loaded result as JSON (schema in the module docstring)."""
    path = Path(path)
    doc = motion_document(result, fps, body)
    path.write_text(json.dumps(doc, allow_nan=False, separators=(",", ":")) + "\n")
    log.info("wrote %s (%d frames)", path, len(doc["frames"]))
    return path
