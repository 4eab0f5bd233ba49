"""Exports of a tracking result for other tools: BVH, glTF binary, OpenSim TRC and JSON.

A results folder records the body it was tracked with in ``body.json``
(:func:`gltrack.data.results.recorded_body`); results written before that file existed take the
body from the dataset's ``meta.json`` (``body``) or, without a dataset, the default body.
:func:`body_for_result` checks that the result fits the body: its parameter vectors the DOF
preset and, for a recorded body, its joints and markers those of the body.

Frames (see "Frame of the coordinates" in :mod:`gltrack.data.results`): a result tracked on a
dataset with a user frame (``gltrack ingest``: a Z-up Pose2Sim or Qualisys calibration, say)
holds joints and markers in the user's frame and params in gltrack's internal +Y-up frame
(``X_user = R_user_from_internal @ X_internal``). Each format follows its own convention:

* **TRC** (:func:`trc_frame`): OpenSim is Y-up, and Pose2Sim writes every TRC from a Z-up
  calibration with its axes relabelled ``X, Y, Z = y, z, x`` (``zup2yup``) and ``Units m``;
  gltrack writes the same (:func:`gltrack.export.trc.opensim_axes`, metres), so an OpenSim
  user loads a gltrack TRC next to a Pose2Sim TRC of the same take and they coincide.
  ``axes="calibration"`` writes the calibration's own axes instead. A result without a user
  frame (synthetic data) is written as before: gltrack's frame (already Y-up), millimetres.
* **BVH** and **glTF/GLB** are Y-up by convention (glTF by its specification; Blender's BVH and
  glTF importers assume it): both are written in the internal frame, which for a Z-up user
  frame is the usual Y-up form of it, ``(x, y, z)_internal = (x, z, -y)_user`` (what Blender
  itself writes), so importing the file into Blender (Z-up) puts the body back at the user's
  coordinates. The BVH root translation is the internal ``params``' root translation.
* **JSON**: joints and markers in the user's frame, as in the results, with the ``"world"``
  record (the matrix) beside them; ``params`` internal, as in the results.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

#: Export formats and their file extensions.
FORMATS = {"bvh": ".bvh", "glb": ".glb", "trc": ".trc", "json": ".json"}


#: Largest distance (metres) between a result's joints or markers and those its recorded body
#: gives for the result's parameters (float32 skinning and JSON round trips stay far below).
BODY_TOLERANCE_M = 1e-4


def body_for_result(result: dict, body_meta: dict | None = None, preset: str | None = None,
                    where: str = "the default body", body=None):
    """The body a result was tracked with.

    Parameters
    ----------
    result : dict
        From :func:`gltrack.data.results.load_results`.
    body_meta : dict, optional
        A dataset's ``meta.json`` ``body`` record; None for the default body. Unused when
        ``body`` is given.
    preset : a key of :data:`gltrack.body.dofs.PRESETS`, optional
        DOF preset overriding the recorded one (as ``gltrack track --dof`` does). With ``body``
        it may only repeat the recorded preset.
    where : str
        Where the body (record) came from, for messages.
    body : gltrack.body.model.BodyModel, optional
        The body the results folder records (``body.json``). The result's joint (and marker)
        names and positions must be the ones this body gives for its ``params``, within
        :data:`BODY_TOLERANCE_M`.

    Returns
    -------
    gltrack.body.model.BodyModel

    Raises
    ------
    ValueError
        The results' ``params`` length differs from the preset's DOF count (the message names
        the preset that would fit, if any); ``preset`` disagrees with ``body``; the result's
        joints or markers are not ``body``'s.
    """
    from gltrack.body.dofs import PRESETS, make_dofs
    from gltrack.body.model import body_from_meta

    recorded = body is not None
    if not recorded:
        body = body_from_meta(body_meta, preset, where=where)
    elif preset is not None and preset != body.dofs.preset:
        raise ValueError(f"DOF preset {preset!r} disagrees with {where}, which records the "
                         f"{body.dofs.preset!r} preset the result was tracked with (leave out --dof)")
    params = np.asarray(result["params"])
    D = params.shape[1]
    if len(params) and D != body.dofs.size:  # a result with no frames has no DOF count
        fits = [p for p in PRESETS if make_dofs(body.skeleton, p).size == D]
        hint = f"; preset {fits[0]!r} has {D} (choose it)" if fits else ""
        raise ValueError(f"results params have {D} values, but the {body.dofs.preset!r} DOF "
                         f"preset of {where} has {body.dofs.size}{hint}")
    if recorded:
        _check_result_body(result, body, where)
    return body


def _check_result_body(result: dict, body, where: str):
    """Refuse a recorded body whose joints or markers are not the result's."""
    checks = [("joint", result["joint_names"], body.skeleton.names, result["joints"], body.joints)]
    if len(result.get("marker_names", [])):
        checks.append(("marker", result["marker_names"], body.markers.names, result["markers"],
                       body.marker_positions))
    params = np.asarray(result["params"], dtype=np.float64)
    R = result_frame(result)  # the body gives internal positions, the result stores user ones
    for kind, names, body_names, xyz, positions in checks:
        if list(names) != list(body_names):
            raise ValueError(f"{where}: the body's {kind} names are not the result's "
                             f"{kind}_names (the body file does not belong to this result)")
        if len(params):
            err = float(np.max(np.linalg.norm(positions(params) @ R.T - np.asarray(xyz),
                                              axis=-1)))
            if not err <= BODY_TOLERANCE_M:
                raise ValueError(f"{where}: the body puts the result's {kind}s up to "
                                 f"{1000 * err:.1f} mm away from the recorded {kind}s (the body "
                                 "file does not belong to this result)")


def result_frame(result: dict) -> np.ndarray:
    """(3, 3) ``R_user_from_internal`` of a loaded result (its ``"world"`` record; identity
    without one). The same as :func:`gltrack.data.results.result_frame`, which this layer may
    not import."""
    world = result.get("world")
    if world is None:
        return np.eye(3)
    return np.asarray(world["R_user_from_internal"], dtype=np.float64)


#: TRC axis choices of :func:`export_result` (see :func:`trc_frame`).
TRC_AXES = ("opensim", "calibration")
TRC_UNITS = ("m", "mm")


def trc_frame(result: dict, axes: str = "opensim") -> np.ndarray:
    """(3, 3) rotation from a result's stored frame to the axes its TRC file is written in.

    Parameters
    ----------
    result : dict, from :func:`gltrack.data.results.load_results`
    axes : {"opensim", "calibration"}
        ``"opensim"``: Y up as OpenSim wants, the user's axes relabelled as Pose2Sim does
        (:func:`gltrack.export.trc.opensim_axes`; a result whose world record names no up
        axis is written in gltrack's internal frame, which is Y-up too). ``"calibration"``: the
        user's calibration axes as they are (Z up for Pose2Sim and Qualisys).

    Returns
    -------
    (3, 3) float64; the identity for results without a user frame (already Y-up).
    """
    from .trc import opensim_axes

    if axes not in TRC_AXES:
        raise ValueError(f"TRC axes must be one of {TRC_AXES}, got {axes!r}")
    world = result.get("world")
    if world is None or axes == "calibration":
        return np.eye(3)
    if world.get("up"):
        return opensim_axes(world["up"])
    log.info("the result's world record names no up axis: TRC in gltrack's Y-up frame")
    return result_frame(result).T


def export_result(result: dict, out, fmt: str, body, fps: float, points: str = "markers",
                  axes: str = "opensim", units: str | None = None) -> Path:
    """Write ``result`` in one format.

    Parameters
    ----------
    result : dict, from :func:`gltrack.data.results.load_results`
    out : path of the file to write
    fmt : {"bvh", "glb", "trc", "json"}
    body : BodyModel, from :func:`body_for_result`
    fps : float, frames per second of the dataset
    points : {"markers", "joints"}
        What a ``trc`` file holds: the results' surface markers (computed from the body for
        results without markers) or the joint centres.
    axes : {"opensim", "calibration"}
        The axes of a ``trc`` file (:func:`trc_frame`; the module docstring says why).
    units : {"m", "mm"}, optional
        Length unit of a ``trc`` file (its ``Units`` header; OpenSim converts either). Default:
        metres for a result in a user's frame (the calibration's unit, and Pose2Sim's),
        millimetres otherwise (gltrack's TRC of synthetic data, as before).

    Returns
    -------
    Path written
    """
    from .bvh import write_params_bvh
    from .gltf import write_glb
    from .jsonout import write_json
    from .trc import write_trc

    out = Path(out)
    if len(result["params"]) == 0:
        raise ValueError("the result holds no frames: nothing to export")
    frames = np.asarray(result["frame"], dtype=np.int64)
    if fmt in ("bvh", "glb") and result.get("world") is not None:
        log.info("%s: %s is Y-up by convention: written in gltrack's internal frame, "
                 "X_user = %s @ X_file", out, fmt.upper(), result_frame(result).tolist())
    if fmt == "bvh":
        if np.any(np.diff(frames) != 1):
            log.warning("%s: frames are not consecutive (%d..%d, %d frames); BVH has no frame "
                        "numbers, so the gaps close up", out, frames[0], frames[-1], len(frames))
        write_params_bvh(out, body, result["params"], fps)
        return out
    if fmt == "glb":
        return write_glb(out, body, result["params"], fps, frames)
    if fmt == "json":
        return write_json(out, result, fps, body)
    if fmt == "trc":
        if points == "joints":
            names, xyz = result["joint_names"], result["joints"]
        elif points == "markers":
            names, xyz = result["marker_names"], result["markers"]
            if not len(names):
                log.info("result has no markers: computing the body's from the params")
                names = body.markers.names
                xyz = body.marker_positions(result["params"]) @ result_frame(result).T
        else:
            raise ValueError(f"points must be 'markers' or 'joints', got {points!r}")
        if units is None:
            units = "mm" if result.get("world") is None else "m"
        M = trc_frame(result, axes)
        if result.get("world") is not None:
            xyz = np.asarray(xyz, dtype=np.float64) @ M.T
            log.info("TRC axes %s (X, Y, Z = rows of %s applied to the user's frame), %s", axes,
                     M.tolist(), units)
        return write_trc(out, names, xyz, fps, frames, units=units)
    raise ValueError(f"unknown export format {fmt!r} (have {', '.join(FORMATS)})")


from .bvh import params_to_bvh, write_params_bvh  # noqa: E402
from .gltf import build_glb, write_glb  # noqa: E402
from .jsonout import motion_document, write_json  # noqa: E402
from .trc import format_trc, opensim_axes, read_trc, write_trc  # noqa: E402

__all__ = ["FORMATS", "TRC_AXES", "TRC_UNITS", "body_for_result", "export_result",
           "trc_frame", "result_frame", "opensim_axes", "params_to_bvh", "write_params_bvh",
           "build_glb", "write_glb", "motion_document", "write_json", "format_trc", "read_trc",
           "write_trc"]
