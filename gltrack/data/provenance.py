"""Provenance of a results folder: which dataset, settings and gltrack made it (``run.json``).

A run records, when it starts (:func:`run_provenance`, written into ``run.json`` by
:class:`gltrack.data.results.ResultsWriter`)::

    "dataset": {"path": absolute path, "fingerprint": sha256 hex, "parts": {part: sha256 hex},
                "fps": F, "frames": N (the dataset's), "rig": "depth" | "multiview"},
    "frames": [A, B],          the dataset frames the run was asked to track (A..B-1)
    "method": M, "options": {the resolved tracker options}, "seed": S, "init": "auto" | ...,
    "body": {"source": "estimate" | "dataset" | "file", "preset": DOF preset},
    "gltrack_version": "x.y.z", "started": ISO 8601 UTC time

The fingerprint (:func:`dataset_fingerprint`) is cheap: a SHA-256 over the small files
(``meta.json``, ``calibration.json``, ``environment.json``, ``groundtruth.npz``,
``keypoints.npz``) and over the sorted names and sizes of every other file (the frames), never
the gigabytes of images. Its
``parts`` (one hash per small file and one per frame folder or video) let a refusal say *what*
differs. Two datasets with the same fingerprint hold the same files under the same names with
the same sizes and the same metadata, calibration and ground truth.

Readers of a results folder (``export``, ``render``, ``eval``, ``track --resume``) use
:func:`read_provenance`; results written before these keys existed have none of them, and the
readers fall back (with a warning where the fallback guesses, e.g. the frame rate).
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from pathlib import Path

log = logging.getLogger(__name__)

#: the dataset's small files hashed byte for byte (the rest: names and sizes only)
_SMALL = ("meta.json", "calibration.json", "environment.json", "groundtruth.npz",
          "keypoints.npz")


def gltrack_version() -> str:
    """The version of the running gltrack (``gltrack.__version__``)."""
    import gltrack

    return str(getattr(gltrack, "__version__", "unknown"))


def dataset_fingerprint(path) -> dict:
    """A cheap content fingerprint of a dataset folder.

    Parameters
    ----------
    path : path of a dataset folder

    Returns
    -------
    dict
        ``fingerprint``: SHA-256 hex over all parts; ``parts``: {name: SHA-256 hex}, one per
        small file present (``meta.json``, ``calibration.json``, ``environment.json``,
        ``groundtruth.npz``, ``keypoints.npz``, hashed whole) and one per other top-level entry (a frame folder
        such as ``cam0`` or ``cam0_mask``: the sorted names and sizes of its files; a video or
        background image: its name and size). Hidden files (``.*``) are left out.
    """
    path = Path(path)
    parts = {}
    for entry in sorted(os.scandir(path), key=lambda e: e.name):
        if entry.name.startswith("."):
            continue
        h = hashlib.sha256()
        if entry.name in _SMALL and entry.is_file():
            with open(entry.path, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        elif entry.is_dir():
            for root, dirs, files in os.walk(entry.path):
                dirs[:] = sorted(d for d in dirs if not d.startswith("."))
                rel = os.path.relpath(root, entry.path)
                for name in sorted(files):
                    if name.startswith("."):
                        continue
                    size = os.stat(os.path.join(root, name)).st_size
                    h.update(f"{rel}/{name}\0{size}\n".encode())
        else:
            h.update(f"{entry.name}\0{entry.stat().st_size}\n".encode())
        parts[entry.name] = h.hexdigest()
    total = hashlib.sha256()
    for name, digest in parts.items():
        total.update(f"{name}\0{digest}\n".encode())
    return {"fingerprint": total.hexdigest(), "parts": parts}


def dataset_record(ds) -> dict:
    """The ``run.json`` ``"dataset"`` record of an open dataset.

    Parameters
    ----------
    ds : gltrack.data.dataset.Dataset

    Returns
    -------
    dict: ``path`` (absolute), ``fingerprint``, ``parts`` (:func:`dataset_fingerprint`),
    ``fps``, ``frames`` (the dataset's frame count), ``rig``
    """
    fp = dataset_fingerprint(ds.path)
    return {"path": str(Path(ds.path).resolve()), "fingerprint": fp["fingerprint"],
            "parts": fp["parts"], "fps": float(ds.fps), "frames": int(ds.frames),
            "rig": str(ds.rig)}


def _plain(obj):
    """``obj`` as it reads back from JSON (tuples become lists, numpy scalars numbers)."""
    return json.loads(json.dumps(obj, default=lambda o: o.item() if hasattr(o, "item")
                                 else str(o)))


def run_provenance(ds, options: dict, seed: int, init: str, frames, body_record: dict) -> dict:
    """The provenance keys a run adds to ``run.json`` (see the module docstring).

    Parameters
    ----------
    ds : gltrack.data.dataset.Dataset, the dataset tracked
    options : dict, the resolved tracker options (every field, defaults included)
    seed : int
    init : str, the ``--init`` choice (a pose file is recorded by its absolute path)
    frames : (start, stop), the dataset frames the run tracks
    body_record : dict, the body record (:func:`gltrack.body.model.body_record`)

    Returns
    -------
    dict, JSON-able
    """
    if init not in ("auto", "groundtruth"):
        init = str(Path(init).resolve())
    return _plain({
        "dataset": dataset_record(ds),
        "frames": [int(frames[0]), int(frames[1])],
        "options": dict(options), "seed": int(seed), "init": init,
        "body": {"source": (body_record or {}).get("source"),
                 "preset": (body_record or {}).get("preset")},
        "gltrack_version": gltrack_version(),
        "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    })


def fingerprint_difference(recorded: dict, current: dict) -> str:
    """Words naming the dataset parts in which two ``"dataset"`` records differ.

    Parameters
    ----------
    recorded, current : dict, ``"dataset"`` records (:func:`dataset_record`)

    Returns
    -------
    str, e.g. ``"groundtruth.npz, cam0 differ"``; ``""`` when the fingerprints agree
    """
    if recorded.get("fingerprint") == current.get("fingerprint"):
        return ""
    a, b = recorded.get("parts") or {}, current.get("parts") or {}
    changed = [k for k in sorted(set(a) & set(b)) if a[k] != b[k]]
    words = []
    if changed:
        words.append(f"{', '.join(changed[:4])}{' ...' if len(changed) > 4 else ''} differ")
    if sorted(set(a) - set(b)):
        words.append(f"{', '.join(sorted(set(a) - set(b))[:4])} missing")
    if sorted(set(b) - set(a)):
        words.append(f"{', '.join(sorted(set(b) - set(a))[:4])} added")
    return "; ".join(words) or "the fingerprint differs"


def resume_problem(stored: dict, mine: dict, force: bool = False) -> str | None:
    """Why a run with provenance ``mine`` may not resume one recorded as ``stored``.

    Compares the dataset fingerprint (skipped with ``force``), the first frame, the options
    and the seed. A dataset that moved (another path, the same fingerprint) and a stop frame
    that changed (a run extended or shortened) are no reason: the caller logs them.

    Parameters
    ----------
    stored : dict, the parsed ``run.json`` of the results folder
    mine : dict, :func:`run_provenance` of the resuming run
    force : bool, resume onto a dataset whose fingerprint differs (a repaired frame)

    Returns
    -------
    str naming the first field that differs, the stored and the new value; None if none.
    """
    sd, md = stored.get("dataset") or {}, mine.get("dataset") or {}
    if not force and sd.get("fingerprint") and sd.get("fingerprint") != md.get("fingerprint"):
        return (f"field 'dataset.fingerprint' differs: {md.get('path')} is not the dataset this "
                f"run began on ({sd.get('path')}: {fingerprint_difference(sd, md)})")
    if "frames" in stored and isinstance(stored["frames"], list) and stored["frames"]:
        if int(stored["frames"][0]) != int(mine["frames"][0]):
            return (f"field 'frames' is {stored['frames'][0]}:{stored['frames'][1]}, this run "
                    f"has {mine['frames'][0]}:{mine['frames'][1]} (it must start at the same "
                    "frame)")
    if "seed" in stored and stored["seed"] != mine.get("seed"):
        return f"field 'seed' is {stored['seed']!r}, this run has {mine.get('seed')!r}"
    if isinstance(stored.get("options"), dict):
        a, b = stored["options"], mine.get("options") or {}
        for key in sorted(set(a) | set(b)):
            if a.get(key) != b.get(key):
                return f"field 'options.{key}' is {a.get(key)!r}, this run has {b.get(key)!r}"
    return None


def read_provenance(result) -> dict:
    """The ``run.json`` of a results folder (or of the folder of a ``poses.npz``), {} if none.

    A missing or unreadable ``run.json`` gives {} (results copied without it still export);
    :func:`gltrack.data.results.load_results` reports damage where it needs the file.
    """
    result = Path(result)
    folder = result.parent if result.is_file() else result
    try:
        run = json.loads((folder / "run.json").read_text())
    except (OSError, ValueError):
        return {}
    return run if isinstance(run, dict) else {}


def recorded_range(result, n_frames: int | None = None):
    """The frame range ``(start, stop)`` a results folder's ``run.json`` records, or None (no
    record, or one outside ``0..n_frames`` when that is given)."""
    rng = read_provenance(result).get("frames")
    try:
        a, b = (int(v) for v in rng)
    except (TypeError, ValueError):
        return None
    if not 0 <= a < b or (n_frames is not None and b > n_frames):
        return None
    return a, b


def recorded_fps(run: dict):
    """The frame rate a ``run.json`` records (its dataset's), or None."""
    try:
        fps = float((run.get("dataset") or {})["fps"])
    except (KeyError, TypeError, ValueError):
        return None
    return fps if fps > 0 else None


def check_same_dataset(run: dict, ds, where: str, force: bool = False,
                       masks_may_differ: bool = False):
    """Refuse a dataset that is not the one a result was tracked on (``eval``, ``render``).

    Parameters
    ----------
    run : dict, the result's ``run.json`` (:func:`read_provenance`); without a ``"dataset"``
        record (older results) nothing is checked here
    ds : gltrack.data.dataset.Dataset, or the path of a dataset folder
    where : str, the result's path, for the message
    force : bool, only log the difference
    masks_may_differ : bool, accept a dataset that differs only in its foreground masks
        (``camN_mask/``, ``camN_mask_sequence/``) and in ``meta.json``, which records them:
        what ``gltrack refine-masks`` changes (``eval --iou-now`` scores against them)

    Raises
    ------
    ValueError
        One line naming the result, the dataset and what differs.
    """
    rec = run.get("dataset")
    if not isinstance(rec, dict) or not rec.get("fingerprint"):
        return
    path = Path(getattr(ds, "path", ds))
    mine = dataset_fingerprint(path)
    if mine["fingerprint"] == rec["fingerprint"]:
        return
    diff = fingerprint_difference(rec, mine)
    a, b = rec.get("parts") or {}, mine.get("parts") or {}
    masks_only = bool(a and b) and not [
        k for k in set(a) | set(b) if a.get(k) != b.get(k) and k != "meta.json"
        and not k.endswith(("_mask", "_mask_sequence"))]
    if masks_only and masks_may_differ:
        log.info("%s: %s's masks differ from those it was tracked on (%s)", where, path, diff)
        return
    msg = (f"{where}: was tracked on {rec.get('path')} (run.json field 'dataset.fingerprint'), "
           f"{path} is another dataset ({diff}"
           + ("; only its masks changed: gltrack eval --iou-now scores against them" if masks_only
              else "") + ")")
    if force:
        log.warning("%s; going on (--force)", msg)
        return
    raise ValueError(msg + "; give --force to compare anyway")
