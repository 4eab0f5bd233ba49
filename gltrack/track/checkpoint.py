"""The tracker's state after each finished frame, so that ``--resume`` goes on bit for bit.

A run killed after frame ``f`` and resumed must track frame ``f + 1`` from exactly the state the
uninterrupted run had: the tracker's pose hypotheses, velocities, motion-prior histories, learnt
appearance and generator state (:meth:`gltrack.track.base.Tracker.get_state`), the runner's
lost-track watch (:class:`gltrack.track.lost.LossWatch`) and the frames it has already tracked
ahead while deciding between start hypotheses (written one by one as the loop reaches them).

File: ``RESULT/checkpoint.npz``, replaced after every frame once that frame's line of
``frames.jsonl`` is on disk (written to a temporary file, fsync'ed, then renamed over the old
one: it is always either the previous frame's or this frame's). Its arrays are the state's
numpy arrays (``a0``, ``a1``, ...) and ``state``, a JSON string of everything else in which
each array is ``{"__array__": "aK"}``. Top-level keys of the JSON: ``format``
(:data:`FORMAT`), ``method``, ``frame`` (the last finished frame), ``params`` (its pose, to
check it against ``frames.jsonl``), ``tracker``, ``watch``, ``decided``.

On resume the checkpoint is used when its method matches and its frame is a finished frame
whose line holds its pose bit for bit. It is normally the last finished frame; a kill between a
frame's line and its checkpoint leaves the checkpoint one frame behind, and the runner then
tracks the frames after it again without writing them (:func:`replayed`) to reach the state
after the last line. Otherwise (no checkpoint: a run of an older version or a method that
cannot checkpoint; one of another run) the tracker re-starts from the last pose with a warning,
as before.
"""
from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

from gltrack.data.results import fsync_dir

log = logging.getLogger(__name__)

CHECKPOINT = "checkpoint.npz"
FORMAT = "gltrack-checkpoint-1"


def _split(obj, arrays: dict):
    """``obj`` with every numpy array moved into ``arrays`` and replaced by a reference."""
    if isinstance(obj, np.ndarray):
        key = f"a{len(arrays)}"
        arrays[key] = obj
        return {"__array__": key}
    if isinstance(obj, dict):
        return {str(k): _split(v, arrays) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_split(v, arrays) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _join(obj, arrays):
    if isinstance(obj, dict):
        if set(obj) == {"__array__"}:
            return np.array(arrays[obj["__array__"]])
        return {k: _join(v, arrays) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_join(v, arrays) for v in obj]
    return obj


def save(out, method: str, frame: int, params, tracker, watch, decided: dict) -> bool:
    """Write the checkpoint of the state after ``frame`` (call once its line is written).

    Parameters
    ----------
    out : results folder
    method : the ``--method`` name
    frame : int, the frame just written
    params : (D,) the pose written for it
    tracker : Tracker, its :meth:`~gltrack.track.base.Tracker.get_state` is saved
    watch : LossWatch
    decided : dict frame -> (FrameEstimate, seconds), frames tracked ahead, not yet written

    Returns
    -------
    bool, False when the tracker cannot checkpoint (nothing is written; an older checkpoint is
    removed so that it cannot be mistaken for this run's)
    """
    path = Path(out) / CHECKPOINT
    state = tracker.get_state()
    if state is None:
        discard(out)
        return False
    ahead = [{"frame": int(f), "params": np.asarray(e.params, dtype=np.float64),
              "score": float(e.score), "evaluations": int(e.evaluations), "info": e.info,
              "seconds": float(s)} for f, (e, s) in sorted(decided.items())]
    record = {"format": FORMAT, "method": str(method), "frame": int(frame),
              "params": np.asarray(params, dtype=np.float64), "tracker": state,
              "watch": watch.get_state(), "decided": ahead}
    arrays = {}
    text = json.dumps(_split(record, arrays))
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "wb") as f:
        np.savez(f, state=np.array(text), **arrays)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    fsync_dir(path.parent)
    return True


def load(out, method: str, finished: dict) -> dict | None:
    """The checkpoint of ``out`` if it belongs to a finished frame, else None (logged).

    Parameters
    ----------
    out : results folder
    method : the ``--method`` name of the resumed run
    finished : dict frame -> (D,) params of the finished frames (``frames.jsonl``)

    Returns
    -------
    dict with ``frame``, ``tracker``, ``watch`` and ``decided`` (a list of dicts: frame,
    params, score, evaluations, info, seconds) or None
    """
    path = Path(out) / CHECKPOINT
    frame = max(finished)
    if not path.is_file():
        log.warning("%s: no checkpoint; the tracker re-starts from frame %d's pose (the "
                    "resumed frames may differ from an uninterrupted run's)", out, frame)
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        record = _join(json.loads(str(arrays.pop("state"))), arrays)
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as exc:
        log.warning("%s: unreadable checkpoint (%s); the tracker re-starts from frame %d's pose",
                    path, exc, frame)
        return None
    problem = None
    if record.get("format") != FORMAT:
        problem = f"format {record.get('format')!r}"
    elif record.get("method") != method:
        problem = f"method {record.get('method')!r}"
    elif record.get("frame") not in finished:
        problem = f"frame {record.get('frame')}, not a finished frame (the last is {frame})"
    elif not np.array_equal(np.asarray(record["params"]),
                            np.asarray(finished[record["frame"]], dtype=np.float64)):
        problem = f"a frame {record['frame']} pose other than frames.jsonl's"
    if problem:
        log.warning("%s: checkpoint of %s; the tracker re-starts from frame %d's pose (the "
                    "resumed frames may differ from an uninterrupted run's)", path, problem, frame)
        return None
    return record


def restore(record: dict, tracker, watch) -> dict:
    """Put a loaded checkpoint into a freshly built ``tracker`` and ``watch``.

    Returns
    -------
    dict frame -> (FrameEstimate, seconds), the frames tracked ahead (the runner writes them
    as it reaches them)
    """
    from .base import FrameEstimate

    tracker.set_state(record["tracker"])
    watch.set_state(record["watch"])
    return {int(d["frame"]): (FrameEstimate(np.asarray(d["params"], dtype=np.float64),
                                            float(d["score"]), int(d["evaluations"]),
                                            d["info"]), float(d["seconds"]))
            for d in record["decided"]}


def replayed(f: int, est, finished: dict) -> None:
    """Check a frame tracked again after a checkpoint that was behind ``frames.jsonl``
    against its written pose (the runner does not write it again); a difference is logged
    (the written frames stay, the next frames go on from the new estimate)."""
    if not np.array_equal(np.asarray(est.params, dtype=np.float64),
                          np.asarray(finished[f], dtype=np.float64)):
        log.warning("frame %d tracked again after the checkpoint differs from its written pose "
                    "by up to %.3g: the tracker is not deterministic here", f,
                    float(np.abs(np.asarray(est.params) - np.asarray(finished[f])).max()))


def discard(out) -> None:
    """Remove the checkpoint of ``out`` (a new run starts, or the tracker cannot checkpoint)."""
    path = Path(out) / CHECKPOINT
    if path.exists():
        path.unlink()
