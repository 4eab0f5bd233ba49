"""Refine a dataset's foreground masks with a tracked result (``gltrack refine-masks DS R``).

For every frame the result holds and every colour camera, the body the result recorded
(``body.json``) is posed at the frame's ``params`` and its silhouette projected into the real
image. Two ways of using it (``method=``):

* ``"background"``: the sequence foreground of ``ingest`` is estimated again with the model's
  silhouettes left out of the temporal background (:func:`_background_pass`): the subject's
  ghost goes and the parts that never move come back, and the hull, GrabCut and shadow cues
  run as in ``ingest``;
* ``"grabcut"``: per frame and camera, :func:`gltrack.observe.model_masks.refine_with_model`
  combines the silhouette with the mask the dataset has (GrabCut seeded by the model, the
  sequence mask kept within reach; see that module for why both);
* ``"scene"``: the sequence mask without the pixels that show the static scene (they match
  their temporal background, which was never the subject's ghost) farther than ``core_m`` from
  the model's silhouette (:func:`_scene_pass`): it only removes, never adds, and removes only
  what the background test calls scene, so a model that is off the person cannot paint itself
  into the masks.

The refined masks replace ``camN_mask/``; the masks
they replaced are moved to ``camN_mask_sequence/`` the first time (a later refinement keeps that
copy, so every refinement starts from the sequence's masks again, never from its own output).
Frames the result does not hold keep the sequence's mask (``"grabcut"``) or have it left out of
the background (``"background"``). ``meta.json``'s ``"masks"`` gets a ``"refined"`` record
(result, method, frames, band, reach, seconds).

Everything is written into temporary folders first and swapped in at the end, so an interrupted
run leaves the dataset as it was (at worst a ``.camN_mask.refining`` folder, removed by the next
run).
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import time
from pathlib import Path

import cv2
import numpy as np

from gltrack.observe.background import clean_mask
from gltrack.observe.foreground import dilate_mask
from gltrack.observe.model_masks import (BAND_M, CORE_M, REACH_M, metres_to_pixels,
                                         model_silhouette, refine_with_model)

log = logging.getLogger(__name__)

#: where the sequence's own masks are kept once a refinement has replaced them
SEQUENCE_SUFFIX = "_mask_sequence"


def _read_mask(folder: Path, f: int) -> np.ndarray:
    src = folder / f"{f:06d}.png"
    seq = cv2.imread(str(src), cv2.IMREAD_GRAYSCALE)
    if seq is None:
        raise ValueError(f"{src}: not a readable mask")
    return seq > 127


class _Posed:
    """The result's model, posed and projected on demand: one frame at a time, cached."""

    def __init__(self, ds, cams, body, by_frame):
        self.ds, self.cams, self.body, self.by_frame = ds, cams, body, by_frame
        self._frame, self._verts = None, None

    def vertices(self, f: int):
        """(V, 3) posed vertices of frame f, or None where the result has no pose."""
        from gltrack.render.reference import skin_vertices

        if f not in self.by_frame:
            return None
        if self._frame != f:
            self._verts = skin_vertices(self.body.mesh,
                                        self.body.skinning(self.by_frame[f][None]))[0]
            self._frame = f
        return self._verts

    def silhouette(self, f: int, j: int):
        """(silhouette (H, W) bool, median depth in metres) of frame f in camera ``cams[j]``,
        or (None, None)."""
        v = self.vertices(f)
        if v is None:
            return None, None
        cam = self.ds.cameras[self.cams[j]]
        return (model_silhouette(cam, v, self.body.mesh.faces),
                float(np.median(cam.depth_of(v))))


def _grabcut_pass(ds, cams, source, posed, *, band_m, reach_m, core_m, progress):
    """Per frame and camera: GrabCut seeded by the model and the sequence mask
    (:func:`refine_with_model`). Yields (frame, camera position, sequence mask, refined)."""
    from tqdm import tqdm

    for f in tqdm(range(ds.frames), desc="refine masks", unit="frame", disable=not progress):
        for j, k in enumerate(cams):
            seq = _read_mask(source[k], f)
            sil, depth = posed.silhouette(f, j)
            if sil is None:
                yield f, j, seq, seq
                continue
            cam = ds.cameras[k]
            yield f, j, seq, refine_with_model(ds.colour(f, k), seq, sil,
                                               band_px=metres_to_pixels(cam, band_m, depth),
                                               reach_px=metres_to_pixels(cam, reach_m, depth),
                                               core_px=metres_to_pixels(cam, core_m, depth))


def _background_pass(ds, cams, source, posed, *, band_m, reach_m, core_m, progress):
    """The sequence foreground again, with the model left out of the background statistics.

    The temporal background of ``ingest`` averages the subject in wherever it stood in most
    frames: where it later moves away, that "ghost" is foreground (a door behind a person who
    stood in front of it), and a still part is background. With the tracked model's silhouette
    left out of every frame's statistics
    (:func:`~gltrack.observe.foreground.estimate_foreground`'s ``person_masks``), the background
    there comes from the frames where the subject was elsewhere, or, where it never left, from
    the surroundings (inpainted), so the whole chain (hull, GrabCut, shadows) runs on a
    background without the subject. The silhouette is widened by ``core_m``, the model's fitting
    error at a limb's edge, and by the estimator's own ``exclude_margin``: a wider margin leaves
    more background unobserved (inpainted) round a subject that barely moves. Frames the result
    does not hold leave out their sequence mask. ``band_m`` and ``reach_m`` are not used.
    """
    from tqdm import tqdm

    from gltrack.observe.foreground import ForegroundParams, estimate_foreground, level_floor

    rec = ds.meta.get("masks") if isinstance(ds.meta.get("masks"), dict) else {}
    params = ForegroundParams(**{k: rec[k] for k in ("work_size", "passes") if k in rec})
    person = [np.zeros((ds.frames, ds.cameras[k].height, ds.cameras[k].width), bool)
              for k in cams]
    # frame by frame, so the model is posed once per frame (``_Posed`` keeps one frame)
    for f in tqdm(range(ds.frames), desc="model silhouettes", unit="frame", disable=not progress):
        for j, k in enumerate(cams):
            sil, depth = posed.silhouette(f, j)
            person[j][f] = (_read_mask(source[k], f) if sil is None
                            else dilate_mask(sil, metres_to_pixels(ds.cameras[k], core_m, depth)))

    def feed(k):
        for f in range(ds.frames):
            yield ds.colour(f, k)

    # the support cue as ingest ran it: with the floor the dataset records (internal +Y)
    res = estimate_foreground([feed(k) for k in cams], [ds.cameras[k] for k in cams],
                              person_masks=person, params=params,
                              floor=level_floor(ds.floor_height()))
    for f in range(ds.frames):
        for j, k in enumerate(cams):
            cam = ds.cameras[k]
            m = res.masks[j][f]
            if m.shape != (cam.height, cam.width):  # as ingest writes them
                m = cv2.resize(m.astype(np.float32), (cam.width, cam.height),
                               interpolation=cv2.INTER_LINEAR) >= 0.5
            yield f, j, _read_mask(source[k], f), m


def _scene_pass(ds, cams, source, posed, *, band_m, reach_m, core_m, progress):
    """The sequence mask without the static scene beside the model.

    The sequence foreground's GrabCut fills the subject's still torso by colour and, with it,
    background of the subject's colours next to it (a skin-coloured door or cupboard). Such a
    pixel shows the static scene: it matches its temporal background (observed, with the
    sequence masks left out of the statistics), and the ghost test never fired there
    (:meth:`~gltrack.observe.foreground.SequenceForeground.scene_pixels`). A still part of the
    subject matches that too, so the model's silhouette, widened by ``core_m`` (its fitting
    error at a limb's edge), keeps what it covers; scene pixels farther from it are dropped.
    Nothing is added: a moving part the model missed (no scene pixel) stays, and frames the
    result does not hold keep their sequence mask. ``band_m`` and ``reach_m`` are not used.
    """
    from tqdm import tqdm

    from gltrack.observe.foreground import ForegroundParams, SequenceForeground

    rec = ds.meta.get("masks") if isinstance(ds.meta.get("masks"), dict) else {}
    params = ForegroundParams(**{k: rec[k] for k in ("work_size",) if k in rec})

    def feed(k):
        for f in range(ds.frames):
            yield ds.colour(f, k)

    est = SequenceForeground([feed(k) for k in cams], [ds.cameras[k] for k in cams], params)
    for j, k in enumerate(cams):
        cam, work = ds.cameras[k], est.cameras[j]
        size = (work.width, work.height)
        seq = np.stack([cv2.resize(_read_mask(source[k], f).astype(np.uint8), size,
                                   interpolation=cv2.INTER_NEAREST) > 0
                        for f in range(ds.frames)])
        scene = est.scene_pixels(j, seq)
        for f in tqdm(range(ds.frames), desc=f"scene {cam.name}", unit="frame",
                      disable=not progress):
            mask = _read_mask(source[k], f)
            sil, depth = posed.silhouette(f, j)
            if sil is None:
                yield f, j, mask, mask
                continue
            here = cv2.resize(scene[f].astype(np.uint8), (cam.width, cam.height),
                              interpolation=cv2.INTER_NEAREST) > 0
            keep = dilate_mask(sil, metres_to_pixels(cam, core_m, depth))
            out = mask & ~(here & ~keep)
            # the scene test is per pixel: the few pixels of a removed region that missed it
            # (noise) would stay as specks; an opening and the foreground's smallest component
            # take them, away from the model (a thin limb it covers stays), adding nothing
            opened = clean_mask(out, params.morph_size, max(int(params.min_area * out.size), 1),
                                close_size=1)
            yield f, j, mask, out & (opened | keep)


#: the ways of refining (``method=``)
METHODS = ("background", "grabcut", "scene")


def silhouette_overlaps(result, dataset, body, progress: bool = False) -> dict:
    """Per-camera silhouette IoU and shares of a result against a dataset's masks as they are
    now, at full resolution (``gltrack eval --iou-now``): what the multi-view trackers record
    while tracking (``info["iou"]``, ``info["model_on_fg"]``, ``info["fg_covered"]``),
    computed again, e.g. after :func:`refine_dataset_masks` changed the masks.

    The body is posed at each row's ``params`` and its silhouette projected through each colour
    camera's lens (:func:`gltrack.observe.model_masks.model_silhouette`), then counted against
    the frame's mask (:func:`gltrack.render.reference.silhouette_overlap`). Unlike the tracker's
    figure no environment layer blocks any pixel, and the count is at the camera's resolution,
    not at ``iou_tile``.

    Parameters
    ----------
    result : dict from :func:`gltrack.data.results.load_results` (``params`` (N, D) in the
        dataset's frame, ``frame`` (N,))
    dataset : gltrack.data.dataset.Dataset
    body : gltrack.body.model.BodyModel, the body the result was tracked with
    progress : bool, show a progress bar

    Returns
    -------
    dict frame -> {"iou", "model_on_fg", "fg_covered"}: lists over the dataset's colour cameras
    (None where the camera has no mask for the frame, or a denominator is empty), the
    ``infos`` :func:`gltrack.eval.quality.quality_summary` reads
    """
    from tqdm import tqdm

    from gltrack.render.reference import silhouette_overlap

    params = np.asarray(result["params"], dtype=np.float64)
    frames = np.asarray(result.get("frame", np.arange(len(params))), dtype=np.int64)
    cams = [k for k, c in enumerate(dataset.cameras) if c.kind == "colour"]
    posed = _Posed(dataset, cams, body, dict(zip(frames.tolist(), params)))
    keys = ("iou", "model_on_fg", "fg_covered")
    out = {}
    for f in tqdm(frames.tolist(), desc="silhouette IoU", unit="frame", disable=not progress):
        rows = []
        for j, k in enumerate(cams):
            mask = dataset.mask(f, k)
            rows.append((np.nan,) * 3 if mask is None
                        else silhouette_overlap(posed.silhouette(f, j)[0], mask))
        out[f] = {key: [None if not np.isfinite(r[i]) else round(float(r[i]), 4) for r in rows]
                  for i, key in enumerate(keys)}
    return out


def refine_dataset_masks(dataset, result, *, method: str = "grabcut", band_m: float = BAND_M,
                         reach_m: float = REACH_M, core_m: float = CORE_M, frames=None,
                         progress: bool = False) -> dict:
    """Refine the masks of ``dataset`` with the tracked ``result`` (see the module docstring).

    Parameters
    ----------
    dataset : path of a multi-view dataset folder with masks (``camN_mask/``)
    result : path of a results folder tracked on it (``body.json`` and its poses)
    band_m, reach_m, core_m : float, metres (:mod:`gltrack.observe.model_masks`)
    frames : (A, B), optional: refine only frames A (inclusive) to B (exclusive) of the result
        (the stretch where its overlay shows the model on the person); default all it holds
    progress : bool, show a progress bar

    Returns
    -------
    dict, the ``"refined"`` record written to ``meta.json`` (with the foreground fraction of the
    refined frames per camera, before and after)

    Raises
    ------
    ValueError
        A dataset without colour cameras or masks, or a result without poses for it.
    """
    from gltrack.data.dataset import META, Dataset
    from gltrack.data.results import _atomic_write_bytes, load_body_record, load_results

    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    t0 = time.perf_counter()
    frames_wanted = frames
    ds = Dataset.open(dataset)
    path = Path(ds.path)
    cams = [k for k, c in enumerate(ds.cameras) if c.kind == "colour"]
    if not cams:
        raise ValueError(f"{path}: no colour cameras: refine-masks is for multi-view datasets")
    for k in cams:
        folder = path / f"{ds.cameras[k].name}_mask"
        if not folder.is_dir():
            raise ValueError(f"{folder}: no masks to refine (make them with gltrack ingest)")
    res = load_results(result)
    body, _ = load_body_record(result)
    params = np.asarray(res["params"], dtype=np.float64)
    frames = np.asarray(res.get("frame", np.arange(len(params))), dtype=np.int64)
    if params.ndim != 2 or params.shape[1] != body.dofs.size:
        raise ValueError(f"{result}: params {params.shape} do not fit the body of its body.json "
                         f"({body.dofs.size} DOF)")
    if len(frames) and (frames.min() < 0 or frames.max() >= ds.frames):
        raise ValueError(f"{result}: frames {frames.min()}..{frames.max()} are not all in "
                         f"{path}'s 0..{ds.frames - 1}: a result of another dataset?")
    by_frame = dict(zip(frames.tolist(), params))
    if frames_wanted is not None:
        a, b = frames_wanted
        by_frame = {f: p for f, p in by_frame.items() if a <= f < b}
        if not by_frame:
            raise ValueError(f"{result}: no frame in {a}:{b} (it holds {frames.min()}.."
                             f"{frames.max()})")
    tmp = {k: path / f".{ds.cameras[k].name}_mask.refining" for k in cams}
    for folder in tmp.values():
        shutil.rmtree(folder, ignore_errors=True)  # debris of an interrupted run
        folder.mkdir()
    before, after = np.zeros(len(cams)), np.zeros(len(cams))
    try:
        # the sequence's masks are the input every time (never a refinement's output)
        source = {}
        for k in cams:
            name = ds.cameras[k].name
            kept = path / f"{name}{SEQUENCE_SUFFIX}"
            source[k] = kept if kept.is_dir() else path / f"{name}_mask"
        posed = _Posed(ds, cams, body, by_frame)
        refine = {"background": _background_pass, "grabcut": _grabcut_pass,
                  "scene": _scene_pass}[method]
        for f, j, seq, out in refine(ds, cams, source, posed, band_m=band_m, reach_m=reach_m,
                                     core_m=core_m, progress=progress):
            k = cams[j]
            if f in by_frame:
                before[j] += seq.mean()
                after[j] += out.mean()
            if not cv2.imwrite(str(tmp[k] / f"{f:06d}.png"),
                               np.where(out, 255, 0).astype(np.uint8)):
                raise OSError(f"{tmp[k] / f'{f:06d}.png'}: cannot write the refined mask")
        # swap in: the sequence's masks are kept once, later refinements replace their output
        for k in cams:
            name = ds.cameras[k].name
            current, kept = path / f"{name}_mask", path / f"{name}{SEQUENCE_SUFFIX}"
            if kept.is_dir():
                shutil.rmtree(current)
            else:
                os.replace(current, kept)
            os.replace(tmp[k], current)
    finally:
        for folder in tmp.values():
            shutil.rmtree(folder, ignore_errors=True)
    n = max(len(by_frame), 1)
    record = {"result": str(Path(result).resolve()), "method": method, "frames": len(by_frame),
              "band_m": band_m, "reach_m": reach_m, "core_m": core_m,
              "seconds": round(time.perf_counter() - t0, 1),
              "foreground_fraction_before": [round(float(b / n), 4) for b in before],
              "foreground_fraction_after": [round(float(a / n), 4) for a in after]}
    meta_path = path / META
    meta = json.loads(meta_path.read_text())
    masks = meta.get("masks") if isinstance(meta.get("masks"), dict) else {}
    masks["refined"] = record
    meta["masks"] = masks
    _atomic_write_bytes(meta_path, (json.dumps(meta, indent=2) + "\n").encode())
    log.info("refined the masks of %d frames x %d cameras in %.0f s; foreground fraction %s -> %s",
             len(by_frame), len(cams), record["seconds"], record["foreground_fraction_before"],
             record["foreground_fraction_after"])
    return record
